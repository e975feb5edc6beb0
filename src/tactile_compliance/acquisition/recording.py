"""Record your own grasps in the raw layout of the public dataset, ready for ``import burgess``.

See docs/inference.md, "Record and train on your own objects", and docs/data.md,
"Recording your own grasps: what ``record`` guarantees".
"""

from __future__ import annotations

import contextlib
import math
import os
import re
import shutil
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from tactile_compliance.acquisition.calibration import SensorCalibration
from tactile_compliance.acquisition.capture import CapturedGrasp, capture_checked
from tactile_compliance.acquisition.readings import (
    ReadingsCallback,
)
from tactile_compliance.acquisition.sensors import (
    FrameSizeError,
    FrameSourceBase,
)
from tactile_compliance.data.depth_model import grey_frame_problem
from tactile_compliance.data.frame_selection import (
    MAX_AUGMENTATIONS,
    MIN_PEAK_FORCE_N,
    augment_selection,
)
from tactile_compliance.data.image_ops import difference_images
from tactile_compliance.data.object_table import (
    LABEL_COLUMN,
    MATERIAL_COLUMN,
    MODULUS_COLUMN,
    SHAPE_COLUMN,
)
from tactile_compliance.data.photometric import reconstruct_depth
from tactile_compliance.data.plausibility import FORCE, MODULUS, WIDTH
from tactile_compliance.data.raw_layout import (
    GRASP_DIR,
    METADATA_FILE,
    SYNTHETIC_MANIFEST,
    augmentation_dir,
    grasp_dir,
    numbered_dirs,
    read_metadata,
    tree_units,
    write_metadata,
    write_sample,
    write_units_file,
)
from tactile_compliance.outputs import (
    MARKER_NAME,
    PARTIAL_PREFIX,
    atomic_file,
    claim_output_dir,
    commit_path,
    exclusive_lock,
    output_kind,
)
from tactile_compliance.physics.estimators import (
    DEFAULT_ESTIMATOR,
    WEDGE_UNITS,
    AnalyticalEstimator,
    GraspUnits,
    SensorUnits,
)

__all__ = [
    "OBJECT_TABLE_FILE",
    "OUTPUT_KIND",
    "ObjectInfo",
    "RecordedGrasp",
    "augmented_indices",
    "claim_dataset_dir",
    "record_grasp",
    "write_grasp",
]

OBJECT_TABLE_FILE = "dataset_objects_and_compliance.csv"
"""The object table written next to the object directories (the dataset's file name)."""

#: Names of the files beside the object directories (lower case: also refused on a file
#: system that ignores case): an object of that name would take the file's place.
RESERVED_NAMES = frozenset(name.lower() for name in (OBJECT_TABLE_FILE, SYNTHETIC_MANIFEST))

TRIALS_COLUMN = "Trials Recorded?"
# Matched with fullmatch: "$" would also accept a trailing newline.
_OBJECT_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.+-]*")

OUTPUT_KIND = "record"
"""The ``outputs.claim_output_dir`` kind of a dataset directory that ``record`` writes."""

LOCK_FILE = ".record.lock"  # flock-ed while one record writes into the dataset


# ---------------------------------------------------------------------- selection
def augmented_indices(
    force_n: Sequence[float] | np.ndarray,
    max_aug: int = MAX_AUGMENTATIONS,
    *,
    modulus_pa: float | None = None,
    max_depth_mm: Sequence[np.ndarray] = (),
    timestamps_s: Sequence[float] | np.ndarray | None = None,
) -> list[tuple[int, int, int]]:
    """The dataset's three frames (indices) of each augmentation k = 0, 1, ...
    (``data.frame_selection.augment_selection``; docs/inference.md, "Record and train").

    ``modulus_pa`` [Pa] and ``max_depth_mm`` (per-frame maximum depths in mm of every
    sensor) feed the published code's hard-object cap.

    Raises:
        ValueError: no selection (no frame reaches 5 N, the peak stays below 10 N, or
            fewer than three frames between contact and peak).
    """
    f = np.asarray(force_n, dtype=np.float64).reshape(-1)
    # One frame set per augmentation for every finger and the readings (what
    # write_grasp stores), so no per-finger contact shift.
    selection = augment_selection(
        f,
        timestamps_s=timestamps_s,
        max_depth_mm=max_depth_mm,
        modulus_pa=modulus_pa,
        max_aug=max_aug,
        contact_shift=False,
    )
    if selection is None:
        peak = float(f.max()) if f.size else 0.0
        raise ValueError(
            f"the grasp has no frame selection: peak force {peak:.1f} N over {f.size} frames "
            f"(it needs a frame >= 5 N, a peak >= {MIN_PEAK_FORCE_N:g} N and three frames "
            f"from contact to peak)"
        )
    return selection.augmentations()


