"""The `tactile-compliance` command. Thin: parse arguments, call library functions, print."""

# typer reads the parameters' annotations at runtime and needs Optional[X] on Python 3.10.
# ruff: noqa: UP045

from __future__ import annotations

import contextlib
import functools
import importlib
import json
import math
import re
import sys
from pathlib import Path
from typing import Annotated, Any, Literal, Optional

import typer
from typer.core import TyperArgument, TyperCommand, TyperGroup, TyperOption

from tactile_compliance import __version__
from tactile_compliance.devices import DEFAULT_DEVICE

#: The exceptions of the click that typer's commands run on: typer vendors its own click
#: (typer._click) in recent versions and used the click package before, so they are found
#: through typer's public BadParameter rather than by importing either.
_click_errors = importlib.import_module(typer.BadParameter.__module__)

#: Exit codes: 0 done; 1 a run failed (cells of a grid, a demo step) or writing failed
#: although the input was fine (a full disk or quota, in every command); 2 bad input (a
#: path, a file's content, a config key, an option), which includes click's usage
#: errors; 130 interrupted (Ctrl-C; re-run to continue).
EXIT_FAILED, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 1, 2, 130

_debug = False  # --debug: let errors raise with their traceback

# The choices the parser checks and the help lists. Each is a vocabulary of the library,
# written out here so that the command starts without importing the library (torch);
# tests/test_cli_help.py checks each against its home, named in the comment.
Fingers = Literal["markerless", "markers", "both"]  # data.raw_layout.FingerChoice
Condition = Literal["seen", "unseen"]  # config.SplitConfig.condition
Grouping = Literal["grasp", "per_sample"]  # config.SplitConfig.grouping
Inputs = Literal[  # data.inputs.InputStrategy
    "Image", "ImageF", "ImageFW", "ALL", "FW", "FWE", "DepthFW", "DepthALL"
]
Objective = Literal["last", "best"]  # training.hpo.objectives.OBJECTIVES
KeepCheckpoints = Literal["all", "best", "none"]  # runs.layout.KEEP_CHECKPOINTS
Backbone = Literal[  # training.pretrain.PRETRAIN_BACKBONES
    "resnet18", "resnet34", "resnet50", "vgg16", "top10nn-cnn"
]
DemoMode = Literal["full", "ci"]  # demo.PLANS and sim2real.PLANS
SimulateKind = Literal["gelsight", "shore-videos"]  # the two generators of `simulate`
PickleDtype = Literal["float16", "float32", "float64"]  # data.raw_layout.ALLOWED_DTYPES


def _exit_code(err: Exception) -> int | None:
    """The exit code of an expected error: 2 for bad input, 1 where the input was fine but
    writing failed (a full disk or quota, in every command); None for a bug.

    ValueError (ConfigError, pydantic's ValidationError, pyarrow's ArrowInvalid, the
    library's argument checks) and OSError (missing files, permissions) are decided without
    importing the library's error classes, which load torch, so that a config typo is
    reported at once."""
    if not isinstance(err, (ValueError, OSError)):
        from tactile_compliance.data.import_report import DataImportError, ImportWriteError
        from tactile_compliance.data.store import StoreError, StoreWriteError
        from tactile_compliance.inference.pretrained import OptionalDependencyError
        from tactile_compliance.models.backbones import BackboneWeightsError
        from tactile_compliance.training.experiment import ExperimentError
        from tactile_compliance.training.hpo import TuneError

        expected = (StoreError, DataImportError, ExperimentError, TuneError, BackboneWeightsError)
        # OptionalDependencyError's message says what to pip install.
        if not isinstance(err, (*expected, OptionalDependencyError)):
            return None
        if isinstance(err, (ImportWriteError, StoreWriteError)):
            return EXIT_FAILED
    return EXIT_FAILED if _disk_full(err) else EXIT_BAD_INPUT


def _disk_full(err: BaseException) -> bool:
    """Whether ``err`` (or what caused it) is a full disk, quota or file-size limit (ENOSPC,
    EDQUOT, EFBIG): the input was fine, writing failed, so exit code 1 whichever command
    it was."""
    import errno

    seen: BaseException | None = err
    for _ in range(8):  # a short chain: the library wraps an OSError at most twice
        if seen is None:
            return False
        if isinstance(seen, OSError) and seen.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
            return True
        # numpy's tofile and np.save to a real file report a short write without an errno.
        if isinstance(seen, OSError) and re.fullmatch(r"\d+ requested and \d+ written", str(seen)):
            return True
        seen = seen.__cause__ or seen.__context__
    return False


def _one_line_errors(command: Any) -> Any:
    """Wrap a command so that expected errors print one line and exit with their code."""

    @functools.wraps(command)
    def run(*args: Any, **kwargs: Any) -> Any:
        try:
            return command(*args, **kwargs)
        except (typer.Exit, typer.Abort, _click_errors.ClickException, BrokenPipeError):
            raise  # click handles these (a closed pipe, e.g. `| head`: exit 1 quietly)
        except KeyboardInterrupt:
            typer.secho("interrupted; re-run the same command to continue", err=True)
            raise typer.Exit(EXIT_INTERRUPTED) from None
        except Exception as err:
            code = None if _debug else _exit_code(err)
            if code is None:
                raise
            _fail(str(err) or type(err).__name__, code)

    return run


def _element_type(shown: str | None) -> str | None:
    """``<list[Path]>`` -> ``<path>``: a repeatable parameter takes one value per use."""
    if not shown:
        return shown
    return re.sub(r"^<list\[(\w+)\]>", lambda m: f"<{m[1].lower()}>", shown)


class _Option(TyperOption):
    """An option whose help shows a value only where it takes one: typer 0.29 shows
    ``<bool>`` for every flag (``--help`` too) and ``<list[str]>`` for a repeatable option,
    which takes one ``<str>`` per use."""

    def display_type_rich(self, ctx: Any) -> str | None:
        if self.is_flag or self.count:
            return None
        return _element_type(super().display_type_rich(ctx))


class _Argument(TyperArgument):
    """An argument shown as click shows one, ``STORE`` (``[STORE]`` when optional,
    ``STORE...`` for several), where typer writes ``{STORE}`` in the usage line. Click's
    public ``get_usage_pieces`` is overridden: typer's own hooks for it differ between
    versions (0.27 and 0.29 alike wrote the braces)."""

    def get_usage_pieces(self, ctx: Any) -> list[str]:
        name = self.metavar if self.required else f"[{self.metavar}]"
        return [f"{name}..." if self.nargs != 1 else name]

    def _rich_display_name(self) -> str:
        return f"{self.metavar}..." if self.nargs != 1 else self.metavar

    def display_type_rich(self, ctx: Any) -> str | None:
        return _element_type(super().display_type_rich(ctx))


def _plain_params(params: list[Any]) -> list[Any]:
    """The parameters with the display above. typer creates its parameter objects itself
    (no hook for a class), so each is given the subclass, which only overrides display."""
    for param in params:
        if type(param) is TyperOption:
            param.__class__ = _Option
        elif type(param) is TyperArgument:
            param.__class__ = _Argument
            if param.metavar is None:
                param.metavar = param.name.upper()
    return params


def _main_with_one_line_errors(main: Any, *args: Any, **kwargs: Any) -> Any:
    """Run click's ``main``; in standalone mode a usage error (an unknown option, a value
    that is not one of the choices, a missing argument) is one line on stderr, exit 2,
    like the commands' own errors, instead of typer's framed usage block."""
    if not kwargs.get("standalone_mode", True):
        return main(*args, **kwargs)
    try:
        code = main(*args, **{**kwargs, "standalone_mode": False})
    except _click_errors.ClickException as err:
        context = getattr(err, "ctx", None)
        hint = f" (see `{context.command_path} --help`)" if context is not None else ""
        # typer checks choices with pydantic, whose messages start with "Value error, ".
        message = err.format_message().replace("Value error, ", "")
        typer.secho(f"error: {message}{hint}", fg=typer.colors.RED, err=True)
        sys.exit(err.exit_code)
    except typer.Abort:
        typer.echo("aborted", err=True)
        sys.exit(EXIT_FAILED)
    # Without standalone mode click returns what the command returned (None) or the code
    # of a typer.Exit (--help, --version, _fail).
    sys.exit(code if isinstance(code, int) else 0)


class _Command(TyperCommand):
    """A command with the help display and the one-line usage errors above."""

    def get_params(self, ctx: Any) -> list[Any]:
        return _plain_params(super().get_params(ctx))

    def parse_args(self, ctx: Any, args: list[str]) -> list[str]:
        try:
            return super().parse_args(ctx, args)
        except _click_errors.MissingParameter as err:
            # One value only fills the last argument (`live CHECKPOINT... SOURCE`), so click
            # names the variadic one before it as missing, where the last was forgotten.
            if err.param is None or err.param.nargs != -1:
                raise
            last = [p for p in self.params if p.param_type_name == "argument"][-1]
            if err.param is last:
                raise
            raise _click_errors.UsageError(
                f"give {err.param.metavar}... and then {last.metavar}", ctx
            ) from None

    def main(self, *args: Any, **kwargs: Any) -> Any:
        return _main_with_one_line_errors(super().main, *args, **kwargs)


