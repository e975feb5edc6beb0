"""The options and vocabularies several commands share, and how the source options are read."""

# typer reads the parameters' annotations at runtime and needs Optional[X] on Python 3.10.
# ruff: noqa: UP045

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal, Optional

import typer

from tactile_compliance.acquisition.sensors import SENSORS

# The choices the parser checks and the help lists. Each is a vocabulary of the library,
# written out here so that the command starts without importing the library (torch);
# tests/test_cli_help.py checks each against its home, named in the comment.
Fingers = Literal["markerless", "markers", "both"]  # data.raw_layout.FingerChoice


Condition = Literal["seen", "unseen"]  # config.SplitConfig.condition


Grouping = Literal["grasp", "per_sample"]  # config.SplitConfig.grouping


Inputs = Literal[  # data.inputs.InputStrategy
    "Image", "ImageF", "ImageFW", "ALL", "FW", "FWE", "DepthFW", "DepthALL", "FWR"
]


Objective = Literal["last", "best"]  # training.hpo.objectives.OBJECTIVES


KeepCheckpoints = Literal["all", "best", "none"]  # runs.layout.KEEP_CHECKPOINTS


Backbone = Literal[  # training.pretrain.PRETRAIN_BACKBONES
    "resnet18", "resnet34", "resnet50", "vgg16", "top10nn-cnn"
]


DemoMode = Literal["full", "ci"]  # demo.PLANS and sim2real.PLANS


SimulateKind = Literal["gelsight", "shore-videos"]  # the two generators of `simulate`


PickleDtype = Literal["float16", "float32", "float64"]  # data.raw_layout.ALLOWED_DTYPES


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


BackboneWeightsOption = Annotated[
    Optional[Path],
    typer.Option(
        "--weights",
        help="Frozen-backbone checkpoints store the head only: a local copy of the "
        "backbone's weights file (e.g. the ImageNet .pth on an offline machine).",
    ),
]


#: Built from the table of sensors (``acquisition.sensors.SENSORS``), in its order.
SOURCE_HELP = (
    f"Frame source: {', '.join(kind.help for kind in SENSORS)}, or a plain path; `live` also "
    "takes none (no camera: a frame-free model on --readings alone)."
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


ReferenceOption = Annotated[
    Optional[Path],
    typer.Option(
        help="A no-contact frame (image file: a camera frame, or one already cut to the "
        "sensor frame); replaces the calibration's reference and the first frame."
    ),
]
FolderTimesOption = Annotated[
    Optional[Path],
    typer.Option("--timestamps", help="CSV of a folder's frame times (file,timestamp_s)."),
]
RigCorrectionOption = Annotated[
    Optional[str],
    typer.Option(
        "--rig",
        help="A rig file from calibrate-rig (or a rig name): also report the rig-corrected "
        "analytical estimates, the rig's own closure taken out (record also writes them, "
        "the input of FWR models).",
    ),
]


def rig_stiffness_n_per_m(rig: str | None) -> float | None:
    """The stiffness [N/m] of ``--rig`` (a name or a rig file), None without one; resolved
    before a source opens, so a wrong rig fails first (ValueError: unknown or invalid)."""
    if rig is None:
        return None
    from tactile_compliance.synthetic.rig import resolve_rig

    return resolve_rig(rig)[1].stiffness_n_per_m


#: ``live``'s source for a frame-free model: no camera, the readings alone.
NO_CAMERA = "none"


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
