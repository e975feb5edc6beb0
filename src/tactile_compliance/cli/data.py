"""Commands that make and read stores: simulate, info, import burgess/yuan, presets, split,
split-summary."""

# typer reads the parameters' annotations at runtime and needs Optional[X] on Python 3.10.
# ruff: noqa: UP045

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Optional

import typer

from tactile_compliance.cli.framework import (
    EXIT_BAD_INPUT,
    _existing_dir,
    _fail,
    _json,
    _load_config,
    _size_option,
)
from tactile_compliance.cli.options import (
    Condition,
    FilterConfigOption,
    Fingers,
    Grouping,
    JsonOption,
    PickleDtype,
    SetOption,
    SimulateKind,
)


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
        f"estimates: {summary['has_estimates']}  rig-corrected estimates: "
        + (", ".join(f"{k:.4g} N/m" for k in summary["rig_stiffnesses_n_per_m"]) or "none")
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


OutOption = Annotated[
    Optional[Path],
    typer.Option("--out", help="Store directory to create (required unless --check)."),
]


CheckOption = Annotated[
    bool,
    typer.Option(
        "--check",
        help="Only check the download: counts, sizes and what is missing or cut short, "
        "in one line; writes nothing (docs/reproduce.md).",
    ),
]


def _check_download(run: object, out: Path | None, as_json: bool) -> None:
    """Print a download check's counts (or JSON); one error line (exit 2) when it is
    incomplete."""
    if out is not None:
        _fail("--check writes nothing: drop --out, then import without --check", EXIT_BAD_INPUT)
    check = run()  # type: ignore[operator]
    typer.echo(_json(check.to_dict()) if as_json else check.format())
    check.raise_if_incomplete()  # type: ignore[attr-defined]


def _require_out(out: Path | None) -> Path:
    if out is None:
        _fail(
            "Missing option '--out': the store directory to create "
            "(or pass --check to only check the download)",
            EXIT_BAD_INPUT,
        )
    return out  # type: ignore[return-value]


ImportJsonOption = Annotated[
    bool,
    typer.Option("--json", help="Print the import report (with --check: the check) as JSON."),
]


def import_burgess_command(
    src: Annotated[
        Path,
        typer.Argument(
            help="The unpacked gelsight_youngs_modulus_dataset/ directory (with --check, "
            "also its zip)."
        ),
    ],
    out: OutOption = None,
    objects: Annotated[
        Optional[Path],
        typer.Option(
            help="Object table CSV (dataset_objects_and_compliance.csv); "
            "labels come from it instead of metadata.json (with --check: the objects and "
            "grasps the download must hold)."
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
    check: CheckOption = False,
) -> None:
    """Import the GelSight Young's-modulus dataset layout (real or simulated)."""
    if check:
        from tactile_compliance.data.download_check import check_burgess_download

        _check_download(lambda: check_burgess_download(src, object_table=objects), out, as_json)
        return
    _existing_dir(src, "unpacked dataset directory (OBJECT/grasp=g/augmentation=k/)")
    from tactile_compliance.data.burgess import import_burgess

    image_size = _size_option(size)
    out = _require_out(out)
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


def import_yuan_command(
    src: Annotated[Path, typer.Argument(help="Directory of {SHAPE}_{hardness}_{n}.avi videos.")],
    out: OutOption = None,
    size: SizeOption = None,
    strict: StrictOption = False,
    overwrite: OverwriteOption = False,
    report_json: ReportOption = None,
    as_json: ImportJsonOption = False,
    check: CheckOption = False,
) -> None:
    """Import the Shore-hardness press videos (Yuan et al. 2017)."""
    if check:
        from tactile_compliance.data.download_check import check_yuan_download

        _check_download(lambda: check_yuan_download(src), out, as_json)
        return
    _existing_dir(src, "directory of the press videos")
    from tactile_compliance.data.yuan import import_yuan

    image_size = _size_option(size)
    out = _require_out(out)
    _run_import(
        lambda: import_yuan(src, out, image_size=image_size, strict=strict, overwrite=overwrite),
        report_json,
        as_json,
    )


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
    from tactile_compliance.data.splits import (
        make_split_from_config,
        store_metadata,
        summarise_split,
    )
    from tactile_compliance.data.store import GraspStore

    options = [f"data.store={store}", f"split.condition={condition}", f"seed={seed}"]
    cfg = _load_config(config, [*options, f"split.grouping={grouping}"], overrides)
    opened = GraspStore.open(store)
    samples, report = filter_samples(opened.samples, cfg)
    drawn = make_split_from_config(samples, cfg, store_metadata(opened))
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