class _Group(TyperGroup):
    """A group with the help display and the one-line usage errors above, whose bare call
    prints its help and exits with 0 (click exits with 2)."""

    def get_params(self, ctx: Any) -> list[Any]:
        return _plain_params(super().get_params(ctx))

    def main(self, *args: Any, **kwargs: Any) -> Any:
        return _main_with_one_line_errors(super().main, *args, **kwargs)

    def parse_args(self, ctx: Any, args: list[str]) -> list[str]:
        if not args and self.no_args_is_help and not ctx.resilient_parsing:
            typer.echo(ctx.get_help(), color=ctx.color)
            ctx.exit(0)
        return super().parse_args(ctx, args)


class _Cli(typer.Typer):
    """A Typer app whose every command turns expected errors into one line (see above)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(cls=_Group, no_args_is_help=True, **kwargs)

    def command(self, *args: Any, **kwargs: Any) -> Any:
        register = super().command(*args, cls=_Command, **kwargs)

        def decorator(command: Any) -> Any:
            register(_one_line_errors(command))
            return command

        return decorator


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


def _fail(message: str, code: int = EXIT_FAILED) -> None:
    typer.secho(f"error: {message}", fg=typer.colors.RED, err=True)
    raise typer.Exit(code)


def _json(document: Any) -> str:
    """JSON as the commands print (--json) and write it: indented, paths as strings."""
    return json.dumps(document, indent=2, default=str)


def _size_option(size: str | None) -> tuple[int, int] | None:
    if size is None:  # no import: image_ops loads OpenCV, which `train` does not need yet
        return None
    from tactile_compliance.data.image_ops import parse_size

    try:
        return parse_size(size)
    except ValueError as err:
        raise typer.BadParameter(str(err)) from err


def _version_callback(value: bool) -> None:
    if value:
        typer.echo(f"tactile-compliance {__version__}")
        raise typer.Exit()


@app.callback()
def main(
    version: Annotated[
        bool,
        typer.Option(
            "--version", callback=_version_callback, is_eager=True, help="Show the version."
        ),
    ] = False,
    debug: Annotated[
        bool, typer.Option("--debug", help="Show the traceback of an error, not one line.")
    ] = False,
) -> None:
    """Estimate an object's Young's modulus from one GelSight grasp."""
    global _debug
    _debug = debug


@app.command()
def simulate(
    out: Annotated[Path, typer.Option(help="Directory to write the raw dataset to.")],
    kind: Annotated[
        SimulateKind,
        typer.Option(
            help="gelsight (the Young's-modulus dataset layout) or shore-videos (the "
            "Shore-hardness press videos)."
        ),
    ] = "gelsight",
    objects: Annotated[
        Optional[int],
        typer.Option(
            min=1,
            help="Number of objects (default: 286 like the real table; "
            "40 silicone samples for shore-videos).",
        ),
    ] = None,
    object_table: Annotated[
        Optional[Path],
        typer.Option(
            help="Simulate exactly the objects of a table in the "
            "real CSV format (dataset_objects_and_compliance.csv)."
        ),
    ] = None,
    grasps_per_object: Annotated[
        Optional[int], typer.Option(min=1, help="Grasps (presses for videos) per object.")
    ] = None,
    seed: Annotated[
        int, typer.Option(min=0, help="Base seed; same seed, byte-identical output.")
    ] = 0,
    size: Annotated[str, typer.Option(help="Frame size HxW in pixels.")] = "250x350",
    dtype: Annotated[PickleDtype, typer.Option(help="Pickle dtype of images and depths.")] = (
        "float16"
    ),
    workers: Annotated[
        Optional[int], typer.Option(min=1, help="Processes (default: all CPUs).")
    ] = None,
    rig: Annotated[
        str,
        typer.Option(
            help="The gripper rig: dataset (the public dataset's, ~60 N presses), wedge-2023 "
            "(the lab's 2023 Wedge rig, ~25 N presses and a compliant mount; docs/synthetic.md) "
            "or a rig file that calibrate-rig wrote."
        ),
    ] = "dataset",
    as_json: Annotated[bool, typer.Option("--json", help="Print the report as JSON.")] = False,
) -> None:
    """Generate a physically grounded synthetic dataset in the real raw layout.

    The output is what `import burgess` (or, with --kind shore-videos, `import yuan`)
    reads. Interrupted runs resume: finished objects are kept.
    """
    from tactile_compliance.synthetic import generate_burgess_tree, generate_shore_videos

    image_size = _size_option(size)
    assert image_size is not None
    if kind == "gelsight":
        options = {"dtype": dtype, "rig": rig} | ({"workers": workers} if workers else {})
        report = generate_burgess_tree(
            out,
            n_objects=objects,
            object_table=object_table,
            grasps_per_object=grasps_per_object,
            seed=seed,
            image_size=image_size,
            **options,
        )
    else:  # shore-videos
        if object_table is not None:
            raise typer.BadParameter("--object-table applies to --kind gelsight only")
        if rig != "dataset":
            raise typer.BadParameter("--rig applies to --kind gelsight only")
        report = generate_shore_videos(
            out,
            n_objects=objects or 40,
            presses_per_object=grasps_per_object or 3,
            seed=seed,
            image_size=image_size,
        )
    importer = "burgess" if kind == "gelsight" else "yuan"
    next_step = f"Next: tactile-compliance import {importer} {out} --out STORE"
    typer.echo(_json(report.to_dict()) if as_json else f"{report.format()}\n{next_step}")


@app.command()
def info(
    store: Annotated[Path, typer.Argument(help="GraspStore directory.")],
    as_json: Annotated[bool, typer.Option("--json", help="Print machine-readable JSON.")] = False,
) -> None:
    """Show what a store holds: counts by material and shape, modulus range, resolution.

    A store that does not validate gets every problem listed, and exit code 2."""
    from tactile_compliance.data.store import GraspStore, store_problems

    problems = store_problems(store)
    if problems:
        for problem in problems[:-1]:
            typer.secho(f"error: {problem}", fg=typer.colors.RED, err=True)
        _fail(problems[-1], EXIT_BAD_INPUT)
    summary = GraspStore.open(store).summary()
    if as_json:
        typer.echo(_json(summary))
        return
    height, width = summary["image_size"]
    lines = [
        f"Store       {summary['path']}  (source: {summary['source']})",
        f"Samples     {summary['num_samples']}  objects {summary['num_objects']}  "
        f"grasps {summary['num_grasps']}",
        f"Frames      3 x {height} x {width} x 3 ({summary['channel_order']}, uint8), "
        f"{summary['frames_bytes'] / 1e6:.1f} MB",
    ]
    if summary["num_samples"]:
        lines.append(
            f"Modulus     {summary['modulus_pa_min']:.3g} .. {summary['modulus_pa_max']:.3g} Pa"
        )
    lines.append(
        f"Inputs      force/width: {summary['has_force_width']}  "
        f"estimates: {summary['has_estimates']}"
    )
    depth = summary["depth"]
    lines.append(
        f"Depth       3 x {depth['size'][0]} x {depth['size'][1]} (float16 mm), "
        f"{depth['samples_with_depth']} samples with depth, {depth['bytes'] / 1e6:.1f} MB"
        if depth
        else "Depth       none (imported without depth maps)"
    )
    for key in ("fingers", "materials", "shapes"):
        counts = ", ".join(f"{name} {count}" for name, count in summary[key].items())
        lines.append(f"{key.capitalize():<11} {counts}")
    typer.echo("\n".join(lines))


def _is_import_report(path: Path) -> bool:
    data = json.loads(path.read_text(encoding="utf-8"))
    return isinstance(data, dict) and {"source_dir", "samples_imported"} <= data.keys()


def _run_import(run: object, report_json: Path | None, as_json: bool = False) -> None:
    from tactile_compliance.outputs import check_output_file

    if report_json is not None:  # checked first: a refused path must cost no import
        check_output_file(report_json, "import report", _is_import_report, option="--report")
    report = run()  # type: ignore[operator]
    typer.echo(_json(report.to_dict()) if as_json else report.format())
    if report_json is not None:
        from tactile_compliance.outputs import atomic_file

        with atomic_file(report_json) as handle:
            handle.write(_json(report.to_dict()) + "\n")


SizeOption = Annotated[
    Optional[str], typer.Option("--size", help="Resize frames to HxW pixels, e.g. 224x224.")
]
StrictOption = Annotated[bool, typer.Option(help="Stop at the first problem.")]
OverwriteOption = Annotated[bool, typer.Option(help="Replace an existing store.")]
ReportOption = Annotated[
    Optional[Path], typer.Option("--report", help="Also write the import report as JSON.")
]
OutOption = Annotated[Path, typer.Option("--out", help="Store directory to create.")]
ImportJsonOption = Annotated[
    bool, typer.Option("--json", help="Print the import report as JSON (as --report writes it).")
]


@import_app.command("burgess")
def import_burgess_command(
    src: Annotated[
        Path, typer.Argument(help="The unpacked gelsight_youngs_modulus_dataset/ directory.")
    ],
    out: OutOption,
    objects: Annotated[
        Optional[Path],
        typer.Option(
            help="Object table CSV (dataset_objects_and_compliance.csv); "
            "labels come from it instead of metadata.json."
        ),
    ] = None,
    fingers: Annotated[
        Fingers, typer.Option(help="markerless (RGB.pkl), markers (RGB_markers.pkl) or both.")
    ] = "both",
    size: SizeOption = None,
    strict: StrictOption = False,
    overwrite: OverwriteOption = False,
    report_json: ReportOption = None,
    depth: Annotated[
        bool,
        typer.Option(
            help="Keep the depth maps (float16 mm, a quarter of the frame size per side; "
            "about 4 % more disk), the target of `pretrain`."
        ),
    ] = True,
    as_json: ImportJsonOption = False,
) -> None:
    """Import the GelSight Young's-modulus dataset layout (real or simulated)."""
    from tactile_compliance.data.burgess import import_burgess

    image_size = _size_option(size)
    _run_import(
        lambda: import_burgess(
            src,
            out,
            object_table=objects,
            fingers=fingers,
            image_size=image_size,
            strict=strict,
            overwrite=overwrite,
            depth=depth,
        ),
        report_json,
        as_json,
    )


