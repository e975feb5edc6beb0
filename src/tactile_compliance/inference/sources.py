"""Read grasps for prediction from a GraspStore, a raw dataset directory or a press video.

All readers return a :class:`GraspBatch` in the store's conventions (uint8 RGB frames
``(B, 3, H, W, 3)``, force in N, width in m, estimates in Pa) and reuse the importers'
own code, so a grasp read here reaches the model exactly as it would through
``tactile-compliance import`` + the evaluation path:

* GraspStore directory (``header.json``): frames and columns as stored.
* Raw dataset directory (``{object}/grasp={g}/augmentation={k}/``, a grasp directory or
  an object directory): the Burgess importer's safe readers (allow-list unpickler,
  BGR -> RGB flip), its resize, and the store's uint8 quantisation.
* Video (``.avi``, ...): the Shore-hardness importer's decoder and press-frame rule
  (first, midway, brightest frame); raw frames, no force/width/estimates.

:func:`predict_path` is the library side of ``tactile-compliance predict``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pandas as pd

from tactile_compliance.data.image_ops import resize_frames
from tactile_compliance.data.raw_layout import (
    ESTIMATE_FILES,
    FINGER_FILES,
    FORCES_FILE,
    VIDEO_SUFFIXES,
    WIDTHS_FILE,
    FingerChoice,
    SampleError,
    load_estimate,
    load_frames,
    load_vector,
    read_metadata,
    recorded_units,
    sample_dirs,
)
from tactile_compliance.data.store import (
    ESTIMATE_COLUMNS,
    FORCE_COLUMNS,
    HEADER_FILE,
    WIDTH_COLUMNS,
    GraspStore,
    StoreError,
    frames_to_uint8,
)
from tactile_compliance.data.yuan import read_video_frames, select_press_frames
from tactile_compliance.devices import DEFAULT_DEVICE
from tactile_compliance.models import InputStrategy
from tactile_compliance.physics.estimators import WEDGE_UNITS, SensorUnits
from tactile_compliance.runs.metrics import compute_metrics

__all__ = [
    "GraspBatch",
    "format_predictions",
    "predict_path",
    "read_grasp_dir",
    "read_source",
    "read_store",
    "read_video",
]

SourceKind = Literal["store", "grasp_dir", "video"]
#: Identification columns reported for every predicted sample.
ROW_COLUMNS = ("sample_id", "object", "grasp", "augmentation", "finger", "source_path")


@dataclass
class GraspBatch:
    """Grasps ready for ``ComplianceEstimator.predict`` plus what identifies them.

    Attributes:
        frames: (B, 3, H, W, 3) uint8 RGB (store encoding); for a whole store a
            :class:`StoreFrames` that reads on demand, so index it in chunks.
        force_n: (B, 3) N, NaN where unknown.
        width_m: (B, 3) m, NaN where unknown.
        estimates_pa: (B, 2) Pa (elastic E, Hertz E*), NaN where unknown.
        rows: one row per grasp: ``ROW_COLUMNS`` + ``modulus_pa`` (truth, NaN if unknown).
        kind: ``store``, ``grasp_dir`` or ``video``.
        frame_kind: ``difference`` or ``raw`` (videos and Shore-hardness stores).
        unreadable: raw sample directories that could not be read (``grasp``,
            ``augmentation``, ``source_path``, ``reason``); skipped like the importer does.
        sensor_units: depth model and pixel density of ``estimates_pa``.
    """

    frames: np.ndarray | StoreFrames
    force_n: np.ndarray
    width_m: np.ndarray
    estimates_pa: np.ndarray
    rows: pd.DataFrame
    kind: SourceKind
    frame_kind: str
    unreadable: list[dict[str, Any]] = field(default_factory=list)
    sensor_units: SensorUnits = WEDGE_UNITS

    def __len__(self) -> int:
        return len(self.frames)

    def scalars(self, ids: np.ndarray | slice | None = None) -> dict[str, np.ndarray]:
        """``force``/``width``/``estimates`` for ``predict`` (rows ``ids``; all by default)."""
        sel = slice(None) if ids is None else ids
        return {
            "force": self.force_n[sel],
            "width": self.width_m[sel],
            "estimates": self.estimates_pa[sel],
        }


# ---------------------------------------------------------------------- store
class StoreFrames:
    """A store's frames, read on demand with ``os.pread`` (``GraspStore.read_sample``).

    Indexing the store's memmap instead maps the pages it touches into the process, so a
    prediction over a 6 GB store ended with 6 GB counted as resident memory.
    """

    def __init__(self, store: GraspStore) -> None:
        self.store = store

    def __len__(self) -> int:
        return len(self.store)

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(self.store.frames.shape)

    def __getitem__(self, index: Any) -> np.ndarray:
        """uint8 frames (n, 3, H, W, 3) of sample positions (an array, list or slice)."""
        positions = np.arange(len(self))[index] if isinstance(index, slice) else index
        return self.store.read_samples(positions)


def read_store(path: str | Path, ids: np.ndarray | list[int] | None = None) -> GraspBatch:
    """Samples ``ids`` (default all) of a GraspStore; frames are read from the memmap."""
    try:
        store = GraspStore.open(path)
    except StoreError as err:
        raise ValueError(str(err)) from err
    idx = np.arange(len(store)) if ids is None else np.asarray(ids, dtype=np.int64)
    if idx.size and (idx.min() < 0 or idx.max() >= len(store)):
        raise ValueError(f"{path}: sample ids must be in [0, {len(store)}), got {idx.min()}..")
    samples = store.samples.iloc[idx]
    rows = samples[[*ROW_COLUMNS, "modulus_pa"]].reset_index(drop=True)
    # The whole store stays on disk (a full-size store is several GB); callers index it
    # chunk by chunk. An explicit id list is read now.
    frames = StoreFrames(store) if ids is None else StoreFrames(store)[idx]
    return GraspBatch(
        frames=frames,
        force_n=samples[list(FORCE_COLUMNS)].to_numpy(np.float64),
        width_m=samples[list(WIDTH_COLUMNS)].to_numpy(np.float64),
        estimates_pa=samples[list(ESTIMATE_COLUMNS)].to_numpy(np.float64),
        rows=rows,
        kind="store",
        frame_kind=str(store.header.creation_parameters.get("frame_kind", "difference")),
        sensor_units=store.sensor_units,
    )


# ---------------------------------------------------------------------- raw dataset dirs
def _label_pa(sample_dir: Path) -> tuple[str, float]:
    """(object name, modulus in Pa) from the object's ``metadata.json``; NaN if absent."""
    object_dir = sample_dir.parent.parent
    try:
        data = read_metadata(object_dir)
        modulus = float(data.get("youngs_modulus", math.nan))
    except (FileNotFoundError, ValueError, TypeError):
        data, modulus = {}, math.nan
    name = str(data.get("object_name", object_dir.name))
    return name, modulus if modulus > 0 else math.nan