# ---------------------------------------------------------------------- estimates
def recording_estimator(sensor: SensorCalibration | None) -> AnalyticalEstimator:
    """The analytical estimator of a recording: the public dataset's (what ``import
    burgess`` records for this layout) at the calibration's pixel density (None: the
    Wedge's). ``record``, ``estimate`` and ``live`` without a model all use it."""
    return DEFAULT_ESTIMATOR.at(None if sensor is None else sensor.px_per_mm)


@dataclass
class GraspEstimates:
    """What :func:`grasp_estimates` computed from one captured grasp.

    Attributes:
        estimates_pa: (elastic E, Hertz E*) in Pa, NaN where not estimable (the dataset
            has such grasps too); in the units of ``units``.
        units: the depth model and pixel density the estimates were made with.
        fingers: ``{"markerless": (difference images (T, H, W, 3) float, depth maps (T, H,
            W) mm)}``, and ``"markers"`` with a second sensor: every captured frame's.
        rig_corrected_pa: the same estimates with the rig's compliance taken out (a rig
            stiffness given), else None; NaN where not estimable.
    """

    estimates_pa: tuple[float, float]
    units: SensorUnits
    fingers: dict[str, tuple[np.ndarray, np.ndarray]]
    rig_corrected_pa: tuple[float, float] | None = None


def grasp_estimates(
    captured: CapturedGrasp,
    *,
    reference: np.ndarray | None = None,
    markers_reference: np.ndarray | None = None,
    sensor: SensorCalibration | None = None,
    markers_sensor: SensorCalibration | None = None,
    rig_stiffness_n_per_m: float | None = None,
) -> GraspEstimates:
    """The analytical estimates of a captured grasp: every frame differenced against the
    no-contact reference, its depth map (the calibration's depth model, else the dataset's
    heuristic), and :func:`recording_estimator` over the whole series (the dataset's
    estimator clips the press itself). The one computation behind the estimates ``record``
    stores, ``estimate`` prints and ``live`` without a model streams; deterministic, no
    side effects.

    Args:
        reference, markers_reference: the no-contact frame of each sensor; default the
            calibration's, else the first frame.
        sensor, markers_sensor: the sensors' calibrations (depth models, pixel density).
        rig_stiffness_n_per_m: the rig's stiffness [N/m] (``calibrate-rig``): also the
            rig-corrected estimates (``GraspEstimates.rig_corrected_pa``).

    Raises:
        FrameSizeError: a reference of another size than the frames.
    """
    frames = captured.frames
    if reference is None and sensor is not None:
        reference = sensor.reference
    if markers_reference is None and markers_sensor is not None:
        markers_reference = markers_sensor.reference
    ref = frames[0] if reference is None else np.asarray(reference)
    if ref.shape != frames.shape[1:]:
        raise FrameSizeError(
            f"the reference frame is {ref.shape[:2]}, the recorded frames {frames.shape[1:3]}"
        )
    if sensor is not None and sensor.depth_model is not None:
        problem = grey_frame_problem(frames[0], ref)
        if problem:
            raise ValueError(f"{problem}; nothing written")
    # Every frame's depth: the dataset's estimator clips the press out of the whole series.
    diff = difference_images(frames, ref)
    depth = reconstruct_depth(diff, model="dataset" if sensor is None else sensor.depth)
    fingers = {"markerless": (diff, depth)}
    marker_depth = None
    if captured.markers_frames is not None:
        markers = captured.markers_frames
        mref = markers[0] if markers_reference is None else np.asarray(markers_reference)
        mdiff = difference_images(markers, mref)
        marker_model = "dataset" if markers_sensor is None else markers_sensor.depth
        marker_depth = reconstruct_depth(mdiff, markers=True, model=marker_model)
        fingers["markers"] = (mdiff, marker_depth)
    # The original took the earlier depth onset of the two fingers.
    estimator = recording_estimator(sensor)

    def estimate(rig: float | None) -> tuple[float, float]:
        try:
            values = estimator.estimate(
                captured.force_n,
                captured.width_m,
                depth,
                marker_depths_mm=marker_depth,
                rig_stiffness_n_per_m=rig,
            )
            return (float(values[0]), float(values[1]))
        except ValueError:
            return (math.nan, math.nan)  # the dataset has no estimate for such grasps

    units = WEDGE_UNITS if sensor is None else sensor.units
    return GraspEstimates(
        estimates_pa=estimate(None),
        units=units,
        fingers=fingers,
        rig_corrected_pa=None if rig_stiffness_n_per_m is None else estimate(rig_stiffness_n_per_m),
    )