@import_app.command("yuan")
def import_yuan_command(
    src: Annotated[Path, typer.Argument(help="Directory of {SHAPE}_{hardness}_{n}.avi videos.")],
    out: OutOption,
    size: SizeOption = None,
    strict: StrictOption = False,
    overwrite: OverwriteOption = False,
    report_json: ReportOption = None,
    as_json: ImportJsonOption = False,
) -> None:
    """Import the Shore-hardness press videos (Yuan et al. 2017)."""
    from tactile_compliance.data.yuan import import_yuan

    image_size = _size_option(size)
    _run_import(
        lambda: import_yuan(src, out, image_size=image_size, strict=strict, overwrite=overwrite),
        report_json,
        as_json,
    )


def _load_config(config: str, options: list[str], overrides: list[str] | None) -> object:
    """The config with the command's options applied, then the --set overrides (which win)."""
    from tactile_compliance.config import load_config

    return load_config(config, [*options, *(overrides or [])])


ConfigArg = Annotated[
    str, typer.Option("--config", "-c", help="YAML config file or packaged preset name.")
]
FilterConfigOption = Annotated[
    str, typer.Option("--config", "-c", help="Config whose filters and split options apply.")
]
DeviceOption = Annotated[
    str,
    typer.Option(help="auto (a CUDA GPU when torch sees one, else the CPU), cpu, cuda or cuda:N."),
]
SetOption = Annotated[
    Optional[list[str]],
    typer.Option(
        "--set",
        "-s",
        metavar="KEY=VALUE",
        help="Override a config value: --set training.lr=1e-4 (repeatable).",
    ),
]


JsonOption = Annotated[bool, typer.Option("--json", help="Print the result as JSON.")]


@app.command()
def presets(as_json: JsonOption = False) -> None:
    """List the packaged presets: experiment grids and training configurations."""
    from tactile_compliance.config import list_presets
    from tactile_compliance.training.experiment_file import experiment_preset_descriptions

    if as_json:
        payload = {"experiments": experiment_preset_descriptions(), "configs": list_presets()}
        typer.echo(_json(payload))
        return
    typer.echo("Experiment presets (tactile-compliance experiment NAME [--quick]):")
    for name, description in experiment_preset_descriptions().items():
        typer.echo(f"  {name:<16} {description}")
    typer.echo("Configuration presets (--config NAME):")
    for name in list_presets():
        typer.echo(f"  {name}")


@app.command()
def split(
    store: Annotated[Path, typer.Argument(help="GraspStore directory.")],
    out: Annotated[Path, typer.Option(help="Where to write the split JSON.")],
    condition: Annotated[
        Condition, typer.Option(help="seen, or unseen (split by object).")
    ] = "seen",
    grouping: Annotated[
        Grouping,
        typer.Option(help="How seen splits: by grasp, or per_sample (the paper's, leaks)."),
    ] = "grasp",
    seed: Annotated[int, typer.Option(min=0, help="Random seed of the split.")] = 0,
    config: FilterConfigOption = "default",
    overrides: SetOption = None,
    as_json: Annotated[
        bool, typer.Option("--json", help="Print the filter report and the split as JSON.")
    ] = False,
) -> None:
    """Filter a store and draw a train/val/test split; print what it contains."""
    from tactile_compliance.data.preprocess import filter_samples
    from tactile_compliance.data.splits import make_split_from_config, summarise_split
    from tactile_compliance.data.store import GraspStore

    options = [f"data.store={store}", f"split.condition={condition}", f"seed={seed}"]
    cfg = _load_config(config, [*options, f"split.grouping={grouping}"], overrides)
    samples, report = filter_samples(GraspStore.open(store).samples, cfg)
    drawn = make_split_from_config(samples, cfg)
    drawn.save(out)
    summary = summarise_split(samples, drawn)
    payload = {"filter": report.to_dict(), "split": summary.to_dict(), "out": str(out)}
    typer.echo(_json(payload) if as_json else f"{report}\n\n{summary}\n\nSplit written to {out}")


def _split_and_store(first: Path, second: Path) -> tuple[Path, Path]:
    """(split file, store directory) from `split-summary`'s two arguments, in either order;
    a missing path or two of one kind is a ValueError naming them."""
    usage = "split-summary takes a split JSON file and a store directory"
    for path, other in ((first, second), (second, first)):
        if not path.exists():
            what = "store directory" if other.is_file() else "split file"
            raise ValueError(f"{path}: no such {what} ({usage})")
    if first.is_file() == second.is_file():
        kind = "files" if first.is_file() else "directories"
        raise ValueError(f"{usage}; {first} and {second} are both {kind}")
    return (first, second) if first.is_file() else (second, first)


@app.command("split-summary")
def split_summary(
    split_file: Annotated[Path, typer.Argument(help="A split JSON (from `split` or a run).")],
    store: Annotated[Path, typer.Argument(help="The store the split was drawn from.")],
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON.")] = False,
) -> None:
    """Show what a saved split contains (counts, materials, shapes, leakage checks).

    The split (a file) and the store (a directory) may come in either order."""
    from tactile_compliance.data.splits import Split, summarise_split
    from tactile_compliance.data.store import GraspStore

    split_file, store = _split_and_store(split_file, store)
    split = Split.load(split_file)  # the small file first: its mistakes are reported first
    summary = summarise_split(GraspStore.open(store).samples, split)
    typer.echo(_json(summary.to_dict()) if as_json else str(summary))


@app.command()
def train(
    config: ConfigArg = "default",
    overrides: SetOption = None,
    run_dir: Annotated[
        Optional[Path],
        typer.Option(
            "--out", help="Run directory to write (default: the config's output_dir/NAME)."
        ),
    ] = None,
    overwrite: Annotated[bool, typer.Option(help="Retrain a finished run.")] = False,
    size: Annotated[
        Optional[str],
        typer.Option(help="Frame size HxW the model sees (data.image_size; a --set of it wins)."),
    ] = None,
    as_json: Annotated[
        bool, typer.Option("--json", help="Print the run's result (metrics.json) as JSON.")
    ] = False,
    keep_checkpoints: Annotated[
        KeepCheckpoints,
        typer.Option(
            help="What the finished run keeps: all (best.pt + checkpoints/last.ckpt, which "
            "only resumes an interrupted run), best (best.pt) or none."
        ),
    ] = "all",
    verbose: Annotated[
        bool,
        typer.Option(
            "--verbose",
            "-v",
            help="Also show Lightning's start-up messages (GPU available, tips, checkpoint "
            "loading) and its deprecation and housekeeping warnings.",
        ),
    ] = False,
) -> None:
    """Train one configuration and evaluate its best epoch on the test split.

    Writes a run directory (config, split, checkpoints, per-epoch log, predictions,
    metrics.json). Re-running resumes an interrupted run or returns a finished one.
    """
    image_size = _size_option(size)
    sized = [f"data.image_size=[{image_size[0]},{image_size[1]}]"] if image_size else []
    # The config first, before torch loads: a typo is reported at once.
    cfg = _load_config(config, sized, overrides)
    from tactile_compliance.training.train import train as train_run

    result = train_run(  # --json: stdout holds the JSON only, so no progress bar
        cfg,  # type: ignore[arg-type]
        run_dir=run_dir,
        overwrite=overwrite,
        verbose=verbose,
        progress=not as_json,
    )
    from tactile_compliance.runs.layout import prune_checkpoints

    prune_checkpoints(result["run_dir"], keep_checkpoints)
    if as_json:
        typer.echo(_json(result))
        return
    test, median = result["test"], result["reference"]["median"]
    typer.echo(
        f"{result['run_name']}: best epoch {result['best_epoch']}, "
        f"test log10 accuracy {test['log10_accuracy']:.3f}, N-MSE {test['nmse']:.4f} "
        f"(median predictor {median['nmse']:.4f})\nRun directory: {result['run_dir']}"
    )