def read_grasp_dir(
    path: str | Path,
    *,
    fingers: FingerChoice = "both",
    image_size: tuple[int, int] | None = None,
) -> GraspBatch:
    """Grasps of a raw dataset directory in the GelSight Young's-modulus layout.

    Accepts an augmentation directory (``.../grasp=g/augmentation=k/`` with ``RGB.pkl``,
    ``forces.pkl``, ...), a grasp directory (all its augmentations) or an object directory
    (all grasps). One sample per (augmentation, finger), like the importer.

    Args:
        path: the directory.
        fingers: ``markerless`` (``RGB.pkl``), ``markers`` (``RGB_markers.pkl``) or both.
        image_size: (H, W) px to resize to with the importer's resize (the training
            store's size); None keeps the files' size.

    Raises:
        ValueError: no sample directory found, an unsafe/corrupt pickle, a wrong shape.
    """
    root = Path(path)
    if not root.is_dir():
        raise ValueError(f"{root}: not a directory")
    if fingers not in ("markerless", "markers", "both"):
        raise ValueError(f"fingers must be markerless, markers or both, got {fingers!r}")
    names = list(FINGER_FILES) if fingers == "both" else [fingers]
    dirs = sample_dirs(root)
    if not dirs:
        raise ValueError(
            f"{root}: no grasp data found; expected an augmentation directory with RGB.pkl "
            f"and forces.pkl, or grasp=g/augmentation=k/ below it"
        )
    frames, forces, widths, estimates, rows = [], [], [], [], []
    unreadable: list[dict[str, Any]] = []
    for grasp, augmentation, directory in dirs:
        try:
            sample = _read_sample_dir(directory, names, image_size)
        except ValueError as err:
            if len(dirs) == 1:
                raise
            # Like the importer: one corrupt augmentation does not sink the whole object.
            unreadable.append(
                {
                    "grasp": grasp,
                    "augmentation": augmentation,
                    "source_path": str(directory),
                    "reason": str(err),
                }
            )
            continue
        for finger, image_file, rgb in sample.images:
            frames.append(rgb)
            forces.append(sample.force)
            widths.append(sample.width)
            estimates.append(sample.estimates)
            rows.append(
                {
                    "sample_id": len(rows),
                    "object": sample.object,
                    "grasp": grasp,
                    "augmentation": augmentation,
                    "finger": finger,
                    "source_path": str(directory / image_file),
                    "modulus_pa": sample.modulus_pa,
                }
            )
    if not frames:
        raise ValueError(f"{root}: no readable sample ({unreadable[0]['reason']})")
    shapes = {f.shape for f in frames}
    if len(shapes) > 1:
        raise ValueError(f"{root}: samples have different frame shapes {sorted(shapes)}")
    return GraspBatch(
        frames=np.stack(frames),
        force_n=np.asarray(forces, dtype=np.float64),
        width_m=np.asarray(widths, dtype=np.float64),
        estimates_pa=np.asarray(estimates, dtype=np.float64),
        rows=pd.DataFrame(rows, columns=[*ROW_COLUMNS, "modulus_pa"]),
        kind="grasp_dir",
        frame_kind="difference",
        unreadable=unreadable,
        sensor_units=recorded_units(Path(root)),
    )