def checked_selection(
    captured: CapturedGrasp, max_aug: int = MAX_AUGMENTATIONS
) -> list[tuple[int, int, int]]:
    """The grasp's frame selection (:func:`augmented_indices`, without the depth caps),
    its readings checked against ``data.plausibility`` at the selected frames.

    Raises:
        ValueError: no selection, or implausible readings (widths in mm, say).
    """
    selection = augmented_indices(captured.force_n, max_aug, timestamps_s=captured.timestamp_s)
    written = sorted({i for idx in selection for i in idx})
    for rule, values in ((FORCE, captured.force_n), (WIDTH, captured.width_m)):
        problem = rule.violation(np.asarray(values)[written])  # data.plausibility
        if problem:
            raise ValueError(
                f"the readings of the selected frames are implausible: {problem}; nothing "
                f"written (are the widths in millimetres? --readings needs metres)"
            )
    return selection


# ---------------------------------------------------------------------- writing
@dataclass(frozen=True)
class ObjectInfo:
    """What ``metadata.json`` and the object table say about the grasped object.

    Attributes:
        name: directory name (letters, digits, ``_ . + -``).
        modulus_pa: Young's modulus E in Pa (the label).
        material: e.g. ``Rubber``, ``Foam``, ``Plastic``.
        shape: e.g. ``Sphere``, ``Cylinder``, ``Rectangle``.
        shore_00, shore_a, shore_d: hardness, when measured.
    """

    name: str
    modulus_pa: float
    material: str = ""
    shape: str = ""
    shore_00: float | None = None
    shore_a: float | None = None
    shore_d: float | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not _OBJECT_NAME.fullmatch(self.name):
            raise ValueError(
                f"object name {self.name!r}: use letters, digits and _ . + - "
                f"(it names a directory), starting with a letter or digit"
            )
        if self.name.lower() in RESERVED_NAMES:
            raise ValueError(
                f"object name {self.name!r} is the name of a file of the dataset layout "
                f"({', '.join(sorted(RESERVED_NAMES))}); the object's directory would take "
                f"its place: choose another name"
            )
        if not (math.isfinite(float(self.modulus_pa)) and float(self.modulus_pa) > 0):
            raise ValueError(f"modulus_pa must be a finite number > 0 Pa, got {self.modulus_pa}")
        problem = MODULUS.violation(float(self.modulus_pa))
        if problem:
            raise ValueError(f"object {self.name}: {problem}")
        for what, text in (("material", self.material), ("shape", self.shape)):
            if any(not ch.isprintable() for ch in text):
                raise ValueError(
                    f"object {self.name}: the {what} {text!r} holds a control character "
                    f"(newline, tab, ...); it would break the object table"
                )


