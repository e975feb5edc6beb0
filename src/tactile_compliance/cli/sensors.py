"""Commands for your own sensor and rig: calibrate, calibrate-depth, calibrate-rig, record."""

# typer reads the parameters' annotations at runtime and needs Optional[X] on Python 3.10.
# ruff: noqa: UP045

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Any, Optional

import typer

from tactile_compliance.cli.framework import (
    _json,
    _size_option,
)
from tactile_compliance.cli.options import (
    CalibrationOption,
    FolderFpsOption,
    FolderTimesOption,
    ReadingsOption,
    ReferenceOption,
    RigCorrectionOption,
    SourceArg,
    _open_source,
    rig_stiffness_n_per_m,
)


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
    from tactile_compliance.acquisition.calibration import picture_path
    from tactile_compliance.acquisition.sensors import open_source

    with open_source(source, fps=fps, timestamps_csv=timestamps) as probe:
        geometry = probe.geometry  # the preset's steps, replaced below where given
    changes: dict[str, Any] = {}
    if corners is not None:
        from tactile_compliance.data.image_ops import parse_corners

        try:
            changes["warp_corners"] = parse_corners(corners)
        except ValueError as err:
            raise typer.BadParameter(str(err), param_hint="--corners") from err
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
        f"{height}x{width} px frames\nPicture {picture_path(out)}: the warped reference with "
        "the crop drawn on it (check the corners and the crop by eye)"
    )


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
        progress=not as_json,
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
    reference: ReferenceOption = None,
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
    rig: RigCorrectionOption = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON.")] = False,
) -> None:
    """Record one grasp into a dataset in the public dataset's raw layout.

    Writes OUT/OBJECT/grasp=G/augmentation=K/ (G: the next free number) and updates
    OUT/dataset_objects_and_compliance.csv; `import burgess OUT` reads it."""
    from contextlib import ExitStack

    from tactile_compliance.acquisition.calibration import read_image
    from tactile_compliance.acquisition.readings import source_readings
    from tactile_compliance.acquisition.recording import ObjectInfo, record_grasp
    from tactile_compliance.data.plausibility import parse_pascals

    try:
        modulus_pa = parse_pascals(modulus)
    except ValueError as err:
        raise typer.BadParameter(str(err), param_hint="--modulus") from None
    info = ObjectInfo(object_name, modulus_pa, material, shape)
    no_contact = None if reference is None else read_image(reference)
    rig_stiffness = rig_stiffness_n_per_m(rig)
    with ExitStack() as stack:
        frames, sensor = _open_source(source, calibration, fps, timestamps)
        stack.enter_context(frames)
        table = source_readings(readings, frames)
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