@app.command()
def pretrain(
    store: Annotated[Path, typer.Argument(help="GraspStore with depth maps (import --depth).")],
    backbone: Annotated[
        Backbone,
        typer.Option(help="resnet18/34/50 (Res-Tf), vgg16 (VGG-LSTM) or top10nn-cnn (Top10NN)."),
    ],
    out: Annotated[Path, typer.Option(help="The backbone weights file to write.")],
    split_file: Annotated[
        Optional[Path],
        typer.Option("--split", help="Use this split's training objects (a split JSON)."),
    ] = None,
    condition: Annotated[
        Condition,
        typer.Option(help="Without --split: draw this condition's split (unseen: by object)."),
    ] = "unseen",
    seed: Annotated[
        int, typer.Option(min=0, help="Seed of the split (without --split) and init.")
    ] = 0,
    config: FilterConfigOption = "default",
    overrides: SetOption = None,
    epochs: Annotated[int, typer.Option(min=1, help="Maximum epochs.")] = 30,
    batch_size: Annotated[int, typer.Option(min=1, help="Samples (3 frames each) per batch.")] = 16,
    lr: Annotated[float, typer.Option(min=0, help="AdamW learning rate.")] = 1e-3,
    patience: Annotated[
        int, typer.Option(min=0, help="Early-stopping patience (epochs, 0: off).")
    ] = 4,
    size: Annotated[
        Optional[str],
        typer.Option(help="Frame size HxW (default: the size the backbone's model uses)."),
    ] = None,
    overwrite: Annotated[bool, typer.Option(help="Replace a pretrained weights file.")] = False,
    device: DeviceOption = DEFAULT_DEVICE,
    as_json: Annotated[
        bool,
        typer.Option(
            "--json",
            help="Print the weights file, its provenance (settings, split, losses per epoch) "
            "and the train overrides that use it as JSON.",
        ),
    ] = False,
) -> None:
    """Pretrain a backbone to predict depth maps and contact masks from the difference images.

    Only the training objects of the split are used (never a test or validation object).
    The result loads with --set model.backbone_weights=OUT. Re-running resumes after the
    last finished epoch.
    """
    _refuse_unread_overrides(overrides)
    options = [f"data.store={store}", f"split.condition={condition}", f"seed={seed}"]
    cfg = _load_config(config, options, overrides)  # before torch loads
    from tactile_compliance.training.pretrain import PretrainSettings
    from tactile_compliance.training.pretrain import pretrain as run_pretrain

    settings = PretrainSettings(
        backbone=backbone,
        epochs=epochs,
        batch_size=batch_size,
        lr=lr,
        patience=patience,
        image_size=_size_option(size),
    )
    result = run_pretrain(
        cfg,  # type: ignore[arg-type]
        settings,
        out,
        split_file=split_file,
        overwrite=overwrite,
        device=device,
        progress=not as_json,
    )
    record = result.provenance
    use = [
        f"data.store={store}",
        f"model.name={record['model']}",
        f"model.backbone_weights={result.out}",
        "model.freeze_backbone=true",
    ]
    if as_json:
        payload = {
            "out": str(result.out),
            "existing": result.existing,
            "resumed_from_epoch": result.resumed_from_epoch,
            "provenance": record,
            "train_overrides": use,
        }
        typer.echo(_json(payload))
        return
    if result.existing:
        typer.echo(f"{out} is already pretrained (pass --overwrite to train it again).")
    typer.echo(
        f"{record['backbone']}: {record['epochs']} epochs (best {record['best_epoch']}) on "
        f"{record['n_train_samples']} samples of {record['n_train_objects']} training objects, "
        f"validation depth MSE {record['first_depth_loss_mm2']:.4g} -> "
        f"{record['final_depth_loss_mm2']:.4g} mm², {record['seconds']:.0f} s\n"
        f"Weights: {result.out}\nUse them: tactile-compliance train "
        + " ".join(f"--set {override}" for override in use)
    )


#: The config sections `pretrain` never reads: its model is --backbone, its training
#: --epochs, --batch-size, --lr, --patience and --device.
_PRETRAIN_UNREAD = ("model", "training", "sampling", "inputs", "output_dir")


def _refuse_unread_overrides(overrides: list[str] | None) -> None:
    """Refuse a `pretrain --set` of a key pretraining never reads (it would be accepted
    and have no effect)."""
    for override in overrides or []:
        key = override.split("=", 1)[0].strip()
        if key.split(".", 1)[0] in _PRETRAIN_UNREAD:
            raise typer.BadParameter(
                f"--set {key}: pretrain does not read {key} (it reads data, filters, split, "
                f"augmentation and seed; the backbone is --backbone, the training --epochs, "
                f"--batch-size, --lr, --patience and --device)"
            )


BackboneWeightsOption = Annotated[
    Optional[Path],
    typer.Option(
        "--weights",
        help="Frozen-backbone checkpoints store the head only: a local copy of the "
        "backbone's weights file (e.g. the ImageNet .pth on an offline machine).",
    ),
]