@dataclass
class _SampleDir:
    """What one augmentation directory holds: its images (one per finger) and scalars."""

    object: str
    modulus_pa: float
    force: np.ndarray
    width: np.ndarray
    estimates: list[float]
    images: list[tuple[str, str, np.ndarray]]  # (finger, file name, uint8 frames)


def _read_sample_dir(
    directory: Path, fingers: list[str], image_size: tuple[int, int] | None
) -> _SampleDir:
    """Read one augmentation directory like the importer does.

    Raises:
        ValueError: an unsafe or corrupt pickle, a wrong shape, no image of ``fingers``.
    """
    try:
        obj, modulus = _label_pa(directory)
        sample = _SampleDir(
            object=obj,
            modulus_pa=modulus,
            # forces/widths are needed only by F/W strategies; their absence is reported there.
            force=load_vector(directory, FORCES_FILE, optional=True),
            width=load_vector(directory, WIDTHS_FILE, optional=True),
            estimates=[load_estimate(directory, name) for name in ESTIMATE_FILES],
            images=[],
        )
        for finger in fingers:
            image_file = FINGER_FILES[finger][0]
            if (directory / image_file).is_file():
                # The importer's reader: allow-list unpickler, shape checks, BGR -> RGB.
                rgb = load_frames(directory, image_file, None)
                sample.images.append(
                    (finger, image_file, frames_to_uint8(resize_frames(rgb, image_size)))
                )
    except SampleError as err:
        raise ValueError(f"{directory}: {err}") from err
    if not sample.images:
        wanted = ", ".join(FINGER_FILES[f][0] for f in fingers)
        raise ValueError(f"{directory}: no image file ({wanted})")
    return sample


# ---------------------------------------------------------------------- videos
def read_video(path: str | Path, *, image_size: tuple[int, int] | None = None) -> GraspBatch:
    """One press video -> one sample (first, midway, brightest frame; raw RGB frames).

    Uses the Shore-hardness importer's decoder and frame rule; there is no force, width
    or estimate, so only ``Image`` checkpoints (trained on raw frames) can use it.
    """
    video = Path(path)
    frames = read_video_frames(video)  # ValueError when unreadable
    chosen = frames[list(select_press_frames(frames))]
    return GraspBatch(
        frames=resize_frames(chosen, image_size)[None],
        force_n=np.full((1, 3), np.nan),
        width_m=np.full((1, 3), np.nan),
        estimates_pa=np.full((1, 2), np.nan),
        rows=pd.DataFrame(
            [
                {
                    "sample_id": 0,
                    "object": video.stem,
                    "grasp": 0,
                    "augmentation": 0,
                    "finger": "markerless",
                    "source_path": str(video),
                    "modulus_pa": math.nan,
                }
            ],
            columns=[*ROW_COLUMNS, "modulus_pa"],
        ),
        kind="video",
        frame_kind="raw",
    )


