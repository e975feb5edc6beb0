"""Commands that apply a model or its analytics: predict, export, estimate, depth, live."""

# typer reads the parameters' annotations at runtime and needs Optional[X] on Python 3.10.
# ruff: noqa: UP045

from __future__ import annotations

import contextlib
import json
from pathlib import Path
from typing import Annotated, Any, Optional

import typer

from tactile_compliance.cli.framework import (
    EXIT_BAD_INPUT,
    _fail,
    _json,
)
from tactile_compliance.cli.options import (
    NO_CAMERA,
    BackboneWeightsOption,
    CalibrationOption,
    DeviceOption,
    Fingers,
    FolderFpsOption,
    FolderTimesOption,
    ReadingsOption,
    ReferenceOption,
    RigCorrectionOption,
    SourceArg,
    _open_source,
    rig_stiffness_n_per_m,
)
from tactile_compliance.devices import DEFAULT_DEVICE


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
    from tactile_compliance.acquisition.readings import source_readings
    from tactile_compliance.inference.live import format_live_event, live_estimates, load_members

    members = load_members([checkpoint], device=device, backbone_weights=weights)
    frames, sensor = _open_source(spec, calibration, None, None)
    with frames:
        for event in live_estimates(
            members, frames, source_readings(None, frames), calibration=sensor
        ):
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


def estimate(
    source: SourceArg,
    readings: ReadingsOption = None,
    calibration: CalibrationOption = None,
    reference: ReferenceOption = None,
    max_frames: Annotated[
        Optional[int], typer.Option(min=1, help="Stop after this many frames (default: release).")
    ] = None,
    fps: FolderFpsOption = None,
    timestamps: FolderTimesOption = None,
    rig: RigCorrectionOption = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON.")] = False,
) -> None:
    """The analytical estimates of one grasp (elastic E, Hertz E*), without a model.

    The values `record` would store, in the sensor's units, with how far such estimates
    were from the truth on real grasps. Nothing is written."""
    from tactile_compliance.acquisition.calibration import read_image
    from tactile_compliance.acquisition.estimates import estimate_recording
    from tactile_compliance.acquisition.readings import source_readings

    rig_stiffness = rig_stiffness_n_per_m(rig)
    no_contact = None if reference is None else read_image(reference)
    frames, sensor = _open_source(source, calibration, fps, timestamps)
    with frames:
        table = source_readings(readings, frames)
        result = estimate_recording(
            frames,
            table,
            calibration=sensor,
            reference=no_contact,
            max_frames=max_frames,
            rig_stiffness_n_per_m=rig_stiffness,
        )
    typer.echo(_json(result.to_dict()) if as_json else result.format())


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


def _refuse_a_model_as_source(source: str) -> None:
    """`live MODEL --readings CSV` (the source forgotten) names its mistake, not a video."""
    path = Path(source)
    model_files = ("best.pt", "model.safetensors")
    if path.suffix in (".pt", ".onnx") or any((path / name).is_file() for name in model_files):
        raise typer.BadParameter(
            f"{source} is a model, not a frame source: give CHECKPOINTS... and then SOURCE "
            "(or only a SOURCE for the analytical estimates without a model)"
        )


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
    rig: RigCorrectionOption = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON lines.")] = False,
    device: DeviceOption = DEFAULT_DEVICE,
    weights: BackboneWeightsOption = None,
) -> None:
    """Stream a sensor (or a replayed video) through the estimator.

    Provisional estimates while the gripper closes, the final one on release. Without a
    checkpoint, the analytical estimates (those of `estimate`)."""
    from tactile_compliance.acquisition.readings import recorded_readings, source_readings
    from tactile_compliance.inference.live import format_live_event, live_estimates, load_members

    if window is not None and window_s is not None:
        raise typer.BadParameter("give --window (frames) or --window-s (seconds), not both")
    if window_s is not None and window_s <= 0:
        raise typer.BadParameter(f"--window-s must be > 0 s, got {window_s}")
    if not 0 < level < 1:
        raise typer.BadParameter(f"--level must lie between 0 and 1 (exclusive), got {level}")
    if checkpoints and rig is not None:
        raise typer.BadParameter(
            "--rig adds the rig-corrected analytical estimates to `live` without a model; a "
            "model gives its own estimate (leave out --rig or the checkpoints)"
        )
    rig_stiffness = rig_stiffness_n_per_m(rig)
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
    if sensor is None and not no_camera:
        from tactile_compliance.physics.estimators import WEDGE_UNITS

        typer.echo(
            f"live: no --calibration: depth and analytical estimates use {WEDGE_UNITS.describe()} "
            "(the public dataset's GelSight Wedge); give --calibration sensor.json (from "
            "`calibrate`) for another sensor",
            err=True,
        )
    final = False
    with frames:
        table = recorded_readings(readings) if no_camera else source_readings(readings, frames)
        for event in live_estimates(
            members,
            None if no_camera else frames,
            table,
            calibration=sensor,
            window=window,
            window_s=window_s,
            level=level,
            readings_offset_s=readings_offset_s,
            rig_stiffness_n_per_m=rig_stiffness,
        ):
            if event["event"] == "no_estimate":
                _fail(f"no estimate: {event['reason']}", EXIT_BAD_INPUT)
            final = final or bool(event.get("final"))
            typer.echo(json.dumps(event) if as_json else format_live_event(event))
    if not final:  # pragma: no cover - live_estimates ends with a final or a no_estimate
        _fail("no estimate", EXIT_BAD_INPUT)