@app.command()
def evaluate(
    run_dir: Annotated[Path, typer.Argument(help="A finished run directory.")],
    store: Annotated[Optional[Path], typer.Option(help="Evaluate on this store instead.")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON.")] = False,
    weights: BackboneWeightsOption = None,
    device: DeviceOption = DEFAULT_DEVICE,
) -> None:
    """Recompute metrics (overall, per material, shape, soft/hard) from a run's checkpoint."""
    from tactile_compliance.evaluation.evaluate import evaluate_run

    evaluation = evaluate_run(run_dir, store, backbone_weights=weights, device=device)
    groups = evaluation.groups
    # R^2 is undefined (NaN) for a group whose true moduli are all equal: said, not shown
    # as a number (JSON: null).
    undefined = "r2" in groups.columns and bool(groups["r2"].isna().any())
    if as_json:
        records = groups.astype(object).where(groups.notna(), None).to_dict(orient="records")
        metrics = {
            k: None if isinstance(v, float) and v != v else v for k, v in evaluation.metrics.items()
        }
        typer.echo(_json({"metrics": metrics, "groups": records}))
        return
    typer.echo(groups.to_string(index=False, float_format=lambda v: f"{v:.4f}", na_rep="n/a"))
    if undefined:
        typer.echo(
            "r2 n/a: the group's true moduli are all equal, so there is no variance to explain"
        )


WorkersOption = Annotated[
    int, typer.Option("--workers", "-w", min=1, help="Local Dask worker processes.")
]
SchedulerOption = Annotated[
    Optional[str],
    typer.Option(
        "--scheduler",
        help="Address (tcp://host:8786) or scheduler file of a "
        "running Dask scheduler, e.g. one started by dask-jobqueue on SLURM/PBS.",
    ),
]
StoreOption = Annotated[
    Optional[Path],
    typer.Option("--store", help="GraspStore for every run (default: the preset's)."),
]
OutputDirOption = Annotated[
    Optional[Path],
    typer.Option("--out", help="Where run directories go.", show_default="the preset's"),
]
QuickOption = Annotated[
    bool, typer.Option("--quick", help="The preset's small variant for a 2-core CPU.")
]
ThreadsOption = Annotated[
    Optional[int],
    typer.Option(min=1, help="Torch threads per run (default 1: one run per worker and core)."),
]
ConditionOption = Annotated[
    Optional[Condition],
    typer.Option(help="Split condition (unseen: by object).", show_default="the config's"),
]
ObjectiveOption = Annotated[
    Objective,
    typer.Option(
        help="A trial's cost: the validation N-MSE of its last epoch (as in the paper; the "
        "trial trains its whole budget) or of its best epoch (with early stopping)."
    ),
]
InputsOption = Annotated[Inputs, typer.Option(help="Input strategy whose search space is used.")]
TuneJsonOption = Annotated[
    bool,
    typer.Option("--json", help="Print the best values, their cost and the files written as JSON."),
]


@app.command()
def experiment(
    preset: Annotated[str, typer.Argument(help="Experiment preset (see `presets`) or YAML file.")],
    quick: QuickOption = False,
    seeds: Annotated[
        Optional[int], typer.Option(min=1, help="Number of seeds (0..N-1); default: the preset's.")
    ] = None,
    store: StoreOption = None,
    overrides: SetOption = None,
    where: Annotated[
        Optional[list[str]],
        typer.Option(
            metavar="KEY=VALUE",
            help="Run only matching cells: --where model.name=res_tf (repeatable).",
        ),
    ] = None,
    workers: WorkersOption = 1,
    scheduler: SchedulerOption = None,
    output_dir: OutputDirOption = None,
    results: Annotated[
        Optional[Path], typer.Option(help="Results store directory (default: runs/results).")
    ] = None,
    threads: ThreadsOption = None,
    keep_checkpoints: Annotated[
        KeepCheckpoints,
        typer.Option(help="What a finished run keeps: best (best.pt), all (+ last.ckpt), none."),
    ] = "best",
    retry_failed: Annotated[
        bool, typer.Option(help="Re-run cells recorded as failed (--no-retry-failed skips them).")
    ] = True,
    dry_run: Annotated[
        bool, typer.Option("--dry-run", help="List the cells and their status; run nothing.")
    ] = False,
    as_json: Annotated[
        bool,
        typer.Option(
            "--json",
            help="Print the summary (counts, failures, mean +- std per configuration) or, "
            "with --dry-run, the cells as JSON.",
        ),
    ] = False,
) -> None:
    """Run an experiment grid (models x inputs x conditions x sampling x seeds) on Dask.

    Every cell goes through `train`; each result is a row of the results store.
    Re-running skips finished cells and retries failed or interrupted ones. Exits with
    status 1 when a cell failed and 130 when interrupted (re-run to continue).
    """
    from tactile_compliance.training.experiment import plan_experiment, run_experiment

    common = dict(
        quick=quick,
        seeds=seeds,
        store=store,
        overrides=overrides or [],
        where=where or [],
        output_dir=output_dir,
        results=results,
    )
    if dry_run:
        plan = plan_experiment(preset, **common)  # type: ignore[arg-type]
        typer.echo(_json(plan.to_dict()) if as_json else plan.format())
        return
    try:
        summary = run_experiment(
            preset,
            workers=workers,
            scheduler=scheduler,
            threads=threads,
            keep_checkpoints=keep_checkpoints,
            retry_failed=retry_failed,
            **common,  # type: ignore[arg-type]
        )
    except KeyboardInterrupt:  # the summary is already on stderr
        raise typer.Exit(EXIT_INTERRUPTED) from None
    typer.echo(_json(summary.to_dict()) if as_json else summary.format())
    if summary.failed:
        _fail(f"{summary.failed} cell(s) failed (recorded with their errors); re-run to retry")


@app.command()
def tune(
    model: Annotated[str, typer.Argument(help="A registered model (top10nn, vgg_lstm, ...).")],
    inputs: InputsOption = "ALL",
    config: Annotated[
        str, typer.Option("--config", "-c", help="Base config or experiment preset.")
    ] = "default",
    quick: QuickOption = False,
    store: StoreOption = None,
    overrides: SetOption = None,
    trials: Annotated[int, typer.Option(min=1, help="SMAC trials.")] = 132,
    min_epochs: Annotated[int, typer.Option(min=1, help="Smallest Hyperband budget (epochs).")] = 5,
    max_epochs: Annotated[int, typer.Option(min=1, help="Largest Hyperband budget (epochs).")] = 50,
    eta: Annotated[int, typer.Option(min=2, help="Hyperband's reduction factor.")] = 3,
    objective: ObjectiveOption = "last",
    condition: ConditionOption = None,
    seed: Annotated[int, typer.Option(min=0, help="SMAC seed.")] = 0,
    workers: WorkersOption = 1,
    scheduler: SchedulerOption = None,
    threads: ThreadsOption = None,
    output_dir: OutputDirOption = None,
    overwrite: Annotated[bool, typer.Option(help="Start the search afresh.")] = False,
    as_json: TuneJsonOption = False,
) -> None:
    """Tune a model's hyperparameters with SMAC3 (Hyperband over epochs, val N-MSE).

    The defaults are the paper's search: 132 trials, 5-50 epochs, each trial scored on its
    last epoch. Resumes from SMAC's run history; writes best.yaml, usable by `train` and
    `experiment`.
    """
    _run_search("tune", dict(locals()))


@app.command("tune-balance")
def tune_balance(
    config: Annotated[
        str, typer.Option("--config", "-c", help="Experiment preset or config to tune.")
    ] = "table2",
    quick: QuickOption = False,
    store: StoreOption = None,
    overrides: SetOption = None,
    epochs: Annotated[
        Optional[int],
        typer.Option(
            min=1, help="Epochs per model and trial.", show_default="10; 50 with --paper-budget"
        ),
    ] = None,
    trials: Annotated[
        Optional[int],
        typer.Option(min=1, help="SMAC trials.", show_default="30; 132 with --paper-budget"),
    ] = None,
    paper_budget: Annotated[
        bool,
        typer.Option(
            "--paper-budget",
            help="The paper's budget: 132 trials of 50 epochs per model (explicit "
            "--epochs / --trials still win).",
        ),
    ] = False,
    objective: ObjectiveOption = "last",
    models: Annotated[
        str, typer.Option(help="Comma-separated models whose mean val N-MSE is the cost.")
    ] = "top10nn,vgg_lstm,res_tf",
    inputs: Annotated[Inputs, typer.Option(help="Input strategy of every model.")] = "ALL",
    condition: Annotated[
        Condition, typer.Option(help="Split condition (unseen: by object).")
    ] = "seen",
    seed: Annotated[int, typer.Option(min=0, help="SMAC seed.")] = 0,
    workers: WorkersOption = 1,
    scheduler: SchedulerOption = None,
    threads: ThreadsOption = None,
    output_dir: OutputDirOption = None,
    overwrite: Annotated[bool, typer.Option(help="Start the search afresh.")] = False,
    as_json: TuneJsonOption = False,
) -> None:
    """Tune the balance threshold t_balance in [0, 1] with SMAC3.

    Cost of a value: the mean validation N-MSE of the three models after a fixed number
    of epochs (of the last epoch, as in the paper, or --objective best). The default
    budget, 30 trials of 10 epochs, is sized for a CPU; --paper-budget is the paper's
    132 x 50. Writes a config with the best t_balance.
    """
    options = dict(locals())
    options["models"] = [m.strip() for m in models.split(",") if m.strip()]
    _run_search("tune_balance", options)


def _run_search(name: str, options: dict[str, Any]) -> None:
    """Run the SMAC search ``training.hpo.<name>`` and print its result.

    ``options`` are the command's parameters, which are named like the search function's
    keyword arguments. Expected errors become one line.
    """
    from tactile_compliance.training import hpo

    options["overrides"] = options["overrides"] or []
    as_json = options.pop("as_json")
    result = getattr(hpo, name)(**options)
    typer.echo(_json(result.to_dict()) if as_json else result.format())


@app.command()
def adapt(
    model: Annotated[
        Path, typer.Argument(help="A simulation-trained checkpoint (best.pt or a run directory).")
    ],
    reference_store: Annotated[
        Path,
        typer.Argument(
            help="A store of grasps of reference objects of known modulus on your rig "
            "(`record`, then `import burgess`)."
        ),
    ],
    out: Annotated[Path, typer.Option(help="Directory for best.pt and adapt.json.")],
    ridge: Annotated[
        float,
        typer.Option(
            min=0.0,
            help="How strongly the calibration's slope is pulled towards 1 (a pure shift); "
            "docs/inference.md.",
        ),
    ] = 1.0,
    device: DeviceOption = DEFAULT_DEVICE,
    as_json: Annotated[bool, typer.Option("--json", help="Print the summary as JSON.")] = False,
) -> None:
    """Adapt a model to your rig from grasps of reference objects of known modulus: an
    output calibration in log10 space, fitted on them, with leave-one-object-out scores.
    Writes OUT/best.pt, which `predict` and `live` take (they apply the calibration)."""
    from tactile_compliance.inference.adapt import adapt_model

    summary = adapt_model(model, reference_store, out, ridge=ridge, device=device)
    typer.echo(_json(summary.to_dict()) if as_json else summary.format())


@app.command()
def predict(
    checkpoint: Annotated[Path, typer.Argument(help="best.pt of a run, or the run directory.")],
    source: Annotated[
        Path, typer.Argument(help="A GraspStore, a raw grasp/object directory, or a video.")
    ],
    as_json: Annotated[bool, typer.Option("--json", help="Print the full JSON report.")] = False,
    fingers: Annotated[
        Fingers, typer.Option(help="Which finger's images of a raw directory.")
    ] = "both",
    device: DeviceOption = DEFAULT_DEVICE,
    weights: BackboneWeightsOption = None,
    calibration: Annotated[
        Optional[Path],
        typer.Option(help="Sensor calibration JSON for a rosbag: source (from `calibrate`)."),
    ] = None,
) -> None:
    """Estimate Young's modulus for every grasp of a store, raw directory or video.

    A rosbag:BAG source is one grasp: the final estimate `live` gives on it."""
    if str(source).startswith("rosbag:"):
        _predict_bag(checkpoint, str(source), calibration, device, weights, as_json)
        return
    if calibration is not None:
        raise typer.BadParameter("--calibration is for a rosbag: source")
    from tactile_compliance.inference.predict import format_predictions, predict_path

    result = predict_path(
        checkpoint, source, device=device, fingers=fingers, backbone_weights=weights
    )
    typer.echo(_json(result) if as_json else format_predictions(result))


def _predict_bag(
    checkpoint: Path,
    spec: str,
    calibration: Path | None,
    device: str,
    weights: Path | None,
    as_json: bool,
) -> None:
    """`predict CHECKPOINT rosbag:BAG`: the bag's grasp through `live`'s loop, its final
    estimate printed (warnings and skipped frames on stderr)."""
    from tactile_compliance.inference.live import format_live_event, live_estimates, load_members

    members = load_members([checkpoint], device=device, backbone_weights=weights)
    frames, sensor = _open_source(spec, calibration, None, None)
    with frames:
        for event in live_estimates(members, frames, _readings(None, frames), calibration=sensor):
            if event["event"] == "no_estimate":
                _fail(f"no estimate: {event['reason']}", EXIT_BAD_INPUT)
            if event["event"] in ("warning", "skipped"):
                typer.echo(format_live_event(event), err=True)
            elif event.get("final"):
                event = {"source": frames.name, **event}
                text = f"{frames.name}: {format_live_event(event)}"
                typer.echo(_json(event) if as_json else text)
                return
    _fail("no estimate", EXIT_BAD_INPUT)  # pragma: no cover - live ends with final or none


@app.command()
def export(
    checkpoint: Annotated[Path, typer.Argument(help="best.pt of a run, or the run directory.")],
    onnx: Annotated[Optional[Path], typer.Option(help="The .onnx file to write.")] = None,
    safetensors: Annotated[
        Optional[Path],
        typer.Option(
            help="Directory to write: model.safetensors + config.json + a model card README.md."
        ),
    ] = None,
    weights: BackboneWeightsOption = None,
    license: Annotated[
        str,
        typer.Option(
            help="The model card's licence for --safetensors (an SPDX id such as mit or "
            "cc-by-4.0); other: the weights follow the licence of their training data."
        ),
    ] = "other",
    as_json: Annotated[
        bool, typer.Option("--json", help="Print what was written (files, sizes, checks) as JSON.")
    ] = False,
) -> None:
    """Export a checkpoint to ONNX (dynamic batch size) and/or a safetensors directory.

    The ONNX graph is checked against PyTorch with onnxruntime (the max abs difference is
    printed). The safetensors directory loads with ComplianceEstimator.from_pretrained.
    """
    from tactile_compliance.inference.export import (
        check_onnx_output,
        export_onnx,
        export_safetensors,
        format_export_report,
        format_safetensors_report,
        require_onnx,
    )

    if onnx is None and safetensors is None:
        raise typer.BadParameter("give --onnx FILE, --safetensors DIR or both")
    if onnx is not None:  # before the safetensors directory is written
        require_onnx()
        check_onnx_output(onnx)
    reports: dict[str, Any] = {}
    if safetensors is not None:
        written = export_safetensors(
            checkpoint, safetensors, backbone_weights=weights, license=license
        )
        reports["safetensors"] = {k: v for k, v in written.items() if k != "config"}
        if not as_json:
            typer.echo(format_safetensors_report(written))
    if onnx is not None:
        try:
            result = export_onnx(checkpoint, onnx, backbone_weights=weights)
        except RuntimeError as err:  # the graph does not match PyTorch: the export failed
            _fail(str(err))
        reports["onnx"] = result
        if not as_json:
            typer.echo(format_export_report(result))
    if as_json:
        typer.echo(_json(reports))


SOURCE_HELP = (
    "Frame source: mini:0, mini:/dev/v4l/by-id/..., wedge:http://host:port/stream.mjpg, "
    "digit:SERIAL, camera:0, video:FILE, folder:DIR, rosbag:BAG[,image=TOPIC,force=TOPIC,"
    "width=TOPIC] (docs/ros2.md), or a plain path; `live` also takes none (no camera: a "
    "frame-free model on --readings alone)."
)
SourceArg = Annotated[str, typer.Argument(help=SOURCE_HELP)]
CalibrationOption = Annotated[
    Optional[Path],
    typer.Option("--calibration", help="Sensor calibration JSON (from `calibrate`)."),
]
FolderFpsOption = Annotated[
    Optional[float],
    typer.Option("--fps", min=0, help="Frame rate of a folder of frames (or give --timestamps)."),
]
ReadingsOption = Annotated[
    Optional[Path],
    typer.Option(
        "--readings",
        help="CSV of timestamp_s,force_n,width_m (s, N, m); followed while the robot writes "
        "it when the source is a live device. Not with a rosbag: source (the bag has them).",
    ),
]
FolderTimesOption = Annotated[
    Optional[Path],
    typer.Option("--timestamps", help="CSV of a folder's frame times (file,timestamp_s)."),
]


#: ``live``'s source for a frame-free model: no camera, the readings alone.
NO_CAMERA = "none"


def _readings(path: Path | None, source: Any) -> Any:
    """The readings CSV: read once for a replay; followed while the robot writes it for a
    live device (each frame waits up to 1 s for its reading). A bag's own readings when
    the source is a ``rosbag:`` (which carries them)."""
    from tactile_compliance.acquisition.recording import FollowedReadings, Readings

    bag_readings = getattr(source, "readings_arrays", None)  # a rosbag: source
    if bag_readings is not None:
        if path is not None:
            raise typer.BadParameter(
                f"--readings {path}: the source {source.name} carries its own force and "
                "width topics; give one or the other"
            )
        try:
            return Readings(*bag_readings)
        except ValueError as err:
            raise ValueError(f"{source.name}: {err}") from err
    if path is None:
        raise typer.BadParameter(
            "--readings CSV is required (timestamp_s,force_n,width_m), except for a "
            "rosbag: source, which carries them"
        )
    if source.live:  # the robot may create the file after the start; its folder must exist
        if not path.parent.is_dir():
            raise ValueError(f"--readings {path}: no such folder: {path.parent}")
        return FollowedReadings(path)
    return _recorded_readings(path)


def _recorded_readings(path: Path | None) -> Any:
    """A recorded readings CSV, read once."""
    from tactile_compliance.acquisition.recording import Readings

    if path is None:
        raise typer.BadParameter("--readings CSV is required (timestamp_s,force_n,width_m)")
    if not path.is_file():
        raise ValueError(f"--readings {path}: no such file")
    try:
        return Readings.from_csv(path)
    except (OSError, ValueError) as err:
        raise ValueError(f"--readings: {err}") from err


def _open_source(
    spec: str, calibration: Path | None, fps: float | None, timestamps: Path | None
) -> tuple[Any, Any]:
    """(source, calibration or None): the source opened with the calibration's geometry."""
    from tactile_compliance.acquisition.calibration import SensorCalibration
    from tactile_compliance.acquisition.sensors import open_source

    options = {"fps": fps, "timestamps_csv": timestamps}
    if calibration is None:
        return open_source(spec, **options), None
    loaded = SensorCalibration.load(calibration)
    return loaded.open(spec, **options), loaded


@app.command()
def estimate(
    source: SourceArg,
    readings: ReadingsOption = None,
    calibration: CalibrationOption = None,
    reference: Annotated[
        Optional[Path],
        typer.Option(
            help="A no-contact frame (image file: a camera frame, or one already cut to the "
            "sensor frame); replaces the calibration's reference and the first frame."
        ),
    ] = None,
    max_frames: Annotated[
        Optional[int], typer.Option(min=1, help="Stop after this many frames (default: release).")
    ] = None,
    fps: FolderFpsOption = None,
    timestamps: FolderTimesOption = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON.")] = False,
) -> None:
    """The analytical estimates of one grasp (elastic E, Hertz E*), without a model.

    The values `record` would store, in the sensor's units, with how far such estimates
    were from the truth on real grasps. Nothing is written."""
    from tactile_compliance.acquisition.calibration import read_image
    from tactile_compliance.acquisition.estimates import estimate_recording

    no_contact = None if reference is None else read_image(reference)
    frames, sensor = _open_source(source, calibration, fps, timestamps)
    with frames:
        table = _readings(readings, frames)
        result = estimate_recording(
            frames, table, calibration=sensor, reference=no_contact, max_frames=max_frames
        )
    typer.echo(_json(result.to_dict()) if as_json else result.format())


@app.command()
def calibrate(
    source: SourceArg,
    out: Annotated[Path, typer.Option(help="Calibration JSON to write.")],
    frames: Annotated[int, typer.Option(min=1, help="Frames to take the median of.")] = 30,
    corners: Annotated[
        Optional[str],
        typer.Option(
            help="Warp: the pad's corners in the camera frame as 'x,y x,y x,y x,y' "
            "(top-left, top-right, bottom-right, bottom-left)."
        ),
    ] = None,
    warp_size: Annotated[
        Optional[str], typer.Option(help="HxW of the warped image (with --corners).")
    ] = None,
    crop_px: Annotated[
        Optional[int], typer.Option(min=0, help="Pixels cropped per side after the warp.")
    ] = None,
    crop_fraction: Annotated[
        Optional[float], typer.Option(help="Share of each side cropped (Mini: 1/7).")
    ] = None,
    size: Annotated[
        Optional[str], typer.Option(help="Final frame size HxW (default: the preset's).")
    ] = None,
    fps: FolderFpsOption = None,
    timestamps: FolderTimesOption = None,
    as_json: Annotated[
        bool,
        typer.Option("--json", help="Print the calibration (without its reference image) as JSON."),
    ] = False,
) -> None:
    """Record a sensor's no-contact reference frame and its crop/warp.

    Nothing may touch the gel. Options replace the source preset's geometry step by step."""
    from dataclasses import replace

    from tactile_compliance.acquisition.calibration import calibrate as run_calibration
    from tactile_compliance.acquisition.sensors import open_source

    with open_source(source, fps=fps, timestamps_csv=timestamps) as probe:
        geometry = probe.geometry  # the preset's steps, replaced below where given
    changes: dict[str, Any] = {}
    if corners is not None:
        try:
            points = tuple(tuple(float(v) for v in p.split(",")) for p in corners.split())
        except ValueError as err:
            raise typer.BadParameter(f"--corners: {err}") from err
        if len(points) != 4 or any(len(p) != 2 for p in points):
            raise typer.BadParameter("--corners needs four points 'x,y x,y x,y x,y'")
        changes["warp_corners"] = points
        changes["warp_size"] = _size_option(warp_size) or geometry.warp_size
        if changes["warp_size"] is None:
            raise typer.BadParameter("--corners needs --warp-size HxW")
    steps = {"crop_px": crop_px, "crop_fraction": crop_fraction, "output_size": _size_option(size)}
    changes |= {step: value for step, value in steps.items() if value is not None}
    result = run_calibration(
        source,
        geometry=replace(geometry, **changes),
        n_frames=frames,
        out=out,
        fps=fps,
        timestamps_csv=timestamps,
    )
    if as_json:
        document = result.to_dict()
        document.pop("reference_png_base64")  # the image is in the file, not on screen
        typer.echo(_json({"out": str(out), **document}))
        return
    height, width = result.frame_size
    typer.echo(
        f"Calibration {out}: reference = median of {result.n_frames} frames, "
        f"{height}x{width} px frames"
    )


@app.command("calibrate-depth")
def calibrate_depth_command(
    presses: Annotated[
        list[str],
        typer.Argument(
            help="Images (or folders of images) of a ball pressed into the gel, one place "
            "each; with --frames, one live source spec instead."
        ),
    ],
    ball_radius_mm: Annotated[float, typer.Option(help="Radius of the ball in mm.")],
    px_per_mm: Annotated[float, typer.Option(help="Pixel density of the sensor frames, px/mm.")],
    out: Annotated[Path, typer.Option(help="Calibration JSON to write (depth model inside).")],
    reference: Annotated[
        Optional[Path],
        typer.Option(
            help="No-contact frame (an image). Default: --calibration's reference, else the "
            "per-pixel median of the presses."
        ),
    ] = None,
    calibration: Annotated[
        Optional[Path],
        typer.Option(
            help="A calibration from `calibrate` to extend: its geometry and reference carry "
            "over to --out."
        ),
    ] = None,
    circles: Annotated[
        Optional[Path],
        typer.Option(
            help="Given contact circles, lines 'NAME (x, y) r' or 'NAME,x,y,r' in px; "
            "presses not listed are found automatically."
        ),
    ] = None,
    frames: Annotated[
        Optional[int],
        typer.Option(help="Take this many presses from the live source PRESSES names."),
    ] = None,
    fps: FolderFpsOption = None,
    timestamps: FolderTimesOption = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON.")] = False,
) -> None:
    """Fit your sensor's depth model from presses of a ball of known radius (as GelSight's
    SDK and Taxim calibrate): colour and position -> surface slope, checked press by press.
    `record`, `live` and `depth` then use it with --calibration OUT."""
    from tactile_compliance.acquisition.calibration import (
        SensorCalibration,
        calibrate_depth,
        capture_presses,
        is_calibration_file,
        read_circles,
        read_image,
        read_images,
    )
    from tactile_compliance.outputs import check_output_file, check_output_folder

    # Checked before the fit: a bad --out must not cost the fit (nor name a temp file).
    check_output_file(out, "sensor calibration", is_calibration_file, option="--out")
    check_output_folder(out, option="--out")
    sensor = SensorCalibration.load(calibration) if calibration is not None else None
    ref = read_image(reference) if reference is not None else None
    if frames is not None:
        if len(presses) != 1:
            raise typer.BadParameter("--frames takes one live source spec as PRESSES")
        images = capture_presses(
            presses[0], frames, sensor=sensor, reference=ref, fps=fps, timestamps_csv=timestamps
        )
    else:
        images = read_images(presses)
    result = calibrate_depth(
        images,
        ball_radius_mm=ball_radius_mm,
        px_per_mm=px_per_mm,
        reference=ref,
        sensor=sensor,
        circles=read_circles(circles) if circles is not None else None,
        source=" ".join(presses),
    )
    result.calibration.save(out)
    saved = f"Calibration {out}: depth model and {px_per_mm:g} px/mm"
    report = result.calibration.depth_model.report
    typer.echo(_json(report) if as_json else f"{result.format()}\n{saved}")


def _radius_options(values: list[str]) -> dict[str, float]:
    """``--radius OBJECT=MM`` values as ``object -> radius [mm]``."""
    radii: dict[str, float] = {}
    for value in values:
        name, sep, mm = value.partition("=")
        try:
            radius = float(mm)
        except ValueError:
            radius = math.nan
        if not sep or not name or not (math.isfinite(radius) and radius > 0):
            raise typer.BadParameter(f"--radius takes OBJECT=MM (a positive radius), got {value!r}")
        radii[name] = radius
    return radii


@app.command("calibrate-rig")
def calibrate_rig_command(
    datasets: Annotated[
        list[Path],
        typer.Argument(
            help="Datasets that `record` (or `simulate`) wrote, of grasps of rigid spheres; "
            "the moduli in their tables are not read."
        ),
    ],
    out: Annotated[Path, typer.Option(help="The rig file (JSON) to write.")],
    radius: Annotated[
        Optional[list[str]],
        typer.Option(
            help="OBJECT=MM: a sphere's radius in mm, for objects whose object table "
            "gives none (repeatable)."
        ),
    ] = None,
    name: Annotated[
        Optional[str], typer.Option(help="The rig's name in the file (default: OUT's stem).")
    ] = None,
    fit_lights: Annotated[
        bool,
        typer.Option(
            "--fit-lights",
            help="Also fit the light balance on the imprint's colour (docs/synthetic.md, "
            "'The lights').",
        ),
    ] = False,
    soft: Annotated[
        Optional[list[Path]],
        typer.Option(
            help="A dataset that `record` wrote of compliant reference spheres of known "
            "modulus (read from its table): fits the soft contact's footprint and glow "
            "(repeatable; docs/synthetic.md, 'Soft contacts')."
        ),
    ] = None,
    randomise: Annotated[
        Optional[list[str]],
        typer.Option(
            help="FIELD=VALUE[,VALUE]: a domain-randomisation range of your rig (e.g. "
            "force_baseline_sd_n=0.25), written into the rig file (repeatable; "
            "docs/synthetic.md, 'Domain randomisation')."
        ),
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the fit as JSON.")] = False,
) -> None:
    """Fit your gripper rig from grasps of rigid spheres, with no modulus label: the press
    force, the finger and mount stiffness (closure), the gel (contact area), the edge glow
    and, with --fit-lights, the light balance; with --soft, the soft contact on reference
    spheres of known modulus. `simulate --rig OUT` and `sim2real --rig OUT` then imitate
    it; its stiffness makes the rig-corrected analytical estimate."""
    from dataclasses import replace

    from tactile_compliance.outputs import atomic_file, check_output_file
    from tactile_compliance.synthetic.rig import (
        RANDOMISATION_FIELDS,
        GripperRig,
        is_rig_file,
        rig_file_text,
    )
    from tactile_compliance.synthetic.rig_fit import fit_rig, read_rigid_grasps
    from tactile_compliance.synthetic.soft_fit import fit_soft_contact, read_soft_grasps

    target = check_output_file(out, "rig file", is_rig_file, option="--out")
    ranges: dict[str, object] = {}
    for text in randomise or []:
        field_name, sep, value = text.partition("=")
        if not sep or field_name not in RANDOMISATION_FIELDS:
            raise typer.BadParameter(
                f"--randomise takes FIELD=VALUE with FIELD one of {', '.join(RANDOMISATION_FIELDS)}"
                f", got {text!r}"
            )
        parts = value.split(",")
        ranges[field_name] = parts if len(parts) > 1 else value
    try:
        given = GripperRig.from_dict(ranges, "--randomise")  # checked before the fit
    except ValueError as err:
        raise typer.BadParameter(str(err)) from err
    radii = _radius_options(radius or [])
    observations = read_rigid_grasps(datasets, radii)
    references = read_soft_grasps(soft, radii) if soft else None
    echo = (lambda text: typer.echo(text, err=True)) if as_json else typer.echo
    fit = fit_rig(observations, fit_lights=fit_lights, progress=echo)
    if references is not None:
        for line in references[1]:
            echo(f"--soft leaves out {line}")
        fit.rig, steps, fit.soft, evaluations = fit_soft_contact(
            fit.rig, references[0], progress=echo
        )
        fit.steps += steps
        fit.evaluations += evaluations
    if ranges:
        fit.rig = replace(fit.rig, **{k: getattr(given, k) for k in ranges})
        fit.steps.append(
            {
                "field": "randomisation",
                "value": {k: fit.rig.to_dict()[k] for k in ranges},
                "fitted_on": "given (--randomise): what the user's rig varies",
            }
        )
    with atomic_file(target, "w") as handle:
        handle.write(rig_file_text(fit.rig, name or target.stem, fit.to_dict()))
    if as_json:
        typer.echo(_json({"out": str(target), "rig": fit.rig.to_dict(), **fit.to_dict()}))
        return
    typer.echo(f"{fit.format()}\nRig {target}: tactile-compliance simulate --rig {target} ...")


@app.command()
def depth(
    frames: Annotated[list[Path], typer.Argument(help="Images (or folders of images).")],
    out: Annotated[Path, typer.Option(help="Directory to write STEM.npy into.")],
    calibration: Annotated[
        Optional[Path],
        typer.Option(
            help="Calibration with a depth model (`calibrate-depth`); without one, the "
            "public dataset's heuristic."
        ),
    ] = None,
    reference: Annotated[
        Optional[Path], typer.Option(help="No-contact frame (default: the calibration's).")
    ] = None,
    png: Annotated[bool, typer.Option("--png", help="Also write a coloured STEM.png.")] = False,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON.")] = False,
) -> None:
    """Depth maps of tactile frames: DIR/STEM.npy, float32 (H, W) in mm, positive into the gel."""
    from tactile_compliance.acquisition.calibration import (
        SensorCalibration,
        read_image,
        read_images,
    )
    from tactile_compliance.inference.depth_maps import write_depth_maps

    sensor = SensorCalibration.load(calibration) if calibration is not None else None
    ref = read_image(reference) if reference is not None else None
    written = write_depth_maps(read_images(frames), out, sensor=sensor, reference=ref, png=png)
    if as_json:
        rows = [{"depth_npy": str(path), "peak_depth_mm": peak} for path, peak in written]
        typer.echo(_json(rows))
        return
    for path, peak in written:
        typer.echo(f"{path}: peak {peak:.3f} mm")


@app.command()
def record(
    source: SourceArg,
    out: Annotated[Path, typer.Option(help="Dataset directory (raw layout).")],
    object_name: Annotated[str, typer.Option("--object", help="Object name (its directory).")],
    modulus: Annotated[
        str, typer.Option(help="Young's modulus E: Pa (2.5e4), or with kPa, MPa, GPa (25kPa).")
    ],
    readings: ReadingsOption = None,
    material: Annotated[str, typer.Option(help="Material, e.g. Rubber.")] = "",
    shape: Annotated[str, typer.Option(help="Shape, e.g. Sphere.")] = "",
    calibration: CalibrationOption = None,
    reference: Annotated[
        Optional[Path],
        typer.Option(
            help="A no-contact frame (image file: a camera frame, or one already cut to the "
            "sensor frame); replaces the calibration's reference and the first frame."
        ),
    ] = None,
    markers_source: Annotated[
        Optional[str], typer.Option(help="A second sensor (the marker finger).")
    ] = None,
    markers_calibration: Annotated[
        Optional[Path], typer.Option(help="Calibration of the second sensor.")
    ] = None,
    max_frames: Annotated[
        Optional[int], typer.Option(min=1, help="Stop after this many frames (default: release).")
    ] = None,
    fps: FolderFpsOption = None,
    timestamps: FolderTimesOption = None,
    rig: Annotated[
        Optional[str],
        typer.Option(
            help="A rig file from calibrate-rig (or a rig name): also report the "
            "rig-corrected analytical estimates, the rig's own closure taken out."
        ),
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON.")] = False,
) -> None:
    """Record one grasp into a dataset in the public dataset's raw layout.

    Writes OUT/OBJECT/grasp=G/augmentation=K/ (G: the next free number) and updates
    OUT/dataset_objects_and_compliance.csv; `import burgess OUT` reads it."""
    from contextlib import ExitStack

    from tactile_compliance.acquisition.calibration import read_image
    from tactile_compliance.acquisition.recording import ObjectInfo, record_grasp
    from tactile_compliance.data.plausibility import parse_pascals

    try:
        modulus_pa = parse_pascals(modulus)
    except ValueError as err:
        raise typer.BadParameter(str(err), param_hint="--modulus") from None
    info = ObjectInfo(object_name, modulus_pa, material, shape)
    no_contact = None if reference is None else read_image(reference)
    rig_stiffness = None
    if rig is not None:
        from tactile_compliance.synthetic.rig import resolve_rig

        rig_stiffness = resolve_rig(rig)[1].stiffness_n_per_m
    with ExitStack() as stack:
        frames, sensor = _open_source(source, calibration, fps, timestamps)
        stack.enter_context(frames)
        table = _readings(readings, frames)
        markers, marker_sensor = None, None
        if markers_source is not None:
            markers, marker_sensor = _open_source(markers_source, markers_calibration, fps, None)
            stack.enter_context(markers)
        result = record_grasp(
            frames,
            table,
            out,
            info,
            calibration=sensor,
            reference=no_contact,
            markers_source=markers,
            markers_calibration=marker_sensor,
            max_frames=max_frames,
            rig_stiffness_n_per_m=rig_stiffness,
        )
    fingers = "" if markers_source is not None else " --fingers markerless"
    next_step = f"Next: tactile-compliance import burgess {out} --out STORE{fingers}"
    typer.echo(_json(result.to_dict()) if as_json else f"{result.format()}\n{next_step}")


def _refuse_a_model_as_source(source: str) -> None:
    """`live MODEL --readings CSV` (the source forgotten) names its mistake, not a video."""
    path = Path(source)
    model_files = ("best.pt", "model.safetensors")
    if path.suffix in (".pt", ".onnx") or any((path / name).is_file() for name in model_files):
        raise typer.BadParameter(
            f"{source} is a model, not a frame source: give CHECKPOINTS... and then SOURCE "
            "(or only a SOURCE for the analytical estimates without a model)"
        )


@app.command()
def live(
    checkpoints: Annotated[
        Optional[list[Path]],
        typer.Argument(
            help="best.pt, a run directory or an `export --safetensors` directory; several "
            "give an ensemble interval; none: the analytical estimates alone."
        ),
    ] = None,
    source: SourceArg = ...,  # `...`: required (after the optional CHECKPOINTS)
    readings: ReadingsOption = None,
    calibration: CalibrationOption = None,
    window: Annotated[
        Optional[int], typer.Option(min=3, help="Estimate from the last N frames (default: all).")
    ] = None,
    window_s: Annotated[
        Optional[float],
        typer.Option(
            min=0,
            help="Estimate from the last S seconds before the peak, by the frames' timestamps "
            "(not with --window; the same at any frame rate).",
        ),
    ] = None,
    level: Annotated[float, typer.Option(min=0, max=1, help="Ensemble interval coverage.")] = 0.8,
    readings_offset_s: Annotated[
        float,
        typer.Option(
            help="Seconds added to a frame's time to find its reading: the readings' clock "
            "minus the sensor's (0 when the robot logs time.monotonic() on this machine)."
        ),
    ] = 0.0,
    fps: FolderFpsOption = None,
    timestamps: FolderTimesOption = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON lines.")] = False,
    device: DeviceOption = DEFAULT_DEVICE,
    weights: BackboneWeightsOption = None,
) -> None:
    """Stream a sensor (or a replayed video) through the estimator.

    Provisional estimates while the gripper closes, the final one on release. Without a
    checkpoint, the analytical estimates (those of `estimate`)."""
    from tactile_compliance.inference.live import format_live_event, live_estimates, load_members

    if window is not None and window_s is not None:
        raise typer.BadParameter("give --window (frames) or --window-s (seconds), not both")
    if window_s is not None and window_s <= 0:
        raise typer.BadParameter(f"--window-s must be > 0 s, got {window_s}")
    if not 0 < level < 1:
        raise typer.BadParameter(f"--level must lie between 0 and 1 (exclusive), got {level}")
    no_camera = source.strip().lower() == NO_CAMERA
    if not checkpoints:  # `live SOURCE`: the analytical estimates, no model
        if no_camera:
            raise typer.BadParameter(
                "the analytical estimates need the frames' depth maps: name a camera or "
                "video, or give a frame-free checkpoint before `none`"
            )
        _refuse_a_model_as_source(source)
    members = (
        load_members(checkpoints, device=device, backbone_weights=weights) if checkpoints else []
    )
    frames, sensor = (
        (contextlib.nullcontext(), None)
        if no_camera
        else _open_source(source, calibration, fps, timestamps)
    )
    final = False
    with frames:
        table = _recorded_readings(readings) if no_camera else _readings(readings, frames)
        for event in live_estimates(
            members,
            None if no_camera else frames,
            table,
            calibration=sensor,
            window=window,
            window_s=window_s,
            level=level,
            readings_offset_s=readings_offset_s,
        ):
            if event["event"] == "no_estimate":
                _fail(f"no estimate: {event['reason']}", EXIT_BAD_INPUT)
            final = final or bool(event.get("final"))
            typer.echo(json.dumps(event) if as_json else format_live_event(event))
    if not final:  # pragma: no cover - live_estimates ends with a final or a no_estimate
        _fail("no estimate", EXIT_BAD_INPUT)


@app.command()
def report(
    results: Annotated[Path, typer.Argument(help="Results store directory (holds rows/*.json).")],
    out: Annotated[
        Optional[Path],
        typer.Option("--out", "-o", help="Output directory (default: RESULTS/report)."),
    ] = None,
    formats: Annotated[
        str, typer.Option("--format", "-f", help="Comma-separated formats: md, html, tex.")
    ] = "md,html",
    stores: Annotated[
        Optional[list[Path]],
        typer.Option("--store", help="Extra GraspStore to draw in Fig. 1 (repeatable)."),
    ] = None,
    as_json: Annotated[
        bool, typer.Option("--json", help="Print what was written and skipped as JSON.")
    ] = False,
) -> None:
    """Build the paper's tables and figures from a results store (Markdown, HTML, LaTeX).

    Parts whose runs are missing are skipped with a note naming the preset that produces
    them; only complete runs count; failed runs are listed.
    """
    from tactile_compliance.evaluation.report import build_report

    summary = build_report(results, out, formats=formats, stores=stores or ())
    payload = {
        "results_dir": str(summary.results_dir),
        "out_dir": str(summary.out_dir),
        "documents": {k: str(v) for k, v in summary.documents.items()},
        "figures": {k: str(v) for k, v in summary.figures.items()},
        "tables": sorted(summary.tables),
        "notes": summary.notes,
        "rows": summary.n_rows,
        "complete": summary.n_complete,
        "failed": summary.n_failed,
    }
    typer.echo(_json(payload) if as_json else str(summary))


@app.command()
def demo(
    out: Annotated[Path, typer.Option(help="Where everything is written.")] = Path("demo-output"),
    mode: Annotated[
        DemoMode, typer.Option(help="full (a few minutes on 2 CPU cores) or ci (seconds, tiny).")
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


@app.command()
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
        DemoMode, typer.Option(help="full (about 7 minutes on 2 CPU cores) or ci (seconds, tiny).")
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


if __name__ == "__main__":  # pragma: no cover
    app()