def read_source(
    path: str | Path,
    *,
    fingers: FingerChoice = "both",
    image_size: tuple[int, int] | None = None,
) -> GraspBatch:
    """Dispatch on what ``path`` is: a store, a raw grasp/object directory or a video.

    ``image_size`` resizes raw sources (not stores, which are used as stored).
    """
    path = Path(path)
    if not path.exists():
        raise ValueError(f"{path}: no such file or directory")
    if path.is_file():
        if path.suffix.lower() in VIDEO_SUFFIXES:
            return read_video(path, image_size=image_size)
        raise ValueError(
            f"{path}: not a store, grasp directory or video ({', '.join(VIDEO_SUFFIXES)})"
        )
    if (path / HEADER_FILE).is_file():
        return read_store(path)
    return read_grasp_dir(path, fingers=fingers, image_size=image_size)


# ---------------------------------------------------------------------- predict (CLI)
def predict_path(
    checkpoint: str | Path,
    path: str | Path,
    *,
    device: str = DEFAULT_DEVICE,
    fingers: FingerChoice = "both",
    batch_size: int = 64,
    backbone_weights: str | Path | None = None,
) -> dict[str, Any]:
    """Predict every grasp under ``path`` with ``checkpoint``: the ``predict`` command.

    ``checkpoint``: ``best.pt``, its run directory, or a directory written by ``export
    --safetensors`` (as ``live`` takes). ``backbone_weights``: a local copy of a frozen
    backbone's weights file (see ``ComplianceEstimator.from_checkpoint``).

    Samples missing an input the checkpoint needs (e.g. NaN estimates in a store) are
    skipped and listed with the reason; everything else is predicted in batches.

    Returns:
        A JSON-serialisable dict: ``checkpoint`` (what the model is), ``source`` (path,
        kind, counts), ``predictions`` (one dict per sample: identification, ``pred_pa``,
        ``pred_log10_pa``, and ``true_pa``/``error_decades`` when the truth is known),
        ``skipped`` and ``summary`` (geometric mean, and the paper's metrics when every
        predicted sample has a known modulus).
    """
    from tactile_compliance.inference.estimator import ComplianceEstimator
    from tactile_compliance.inference.pretrained import WEIGHTS_FILE

    if (Path(checkpoint) / WEIGHTS_FILE).is_file():  # an exported directory
        estimator = ComplianceEstimator.from_pretrained(checkpoint, device=device)
    else:
        estimator = ComplianceEstimator.from_checkpoint(
            checkpoint, device=device, backbone_weights=backbone_weights
        )
    source = read_source(path, fingers=fingers, image_size=estimator.store_image_size)
    needed = estimator.required_inputs
    if source.kind == "video" and needed:
        raise ValueError(
            f"{path}: a video carries no force, width or estimates, but checkpoint "
            f"{estimator.source} (inputs={estimator.inputs.value}) needs {', '.join(needed)}; "
            f"use an Image checkpoint"
        )
    if "estimates" in needed:
        estimator.sensor_units.check_same(
            source.sensor_units, trained=f"checkpoint {estimator.source}", used=str(path)
        )
    scalars = source.scalars()
    usable = np.ones(len(source), dtype=bool)
    reasons: list[str] = [""] * len(source)
    for name in needed:
        missing = ~np.all(np.isfinite(scalars[name]), axis=1)
        for i in np.flatnonzero(missing & usable):
            reasons[i] = f"missing {name} (NaN)"
        usable &= ~missing
    if len(source) and not usable.any():
        _refuse_when_nothing_is_usable(path, estimator.source, estimator.inputs, reasons)
    ids = np.flatnonzero(usable)
    pred_pa = np.full(len(source), np.nan)
    pred_log10 = np.full(len(source), np.nan)
    chunk = max(1, int(batch_size)) * 4  # bound memory on large stores
    for start in range(0, ids.size, chunk):
        part = ids[start : start + chunk]
        part_scalars = source.scalars(part)
        prediction = estimator.predict(
            source.frames[part],
            force=part_scalars["force"] if "force" in needed else None,
            width=part_scalars["width"] if "width" in needed else None,
            estimates=part_scalars["estimates"] if "estimates" in needed else None,
            batch_size=batch_size,
        )
        pred_pa[part] = prediction.modulus_pa
        pred_log10[part] = prediction.log10_modulus_pa

    records: list[dict[str, Any]] = []
    skipped = [{**dict.fromkeys(ROW_COLUMNS), **bad} for bad in source.unreadable]
    truth = source.rows["modulus_pa"].to_numpy(np.float64)
    for i, row in enumerate(source.rows.to_dict(orient="records")):
        ident = {k: _plain(row[k]) for k in ROW_COLUMNS}
        if not usable[i]:
            skipped.append({**ident, "reason": reasons[i]})
            continue
        record = {**ident, "pred_pa": float(pred_pa[i]), "pred_log10_pa": float(pred_log10[i])}
        if np.isfinite(truth[i]) and truth[i] > 0:
            record["true_pa"] = float(truth[i])
            record["error_decades"] = float(pred_log10[i] - np.log10(truth[i]))
        records.append(record)

    summary: dict[str, Any] = {"n_predicted": int(ids.size), "n_skipped": len(skipped)}
    if ids.size:
        mean_log10 = float(np.mean(pred_log10[ids]))
        summary["mean_log10_pa"] = mean_log10
        summary["geometric_mean_pa"] = float(10.0**mean_log10)
        known = truth[ids]
        if np.all(np.isfinite(known) & (known > 0)):
            summary["metrics"] = compute_metrics(known, pred_pa[ids], estimator.constants)
    return {
        "checkpoint": estimator.describe(),
        "source": {
            "path": str(path),
            "kind": source.kind,
            "frame_kind": source.frame_kind,
            "samples": len(source),
        },
        "predictions": records,
        "skipped": skipped,
        "summary": summary,
    }


