"""The end-to-end runs on built-in synthetic data: demo, sim2real."""

# typer reads the parameters' annotations at runtime and needs Optional[X] on Python 3.10.
# ruff: noqa: UP045

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from tactile_compliance.cli.framework import (
    _json,
)
from tactile_compliance.cli.options import (
    DemoMode,
    DeviceOption,
)
from tactile_compliance.devices import DEFAULT_DEVICE


def demo(
    out: Annotated[Path, typer.Option(help="Where everything is written.")] = Path("demo-output"),
    mode: Annotated[
        DemoMode,
        typer.Option(help="full (6-25 minutes on 2 CPU cores, by CPU) or ci (seconds, tiny)."),
    ] = "full",
    workers: Annotated[
        Optional[int],
        typer.Option(min=1, help="Dask worker processes for the grids (default: CPUs, at most 4)."),
    ] = None,
    as_json: Annotated[
        bool,
        typer.Option(
            "--json",
            help="Print the summary (stage times, import reports, grid summaries, the "
            "report's path) as JSON; the stages' text goes to stderr.",
        ),
    ] = False,
) -> None:
    """Run the whole system on built-in synthetic data (the main job).

    Generates a synthetic dataset, imports it, trains the quick experiment grids and
    writes the report. Re-running continues where it stopped.
    """
    from tactile_compliance.demo import run_demo

    echo = (lambda text: typer.echo(text, err=True)) if as_json else typer.echo  # stdout: JSON only
    summary = run_demo(out, mode=mode, workers=workers, echo=echo)
    typer.echo(_json(summary.to_dict()) if as_json else summary.format())


def sim2real(
    out: Annotated[Path, typer.Option(help="Where the data, the run and DIR/best.pt go.")] = Path(
        "sim2real-output"
    ),
    rig: Annotated[
        str,
        typer.Option(
            help="The real rig the synthetic grasps imitate (`simulate --rig`): a name "
            "(wedge-2023, dataset) or a rig file that calibrate-rig wrote (its press force, "
            "stiffness, gel, edge glow and lights)."
        ),
    ] = "wedge-2023",
    mode: Annotated[
        DemoMode, typer.Option(help="full (about 10 minutes on 2 CPU cores) or ci (seconds, tiny).")
    ] = "full",
    seed: Annotated[int, typer.Option(min=0, help="Generation and training seed.")] = 0,
    workers: Annotated[
        Optional[int], typer.Option(min=1, help="Generator processes (default: all CPUs).")
    ] = None,
    device: DeviceOption = DEFAULT_DEVICE,
    as_json: Annotated[bool, typer.Option("--json", help="Print the summary as JSON.")] = False,
) -> None:
    """Train a model for a real GelSight rig on synthetic grasps only.

    Generates grasps with the generator set to the rig, imports them, trains the packaged
    `sim2real` configuration and writes DIR/best.pt, which `predict` and `live` take.
    Re-running continues where it stopped. How it transfers: docs/results.md, "Real grasps".
    """
    from tactile_compliance.sim2real import run_sim2real

    summary = run_sim2real(
        out,
        rig=rig,
        mode=mode,
        seed=seed,
        workers=workers,
        device=device,
        # Lightning's bar writes to stdout, which --json keeps for the JSON (as `train`).
        progress=not as_json,
        echo=(lambda text: typer.echo(text, err=True)) if as_json else typer.echo,
    )
    typer.echo(_json(summary.to_dict()) if as_json else summary.format())