@dataclass
class RecordedGrasp:
    """What :func:`write_grasp` wrote.

    Attributes:
        path: the ``grasp={g}`` directory.
        grasp: its number g.
        frame_indices: the three frames of each augmentation (into the capture).
        estimates_pa: (elastic E, Hertz E*) in Pa, NaN where not estimable.
        n_frames: frames captured; skipped: frames left out, with the reason.
        object_table: the object table written or updated.
        warnings: what looked wrong in the readings or the reference
            (:func:`check_recording`); the grasp is written all the same.
        checks: the numbers behind them.
        rig_corrected_pa: (elastic E, Hertz E*) in Pa with the rig's own closure taken
            out of the widths (``physics.contact.rig_corrected_widths_m``), when a rig
            stiffness was given; reported next to ``estimates_pa``, not written to the
            dataset.
        rig_stiffness_n_per_m: that stiffness [N/m], or None.
    """

    path: Path
    grasp: int
    frame_indices: list[tuple[int, int, int]]
    estimates_pa: tuple[float, float]
    n_frames: int
    skipped: list[str]
    object_table: Path
    warnings: list[str] = field(default_factory=list)
    checks: dict[str, Any] = field(default_factory=dict)
    rig_corrected_pa: tuple[float, float] | None = None
    rig_stiffness_n_per_m: float | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly dict."""
        return {
            "path": str(self.path),
            "grasp": self.grasp,
            "augmentations": len(self.frame_indices),
            "frame_indices": [list(i) for i in self.frame_indices],
            "estimates_pa": [None if math.isnan(v) else v for v in self.estimates_pa],
            "n_frames": self.n_frames,
            "skipped": self.skipped,
            "object_table": str(self.object_table),
            "warnings": self.warnings,
            "checks": self.checks,
            "rig_corrected_pa": None
            if self.rig_corrected_pa is None
            else [None if math.isnan(v) else v for v in self.rig_corrected_pa],
            "rig_stiffness_n_per_m": self.rig_stiffness_n_per_m,
        }

    def format(self) -> str:
        """Human-readable summary (what the CLI prints)."""
        elastic, hertz = self.estimates_pa
        lines = [
            f"Recorded    {self.path}  ({self.n_frames} frames, "
            f"{len(self.frame_indices)} augmentations)",
            f"Frames      {', '.join(map(str, self.frame_indices[0]))} (augmentation 0)",
            f"Estimates   elastic {elastic:.4g} Pa, Hertz {hertz:.4g} Pa",
        ]
        if self.rig_corrected_pa is not None:
            rc_elastic, rc_hertz = self.rig_corrected_pa
            lines.append(
                f"Rig-corrected elastic {rc_elastic:.4g} Pa, Hertz {rc_hertz:.4g} Pa (rig "
                f"{self.rig_stiffness_n_per_m:.4g} N/m)"
            )
        lines += [
            f"Objects     {self.object_table}",
        ]
        lines += capture_notes(self.skipped, self.checks, self.warnings)
        return "\n".join(lines)


def capture_notes(
    skipped: Sequence[Any], checks: Mapping[str, Any], warnings: Sequence[str]
) -> list[str]:
    """The report lines a capture's checks add (skipped frames, the force baseline, the
    warnings), as ``record`` and ``estimate`` print them."""
    lines = []
    if skipped:
        lines.append(f"Skipped     {len(skipped)} frames; first: {skipped[0]}")
    baseline = checks.get("baseline_text")
    if baseline:
        lines.append(f"Force       {baseline}")
    lines.extend(f"Warning     {w}" for w in warnings)
    return lines


def _next_grasp(object_dir: Path) -> int:
    taken = [
        int(m.group(1))
        for child in object_dir.iterdir()
        if (m := re.match(r"^\.?(?:partial-)?grasp=(\d+)", child.name))
    ]
    return max(taken, default=-1) + 1


def _write_metadata(object_dir: Path, info: ObjectInfo) -> bool:
    """Create ``metadata.json`` (True: a failed grasp write removes it again), or check
    that an existing one names the same label (False)."""
    path = object_dir / METADATA_FILE
    if path.exists():
        try:
            modulus = float(read_metadata(object_dir).get("youngs_modulus"))  # type: ignore[arg-type]
        except (ValueError, TypeError) as err:
            raise ValueError(f"{path}: unreadable metadata.json ({err}); nothing written") from err
        if not math.isclose(modulus, float(info.modulus_pa), rel_tol=1e-9):
            raise ValueError(
                f"{path} gives {info.name} a modulus of {modulus:.6g} Pa, not "
                f"{info.modulus_pa:.6g}; nothing written (use another object name)"
            )
        return False
    shore = (info.shore_00, info.shore_a, info.shore_d)
    write_metadata(object_dir, info.name, info.modulus_pa, info.material, info.shape, shore)
    return True


def _update_object_table(
    out_dir: Path,
    info: ObjectInfo,
    grasps: int,
    before_replace: Callable[[], None] | None = None,
) -> Path:
    """Add the object to the table, or update its row, keeping other columns and rows. The
    row follows ``metadata.json`` (written or checked against ``info`` just before), also
    for an object deleted and recorded again with another modulus. The caller holds the
    dataset's lock; the file is replaced atomically, ``before_replace`` (the grasp's
    commit) called once the new table is written whole."""

    def text(value: float | None) -> str:
        return "" if value is None else f"{value:g}"

    row = {
        LABEL_COLUMN: info.name,
        SHAPE_COLUMN: info.shape,
        MATERIAL_COLUMN: info.material,
        "Shore 00 [/]": text(info.shore_00),
        "Shore A [/]": text(info.shore_a),
        "Shore D [/]": text(info.shore_d),
        MODULUS_COLUMN: f"{float(info.modulus_pa):.6g}",
        TRIALS_COLUMN: str(grasps),
    }
    path = out_dir / OBJECT_TABLE_FILE
    if path.exists():
        try:
            table = pd.read_csv(path, dtype=str, keep_default_na=False)
        except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as err:
            raise ValueError(f"{path}: not an object table ({err}); nothing updated") from err
        missing = [c for c in (LABEL_COLUMN, MODULUS_COLUMN) if c not in table.columns]
        if missing:
            raise ValueError(f"{path}: not an object table (missing {missing}); nothing updated")
    else:
        table = pd.DataFrame(columns=list(row), dtype=str)
    for column in (SHAPE_COLUMN, MATERIAL_COLUMN, TRIALS_COLUMN):
        if column not in table.columns:
            table[column] = ""
    match = table.index[table[LABEL_COLUMN].str.strip() == info.name]
    if len(match):
        for column, value in row.items():
            # Keep what the user wrote into the table where this recording says nothing.
            if column in table.columns and (value or column == MODULUS_COLUMN):
                table.loc[match[0], column] = value
    else:
        new = {c: row.get(c, "") for c in table.columns}
        table = pd.concat([table, pd.DataFrame([new], dtype=str)], ignore_index=True)
    with atomic_file(path, "w", before_replace=before_replace) as handle:
        table.to_csv(handle, index=False)
    return path


def write_grasp(
    captured: CapturedGrasp,
    out_dir: str | Path,
    info: ObjectInfo,
    *,
    reference: np.ndarray | None = None,
    markers_reference: np.ndarray | None = None,
    max_aug: int = MAX_AUGMENTATIONS,
    sensor: SensorCalibration | None = None,
    markers_sensor: SensorCalibration | None = None,
    rig_stiffness_n_per_m: float | None = None,
) -> RecordedGrasp:
    """Write a captured grasp as ``OUT/{object}/grasp={next}/augmentation={k}/``.

    The grasp number is the next free one. The grasp is written under a hidden
    ``.partial-`` name and renamed into place (``outputs.commit_path``) with its
    ``units.json``, so nothing existing is overwritten and an interrupted write leaves no
    half grasp that looks finished.

    Args:
        reference, markers_reference: the no-contact frame of each sensor; default the
            calibration's, else the first frame.
        sensor, markers_sensor: the sensors' calibrations (depth models, pixel density).
        rig_stiffness_n_per_m: the rig's stiffness [N/m] (``calibrate-rig``): the result
            also holds the rig-corrected estimates (``RecordedGrasp.rig_corrected_pa``).

    Raises:
        ValueError: the grasp has no frame selection (nothing is written), or the object
            exists with another modulus.
    """
    # No selection or implausible readings: fail before any work (the depth caps below
    # only drop augmentations, so these frames include every frame written).
    checked_selection(captured, max_aug)
    computed = grasp_estimates(
        captured,
        reference=reference,
        markers_reference=markers_reference,
        sensor=sensor,
        markers_sensor=markers_sensor,
        rig_stiffness_n_per_m=rig_stiffness_n_per_m,
    )
    fingers = computed.fingers
    indices = augmented_indices(
        captured.force_n,
        max_aug,
        modulus_pa=info.modulus_pa,
        max_depth_mm=[d.reshape(len(d), -1).max(axis=1) for _, d in fingers.values()],
        timestamps_s=captured.timestamp_s,
    )
    estimates = computed.estimates_pa
    rig_corrected = computed.rig_corrected_pa
    # Checked before anything is created; claimed (the marker written) under the lock, so
    # concurrent recordings into a new dataset never see each other's half-made marker.
    out = claim_dataset_dir(out_dir, create=False)
    out.mkdir(parents=True, exist_ok=True)
    with exclusive_lock(out / LOCK_FILE, what=f"the dataset {out}"):
        claim_dataset_dir(out)
        units = GraspUnits(computed.units, recording_estimator(sensor).name, rig_stiffness_n_per_m)
        _check_dataset_units(out, units)
        object_dir = out / info.name
        new_object = not object_dir.exists()
        object_dir.mkdir(parents=True, exist_ok=True)
        grasp = _next_grasp(object_dir)
        partial = object_dir / f"{PARTIAL_PREFIX}grasp={grasp}-{os.getpid()}"
        final = grasp_dir(object_dir, grasp)
        created_metadata = committed = False

        def commit() -> None:
            nonlocal committed
            commit_path(partial, final)
            committed = True

        try:
            created_metadata = _write_metadata(object_dir, info)
            write_units_file(partial, units)  # committed with the grasp, never apart
            for k, idx in enumerate(indices):
                sel = list(idx)
                write_sample(
                    augmentation_dir(partial, k),
                    {
                        finger: (images[sel], depths[sel])
                        for finger, (images, depths) in fingers.items()
                    },
                    captured.force_n[sel],
                    captured.width_m[sel],
                    estimates,
                    rig_estimates_pa=rig_corrected,
                )
            # The grasp is committed only once the new object table is written whole
            # (just before it replaces the old one): a full disk leaves neither, so a
            # re-run records the grasp once.
            grasps = len(numbered_dirs(object_dir, GRASP_DIR)) + 1
            table = _update_object_table(out, info, grasps, before_replace=commit)
        except BaseException:
            if committed:  # the table could not replace the old one: take the grasp back
                with contextlib.suppress(OSError):
                    os.rename(final, partial)
            shutil.rmtree(partial, ignore_errors=True)
            # A full disk or Ctrl-C: leave no labelled object without grasps behind.
            if created_metadata:
                (object_dir / METADATA_FILE).unlink(missing_ok=True)
            if new_object:
                with contextlib.suppress(OSError):  # only when empty
                    object_dir.rmdir()
            raise
    return RecordedGrasp(
        path=final,
        grasp=grasp,
        frame_indices=indices,
        estimates_pa=estimates,
        n_frames=len(captured),
        skipped=list(captured.skipped),
        object_table=table,
        rig_corrected_pa=rig_corrected,
        rig_stiffness_n_per_m=rig_stiffness_n_per_m,
    )


def _check_dataset_units(out: Path, units: GraspUnits) -> None:
    """Refuse a grasp whose estimates would not be in the units of the dataset's earlier
    grasps, each read from its own ``units.json`` (``raw_layout.tree_units``), so a deleted
    or copied file relabels nothing. The caller holds the dataset's lock.

    Raises:
        ValueError: other units (naming both and an earlier grasp), or a dataset whose
            grasps are already in two.
    """
    grasps = [
        directory
        for child in sorted(out.iterdir())
        if child.is_dir() and not child.name.startswith(".")
        for _, directory in numbered_dirs(child, GRASP_DIR)
    ]
    if not grasps:
        return
    # The rig stiffness is left out, as import leaves it out (``tree_units``): a grasp
    # recorded with another --rig, or without, only keeps the dataset's rig-corrected
    # estimates out of its store (the import report says so).
    earlier = replace(tree_units(grasps).units, rig_stiffness_n_per_m=None)
    this = replace(units, rig_stiffness_n_per_m=None)
    if earlier != this:
        raise ValueError(
            f"{out} holds grasps with {earlier.describe()} (e.g. {grasps[0]}), this recording "
            f"has {this.describe()}: their estimates would be mixed; nothing written (record "
            "into another dataset)"
        )


def claim_dataset_dir(out_dir: str | Path, *, create: bool = True) -> Path:
    """Make ``out_dir`` a dataset directory of ``record`` (``outputs.claim_output_dir``;
    docs/data.md, "Recording your own grasps"). ``create=False`` only checks."""
    return claim_output_dir(out_dir, OUTPUT_KIND, recognise=_is_unmarked_recording, create=create)


def _is_unmarked_recording(path: Path) -> bool:
    """Whether another ``record`` is creating the dataset ``path`` (its marker not yet read)."""
    names = {child.name for child in path.iterdir()}
    # Its lock, its marker, or the marker's temp file (outputs.atomic_file) being written.
    if all(name == LOCK_FILE or name.startswith(MARKER_NAME) for name in names):
        return True
    # Read again after the listing: a concurrent record that created an object directory
    # had finished its marker before, though the first read may have caught it half written.
    return output_kind(path) == OUTPUT_KIND


def record_grasp(
    source: FrameSourceBase,
    readings: ReadingsCallback,
    out_dir: str | Path,
    info: ObjectInfo,
    *,
    calibration: SensorCalibration | None = None,
    reference: np.ndarray | None = None,
    markers_source: FrameSourceBase | None = None,
    markers_calibration: SensorCalibration | None = None,
    max_frames: int | None = None,
    stop_on_release: bool = True,
    max_aug: int = MAX_AUGMENTATIONS,
    rig_stiffness_n_per_m: float | None = None,
) -> RecordedGrasp:
    """Capture one grasp from ``source`` with ``readings`` and write it; what looks wrong
    is in the result's ``warnings`` (docs/inference.md, "Record and train").

    Args:
        source: an open frame source (with a calibration: ``calibration.open(spec)``, so
            the geometry matches the reference).
        readings: ``timestamp_s -> (force_n, width_m)``, e.g. ``Readings.from_csv(path)``.
        reference: a no-contact uint8 BGR camera or sensor frame; replaces the
            calibration's reference.
        rig_stiffness_n_per_m: the rig's stiffness [N/m]: also report the rig-corrected
            estimates (:func:`write_grasp`).

    Raises:
        OutputExistsError: ``out_dir`` exists and is not a dataset ``record`` wrote
            (checked before the capture starts).
    """
    claim_dataset_dir(out_dir, create=False)  # refuse a store or a run directory first
    captured, used, warnings, checks = capture_checked(
        source,
        readings,
        calibration=calibration,
        reference=reference,
        markers_source=markers_source,
        max_frames=max_frames,
        stop_on_release=stop_on_release,
    )
    result = write_grasp(
        captured,
        out_dir,
        info,
        reference=used,
        max_aug=max_aug,
        sensor=calibration,
        markers_sensor=markers_calibration,
        rig_stiffness_n_per_m=rig_stiffness_n_per_m,
    )
    missing = [
        name
        for name, value in zip(("elastic", "Hertz"), result.estimates_pa, strict=True)
        if not math.isfinite(value)
    ]
    if missing:
        # The grasp is written (the dataset has such grasps too), but an ALL model will
        # skip it: say so now rather than at `predict`, which only counts skipped samples.
        warnings.append(
            f"no {' or '.join(missing)} analytical estimate for this grasp (too little "
            "contact area or depth at this frame size and pixel density): ALL models will "
            "skip it; Image, ImageF and ImageFW models can use it"
        )
    result.warnings, result.checks = warnings, checks
    return result
