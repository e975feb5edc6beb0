"""The `tactile-compliance` command. Thin: parse arguments, call library functions, print.

The app is built here from the command modules, in the order `--help` lists the commands:
`framework` (how a command runs and fails), `options` (what several commands share) and
one module per group of commands (`data`, `training`, `inference`, `sensors`, `demos`).
Every library import stays inside a command, so that a config typo is reported before
torch loads."""

from __future__ import annotations

from tactile_compliance.cli import data, demos, inference, sensors, training
from tactile_compliance.cli.framework import (
    EXIT_BAD_INPUT,
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    _Cli,
    main,
)

__all__ = ["EXIT_BAD_INPUT", "EXIT_FAILED", "EXIT_INTERRUPTED", "app"]

app = _Cli(
    name="tactile-compliance",
    help=(
        "Estimate an object's Young's modulus from one GelSight grasp.\n\n"
        "Typical flow: `simulate` (or get real data) -> `import` -> `info` -> `split` -> "
        "`train` (one run) or `experiment` (a grid) -> `evaluate` -> `report`; then "
        "`export` and `predict`, or `calibrate` a sensor -> `live` (and `record` your own "
        "grasps). `presets` lists the packaged grids and configs."
    ),
    pretty_exceptions_enable=False,
)
import_app = _Cli(
    help="Import a raw dataset into a GraspStore (the one on-disk format every command reads)."
)
app.add_typer(import_app, name="import")
app.callback()(main)

import_app.command("burgess")(data.import_burgess_command)
import_app.command("yuan")(data.import_yuan_command)
for name, command in (
    ("simulate", data.simulate),
    ("info", data.info),
    ("presets", data.presets),
    ("split", data.split),
    ("split-summary", data.split_summary),
    ("train", training.train),
    ("pretrain", training.pretrain),
    ("evaluate", training.evaluate),
    ("experiment", training.experiment),
    ("tune", training.tune),
    ("tune-balance", training.tune_balance),
    ("adapt", training.adapt),
    ("predict", inference.predict),
    ("export", inference.export),
    ("estimate", inference.estimate),
    ("calibrate", sensors.calibrate),
    ("calibrate-depth", sensors.calibrate_depth_command),
    ("calibrate-rig", sensors.calibrate_rig_command),
    ("depth", inference.depth),
    ("record", sensors.record),
    ("live", inference.live),
    ("report", training.report),
    ("demo", demos.demo),
    ("sim2real", demos.sim2real),
):
    app.command(name)(command)