def _refuse_when_nothing_is_usable(
    path: str | Path, checkpoint: str, inputs: InputStrategy, reasons: list[str]
) -> None:
    """A ValueError naming why no sample of ``path`` can be predicted, and which input
    strategies could (before, `predict` printed only "Skipped N samples" and exit 0)."""
    lacking = {name for name in inputs.needs if any(name in reason for reason in reasons)}
    could = [s.value for s in InputStrategy if not lacking & set(s.needs)]
    raise ValueError(
        f"{path}: none of its {len(reasons)} samples can be predicted by {checkpoint} "
        f"(inputs={inputs.value}): {skip_reasons([{'reason': r} for r in reasons])}; "
        f"a checkpoint of {' or '.join(could)} inputs can"
    )


def skip_reasons(skipped: list[dict[str, Any]]) -> str:
    """Why samples were skipped, most common first: ``"missing estimates (NaN): 4"``."""
    counts: dict[str, int] = {}
    for row in skipped:
        counts[str(row.get("reason"))] = counts.get(str(row.get("reason")), 0) + 1
    return ", ".join(f"{reason}: {n}" for reason, n in sorted(counts.items(), key=lambda c: -c[1]))


def _plain(value: Any) -> Any:
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    return value


def format_predictions(report: dict[str, Any], max_rows: int = 20) -> str:
    """Human-readable text of a :func:`predict_path` report (what the CLI prints)."""
    ckpt, source, summary = report["checkpoint"], report["source"], report["summary"]
    size = "x".join(map(str, ckpt["image_size"])) if ckpt["image_size"] else "native"
    lines = [
        f"Checkpoint  {ckpt['checkpoint']}  ({ckpt['model']}, inputs {ckpt['inputs']}, "
        f"frames {size})",
        f"Source      {source['path']}  ({source['kind']}, {source['samples']} samples)",
    ]
    predictions = report["predictions"]
    if predictions:
        has_truth = all("true_pa" in p for p in predictions)
        header = f"{'object':<24} {'grasp':>5} {'aug':>3} {'finger':<10} {'E_pred [Pa]':>12}"
        if has_truth:
            header += f" {'E_true [Pa]':>12} {'err [dec]':>9}"
        lines += ["", header]
        for p in predictions[:max_rows]:
            line = (
                f"{str(p['object'])[:24]:<24} {p['grasp']:>5} {p['augmentation']:>3} "
                f"{p['finger']:<10} {p['pred_pa']:>12.3g}"
            )
            if has_truth:
                line += f" {p['true_pa']:>12.3g} {p['error_decades']:>+9.2f}"
            lines.append(line)
        if len(predictions) > max_rows:
            lines.append(f"... {len(predictions) - max_rows} more (use --json for all)")
    lines.append("")
    if summary["n_predicted"]:
        lines.append(
            f"Estimate    {summary['geometric_mean_pa']:.4g} Pa (geometric mean of "
            f"{summary['n_predicted']}; log10 {summary['mean_log10_pa']:.3f})"
        )
    if "metrics" in summary:
        m = summary["metrics"]
        lines.append(
            f"Metrics     log10 accuracy {m['log10_accuracy']:.3f}, N-MSE {m['nmse']:.4f}, "
            f"MAE {m['mae_decades']:.3f} decades"
        )
    if report["skipped"]:
        lines.append(
            f"Skipped     {len(report['skipped'])} samples ({skip_reasons(report['skipped'])}; "
            "see --json)"
        )
    return "\n".join(lines)
