"""Read grasps for prediction from a GraspStore, a raw dataset directory or a press video,
through the importers' own readers. See docs/inference.md, "Command line".
"""

from __future__ import annotations

import math
from collections.abc import Sequence
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
    RIG_ESTIMATE_FILES,
    VIDEO_SUFFIXES,
    WIDTHS_FILE,
    FingerChoice,
    SampleError,
    load_estimate,
    load_frames,
    load_vector,
    read_metadata,
    sample_dirs,
    sample_grasp_dir,
    tree_units,
)
from tactile_compliance.data.store import (
    ESTIMATE_COLUMNS,
    FORCE_COLUMNS,
    HEADER_FILE,
    RIG_ESTIMATE_COLUMNS,
    WIDTH_COLUMNS,
    GraspStore,
    StoreError,
    frames_to_uint8,
)
from tactile_compliance.data.yuan import read_video_frames, select_press_frames
from tactile_compliance.physics.estimators import WEDGE_UNITS, SensorUnits

__all__ = [
    "GraspBatch",
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
        rig_estimates_pa: (B, 2) Pa, the rig-corrected pair (``record --rig``, the
            generator), NaN where unknown; None: the source has none.
        rig_stiffness_n_per_m: the rig stiffness [N/m] they were made at; None: none
            (or grasps of different rigs, whose pairs are then not read).
        rows: one row per grasp: ``ROW_COLUMNS`` + ``modulus_pa`` (truth, NaN if unknown).
        kind: ``store``, ``grasp_dir`` or ``video``.
        frame_kind: ``difference`` or ``raw`` (videos and Shore-hardness stores).
        unreadable: raw sample directories that could not be read (``grasp``,
            ``augmentation``, ``source_path``, ``reason``); skipped like the importer does.
        sensor_units: depth model and pixel density of ``estimates_pa`` and ``depth_mm``.
        depth_mm: (B, 3, h, w) depth maps in mm as the store keeps them (a
            :class:`StoreDepth` for a whole store), None when the source holds none.
        source_image_size: (H, W) px of the frames as the source holds them, before any
            resize to the model's store size (None: not known).
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
    depth_mm: np.ndarray | StoreDepth | None = None
    source_image_size: tuple[int, int] | None = None
    rig_estimates_pa: np.ndarray | None = None
    rig_stiffness_n_per_m: float | None = None

    def __len__(self) -> int:
        return len(self.frames)

    def inputs(self, names: Sequence[str], ids: np.ndarray | None = None) -> dict[str, Any]:
        """The ``predict`` inputs ``names`` (``data.inputs.INPUTS`` names) of rows ``ids``
        (all by default), in their physical units."""
        columns = {
            "frames": self.frames,
            "depth": self.depth_mm,
            "force": self.force_n,
            "width": self.width_m,
            "estimates": self.estimates_pa,
            "rig_estimates": (
                np.full((len(self), 2), np.nan)
                if self.rig_estimates_pa is None
                else self.rig_estimates_pa
            ),
        }
        return {name: columns[name][slice(None) if ids is None else ids] for name in names}


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
    depth = None
    if store.has_depth:
        depth = StoreDepth(store) if ids is None else StoreDepth(store)[idx]
    return GraspBatch(
        frames=frames,
        depth_mm=depth,
        force_n=samples[list(FORCE_COLUMNS)].to_numpy(np.float64),
        width_m=samples[list(WIDTH_COLUMNS)].to_numpy(np.float64),
        estimates_pa=samples[list(ESTIMATE_COLUMNS)].to_numpy(np.float64),
        rig_estimates_pa=samples[list(RIG_ESTIMATE_COLUMNS)].to_numpy(np.float64),
        rig_stiffness_n_per_m=store.units.rig_stiffness_n_per_m,
        rows=rows,
        kind="store",
        frame_kind=str(store.header.creation_parameters.get("frame_kind", "difference")),
        source_image_size=tuple(store.header.image_size),
        sensor_units=store.sensor_units,
    )


class StoreDepth(StoreFrames):
    """A store's depth maps, read on demand (``GraspStore.read_depth``), float32 mm."""

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(self.store.depth.shape)  # type: ignore[union-attr]

    def __getitem__(self, index: Any) -> np.ndarray:
        """Depth maps (n, 3, h, w) mm of sample positions (an array, list or slice)."""
        positions = np.arange(len(self))[index] if isinstance(index, slice) else index
        return self.store.read_depth(positions)


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
    """Grasps of a raw augmentation, grasp or object directory; one sample per
    (augmentation, finger), like the importer.

    Args:
        fingers: ``markerless`` (``RGB.pkl``), ``markers`` (``RGB_markers.pkl``) or both.
        image_size: (H, W) px to resize to with the importer's resize; None keeps the
            files' size.

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
    # Each grasp's own units.json; ValueError: grasps in two units. The rig-corrected
    # pairs are read only at one rig stiffness, as import reads them.
    units = tree_units(sample_grasp_dir(d) for _, _, d in dirs).units
    rig = units.rig_stiffness_n_per_m is not None
    frames, forces, widths, estimates, rig_estimates, rows = [], [], [], [], [], []
    unreadable: list[dict[str, Any]] = []
    native: tuple[int, int] | None = None
    for grasp, augmentation, directory in dirs:
        try:
            sample = _read_sample_dir(directory, names, image_size, rig=rig)
            native = native or sample.native_size
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
            rig_estimates.append(sample.rig_estimates)
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
        rig_estimates_pa=np.asarray(rig_estimates, dtype=np.float64).reshape(-1, 2),
        rows=pd.DataFrame(rows, columns=[*ROW_COLUMNS, "modulus_pa"]),
        kind="grasp_dir",
        frame_kind="difference",
        unreadable=unreadable,
        source_image_size=native,
        sensor_units=units.sensor,
        rig_stiffness_n_per_m=units.rig_stiffness_n_per_m,
    )


@dataclass
class _SampleDir:
    """What one augmentation directory holds: its images (one per finger) and scalars."""

    object: str
    modulus_pa: float
    force: np.ndarray
    width: np.ndarray
    estimates: list[float]
    rig_estimates: list[float]
    images: list[tuple[str, str, np.ndarray]]  # (finger, file name, uint8 frames)
    native_size: tuple[int, int] | None = None  # (H, W) px of the files, before any resize


def _read_sample_dir(
    directory: Path, fingers: list[str], image_size: tuple[int, int] | None, *, rig: bool
) -> _SampleDir:
    """Read one augmentation directory like the importer does; ``rig``: also its
    rig-corrected pair (else NaN).

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
            rig_estimates=[
                load_estimate(directory, name) if rig else math.nan for name in RIG_ESTIMATE_FILES
            ],
            images=[],
        )
        for finger in fingers:
            image_file = FINGER_FILES[finger][0]
            if (directory / image_file).is_file():
                # The importer's reader: allow-list unpickler, shape checks, BGR -> RGB.
                rgb = load_frames(directory, image_file, None)
                sample.native_size = (int(rgb.shape[1]), int(rgb.shape[2]))
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
    """One press video -> one sample of raw RGB frames (the Shore-hardness importer's
    decoder and frame rule), with no force, width or estimates."""
    video = Path(path)
    frames = read_video_frames(video)  # ValueError when unreadable
    chosen = frames[list(select_press_frames(frames))]
    return GraspBatch(
        source_image_size=(int(chosen.shape[1]), int(chosen.shape[2])),
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
    """Dispatch on what ``path`` is: a store (used as stored), a raw grasp/object directory
    or a video (both resized to ``image_size``)."""
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
