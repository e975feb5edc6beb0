"""GraspStore: the one on-disk format every data source is imported into (frames as uint8
RGB difference images (N, 3, H, W, 3), memory-mapped; optional float16 depth maps [mm],
NaN for a sample without one; a checked table), read here and written by
``data.store_writer.GraspStoreWriter``.

See docs/data.md, "The GraspStore format (version 1)".
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
import shutil
import socket
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from tactile_compliance.data.plausibility import (
    DEPTH,
    ESTIMATE,
    FORCE,
    MODULUS,
    WIDTH,
    PlausibleRange,
    as_real_number,
    check_size,
    dtype_problem,
)
from tactile_compliance.outputs import (
    MARKER_NAME,
    check_format_version,
    output_kind,
    process_alive,
)
from tactile_compliance.physics.estimators import (
    DATASET_UNITS,
    AnalyticalEstimator,
    GraspUnits,
    SensorUnits,
)

FORMAT_VERSION = 1
#: The marker of every tactile-compliance output, kind "store" here: ``--overwrite``
#: replaces only a directory that has it (:func:`is_store_dir`).
STORE_MARKER = MARKER_NAME
STORE_KIND = "store"
#: Written into a writer's temporary directory when it is created: who owns it.
PARTIAL_MARKER = ".partial-owner.json"
HEADER_FILE = "header.json"
SAMPLES_FILE = "samples.parquet"
FRAMES_FILE = "frames.u8"
DEPTH_FILE = "depth.f16"
FRAMES_PER_SAMPLE = 3
#: Depth maps are stored at ``ceil(H / DEPTH_DOWNSAMPLE) x ceil(W / DEPTH_DOWNSAMPLE)``.
DEPTH_DOWNSAMPLE = 4
#: Largest stored |depth| in mm: a gel is a few mm thick, so anything beyond is no depth map.
MAX_ABS_DEPTH_MM = DEPTH.high

FORCE_COLUMNS = ("force_n_0", "force_n_1", "force_n_2")
WIDTH_COLUMNS = ("width_m_0", "width_m_1", "width_m_2")
ESTIMATE_COLUMNS = ("elastic_estimate_pa", "hertz_estimate_pa")
#: The same two estimates with the rig's own closure taken out of the widths
#: (``physics.contact.rig_corrected_widths_m``) with the row's ``rig_stiffness_n_per_m``;
#: NaN where the grasp has none (recorded without ``--rig``, or the fit failed).
RIG_ESTIMATE_COLUMNS = ("elastic_rig_estimate_pa", "hertz_rig_estimate_pa")
DEPTH_COLUMNS = ("depth_max_mm_0", "depth_max_mm_1", "depth_max_mm_2")
#: What each row's analytical estimates were made with (``physics.estimators.GraspUnits``):
#: the estimator's name, the depth model, the pixel density in px/mm (NaN: the
#: estimator's own, the Wedge's) and the rig stiffness in N/m of the rig-corrected
#: estimates (NaN: none). Every row carries them, so a store never relabels a grasp;
#: :attr:`GraspStore.units` refuses a store whose rows disagree.
UNIT_COLUMNS = ("analytical_estimator", "depth_model", "px_per_mm", "rig_stiffness_n_per_m")
#: Columns a store written before the rig-corrected estimates lacks: reading it fills them
#: with NaN (no rig-corrected estimates), so those stores keep opening.
_LATER_COLUMNS = (*RIG_ESTIMATE_COLUMNS, "rig_stiffness_n_per_m")
# Column order of samples.parquet. Units: forces in N, widths in m, moduli and
# estimates in Pa, depths in mm. Missing values are NaN (e.g. the Shore-hardness
# videos have no force, width, estimates or depth).
SAMPLE_COLUMNS: tuple[str, ...] = (
    *("sample_id", "object", "grasp", "augmentation", "finger", "material", "shape"),
    "modulus_pa",
    *FORCE_COLUMNS,
    *WIDTH_COLUMNS,
    *ESTIMATE_COLUMNS,
    *RIG_ESTIMATE_COLUMNS,
    *DEPTH_COLUMNS,
    *UNIT_COLUMNS,
    "source_path",
)
#: The plausibility rule of each numeric column. NaN (missing) is allowed in all of them
#: but ``modulus_pa``, the training label.
COLUMN_RULES: dict[str, PlausibleRange] = {
    "modulus_pa": MODULUS,
    **{column: FORCE for column in FORCE_COLUMNS},
    **{column: WIDTH for column in WIDTH_COLUMNS},
    **{column: ESTIMATE for column in ESTIMATE_COLUMNS},
    **{column: ESTIMATE for column in RIG_ESTIMATE_COLUMNS},
}
_STRING_COLUMNS = (
    "object",
    "finger",
    "material",
    "shape",
    "analytical_estimator",
    "depth_model",
    "source_path",
)
_INT_COLUMNS = ("sample_id", "grasp", "augmentation")


class StoreError(Exception):
    """A store is missing, incomplete or inconsistent."""


class NotAStoreError(StoreError):
    """A path to be replaced is not a GraspStore; it was left untouched."""


class StoreWriteError(StoreError):
    """Writing a store failed (e.g. a full disk); everything written was removed.

    ``reason`` is the operating system's message, ``errno`` its error number."""

    def __init__(self, message: str, reason: str = "", errno: int | None = None) -> None:
        super().__init__(message)
        self.reason = reason or message
        self.errno = errno


#: Decoding is ``(u + FRAME_DECODE_OFFSET) / 255``; see :func:`frames_to_uint8`.
FRAME_DECODE_OFFSET = 0.5
#: The range of difference grey levels k (``x = k / 255 + 0.5``) that uint8 holds:
#: ``u = floor(k + 127.5) = k + 127`` lies in 0..255 for k in -127..+128. A larger
#: difference is stored as the nearest end (clipped) and counted.
MIN_DIFFERENCE_LEVEL = -127
MAX_DIFFERENCE_LEVEL = 128


def encode_frames(frames: np.ndarray) -> tuple[np.ndarray, int]:
    """:func:`frames_to_uint8` and the number of values it clipped to 0 or 255 (the
    saturated pixels the frame rule :data:`~tactile_compliance.data.plausibility.FRAME`
    allows); uint8 input is never clipped."""
    frames = np.asarray(frames)
    if frames.dtype == np.uint8:
        return frames, 0
    # float64 keeps k/255 + 0.5 exact enough that floor never drops a level.
    levels = np.floor(frames.astype(np.float64) * 255.0)
    clipped = int(np.count_nonzero((levels < 0) | (levels > 255)))
    return np.clip(levels, 0, 255).astype(np.uint8), clipped


def frames_to_uint8(frames: np.ndarray) -> np.ndarray:
    """Quantise float difference images in [0, 1] (any shape) to uint8 ``floor(x * 255)``.

    The recording pipeline's values are ``k / 255 + 0.5`` with an integer k (uint8 frame
    minus uint8 blurred reference), so ``x * 255`` always ends in .5: rounding would merge
    neighbouring grey levels, while ``floor`` keeps every level and the decoder
    (:func:`frames_from_uint8`, ``(u + 0.5) / 255``) recovers the value exactly. Arbitrary
    floats are reproduced within half a grey level, without bias. uint8 input (raw camera
    frames) is stored unchanged; differences beyond :data:`MIN_DIFFERENCE_LEVEL` ..
    :data:`MAX_DIFFERENCE_LEVEL` are clipped (:func:`encode_frames` counts them).
    """
    return encode_frames(frames)[0]


def frames_from_uint8(frames: np.ndarray) -> np.ndarray:
    """Decode stored uint8 frames to float32 ``(u + 0.5) / 255`` (inverse of the encoding)."""
    decoded = np.asarray(frames, dtype=np.float32) + np.float32(FRAME_DECODE_OFFSET)
    return decoded / np.float32(255.0)


def depth_size_for(image_size: tuple[int, int]) -> tuple[int, int]:
    """The stored depth-map size (h, w) px for frames of ``image_size`` (H, W) px."""
    height, width = image_size
    return (-(-int(height) // DEPTH_DOWNSAMPLE), -(-int(width) // DEPTH_DOWNSAMPLE))


def store_depth_maps(depth_mm: np.ndarray, image_size: tuple[int, int]) -> np.ndarray:
    """Depth maps (n, H, W) mm at a sensor's resolution as a store of frames ``image_size``
    (H, W) px keeps them: area-averaged to :func:`depth_size_for`, float32 mm; what the
    importer stores and what a depth-map model reads."""
    # Imported here: cv2 loads with it, and the command line reads the store module to
    # check a config before anything heavy.
    from tactile_compliance.data.image_ops import resize_frames

    return resize_frames(np.asarray(depth_mm, dtype=np.float32), depth_size_for(image_size))


def _column_numbers(series: pd.Series) -> tuple[np.ndarray, np.ndarray]:
    """A numeric column as float64, and where it holds no number (a word, a bool, a complex
    number); numeric text counts, None/NaN stay NaN (missing) and are not flagged."""
    if series.dtype.kind in "iuf":
        values = series.to_numpy(dtype=np.float64, na_value=np.nan)
        return values, np.zeros(len(series), dtype=bool)
    values = np.full(len(series), np.nan)
    not_number = np.zeros(len(series), dtype=bool)
    for row, item in enumerate(series.tolist()):
        if item is None or (isinstance(item, float) and np.isnan(item)):
            continue
        try:
            values[row] = float(item) if isinstance(item, str) else as_real_number(item)
        except (TypeError, ValueError):
            not_number[row] = True
    return values, not_number


def validate_samples(samples: pd.DataFrame) -> list[str]:
    """What is wrong with a store's table, one message per problem (empty: nothing).

    Every column of :data:`SAMPLE_COLUMNS`; ``sample_id`` equal to the row number (the
    index into ``frames.u8``); every numeric column within its rule of
    :data:`COLUMN_RULES` or NaN (missing), but ``modulus_pa``, the label, never NaN; a
    column of another dtype is a problem, never cast (docs/data.md, "Opening a store
    checks its table"). Messages name the column and the first bad (0-based) rows.
    """
    problems = []
    missing = [c for c in SAMPLE_COLUMNS if c not in samples.columns]
    if missing:
        problems.append(f"missing columns {missing}")

    def first(rows: np.ndarray, column: str) -> str:
        values = samples[column].iloc[rows[:5]].tolist()  # plain Python values to print
        shown = ", ".join(f"row {r}: {v!r}" for r, v in zip(rows[:5], values, strict=True))
        more = f" and {len(rows) - 5} more" if len(rows) > 5 else ""
        return f"{shown}{more}"

    if "sample_id" in samples.columns:
        ids = pd.to_numeric(samples["sample_id"], errors="coerce").to_numpy(dtype=np.float64)
        duplicated = np.flatnonzero(samples["sample_id"].duplicated().to_numpy())
        wrong = np.flatnonzero(ids != np.arange(len(samples)))
        if duplicated.size:
            problems.append(
                f"column sample_id has {duplicated.size} duplicated value(s): "
                f"{first(duplicated, 'sample_id')}"
            )
        elif wrong.size:
            problems.append(
                f"column sample_id must equal the row number (it indexes {FRAMES_FILE}); "
                f"{wrong.size} row(s) differ: {first(wrong, 'sample_id')}"
            )
    if all(c in samples.columns for c in UNIT_COLUMNS) and len(samples):
        for row, problem in _unit_problems(samples):
            problems.append(
                f"columns {', '.join(UNIT_COLUMNS)}: {problem}; {first(row, 'depth_model')}"
            )
    for column, rule in COLUMN_RULES.items():
        if column not in samples.columns:
            continue
        series = samples[column]
        label = column == "modulus_pa"
        missing = "" if label else ", or NaN (missing)"
        if series.dtype.kind != "O" and dtype_problem(series.dtype):
            problems.append(
                f"column {column} has dtype {series.dtype}, expected numbers "
                f"({rule.quantity} in {rule.unit})"
            )
            continue
        values, not_number = _column_numbers(series)
        bad_mask = not_number | rule.outside(values)
        if label:
            bad_mask |= np.isnan(values)
        bad = np.flatnonzero(bad_mask)
        if bad.size:
            problems.append(
                f"column {column} must be {rule.requirement()}{missing}; {bad.size} bad "
                f"row(s): {first(bad, column)}"
            )
    return problems


def row_units(
    estimator: Any, depth_model: Any, px_per_mm: Any, rig_stiffness_n_per_m: Any
) -> GraspUnits:
    """A row's :data:`UNIT_COLUMNS` as ``GraspUnits`` (ValueError: invalid values)."""
    px, k = as_real_number(px_per_mm), as_real_number(rig_stiffness_n_per_m)
    sensor = SensorUnits(str(depth_model), None if math.isnan(px) else px)
    return GraspUnits(sensor, str(estimator), None if math.isnan(k) else k)


def _unit_problems(samples: pd.DataFrame) -> list[tuple[np.ndarray, str]]:
    """(rows, why) for each distinct invalid combination of a table's unit columns."""
    problems = []
    columns = samples[list(UNIT_COLUMNS)]
    for key, rows in columns.groupby(list(UNIT_COLUMNS), dropna=False, sort=False).indices.items():
        try:
            row_units(*key)
        except (TypeError, ValueError) as err:
            problems.append((np.sort(rows), str(err)))
    return problems


def store_problems(path: str | Path) -> list[str]:
    """Everything wrong with the store at ``path`` (empty: it opens and validates).

    Never raises; for ``info`` to list the problems of a store that does not open."""
    try:
        store = GraspStore.open(path, validate=False)
    except StoreError as err:
        return [str(err)]
    return validate_samples(store.samples)


def is_store_dir(path: str | Path) -> bool:
    """Whether ``path`` is a GraspStore directory that may be replaced (``--overwrite``): a
    real directory (not a link) with the store marker. Nothing else is ever replaced."""
    path = Path(path)
    return not path.is_symlink() and path.is_dir() and output_kind(path) == STORE_KIND


def store_kind_hint(path: str | Path) -> str:
    """What ``path`` is, for the message refusing to replace it."""
    path = Path(path)
    if path.is_symlink():
        return "a symbolic link"
    if not path.is_dir():
        return "not a directory"
    return f"a directory without {STORE_MARKER}"


# ------------------------------------------------------------- leftovers of killed writers
def _partial_owner_gone(partial: Path) -> bool:
    """Whether ``partial`` is a writer's temporary directory whose process is gone."""
    if partial.is_symlink() or not partial.is_dir():
        return False
    try:
        owner = json.loads((partial / PARTIAL_MARKER).read_text())
        pid, host = int(owner["pid"]), str(owner["host"])
    except (OSError, ValueError, KeyError, TypeError):
        return False  # not written by a writer (or by one killed before the marker)
    if owner.get("kind") != STORE_KIND or host != socket.gethostname():
        return False  # another machine's (shared file system): cannot tell, keep it
    return not process_alive(pid, owner.get("start"))


def recover_interrupted_writes(path: str | Path) -> list[Path]:
    """Tidy what killed writers of the store ``path`` left next to it (docs/data.md, "A
    killed import"); returns what was removed or restored.

    A ``.NAME.partial-*`` directory is deleted only when its owner file names a process of
    this host that no longer runs. A ``.NAME.old-PID-*`` store whose process is gone is put
    back as ``NAME`` when ``NAME`` is missing, else deleted. Anything else (live writers,
    other hosts, no owner file, not a store) is left alone.
    """
    path = Path(path)
    parent = path.parent
    touched: list[Path] = []
    if not parent.is_dir():
        return touched
    partial = re.compile(re.escape(f".{path.name}.partial-") + r"[0-9a-f]+$")
    backup = re.compile(re.escape(f".{path.name}.old-") + r"(\d+)-[0-9a-f]+$")
    try:
        entries = sorted(parent.iterdir())
    except OSError:
        return touched
    for entry in entries:
        if partial.match(entry.name) and _partial_owner_gone(entry):
            shutil.rmtree(entry, ignore_errors=True)
            touched.append(entry)
        match = backup.match(entry.name)
        if match and is_store_dir(entry) and not process_alive(int(match[1]), None):
            try:
                if os.path.lexists(path):
                    shutil.rmtree(entry)
                else:
                    os.rename(entry, path)
            except OSError:
                continue
            touched.append(entry)
    return touched


@dataclass(frozen=True)
class StoreHeader:
    """Contents of ``header.json``."""

    format_version: int
    num_samples: int
    image_size: tuple[int, int]  # (height, width) in pixels
    channel_order: str
    source: str
    created: str
    package_version: str
    creation_parameters: dict[str, Any]
    #: (h, w) px of the stored depth maps (``depth.f16``), or None: no depth maps.
    depth_size: tuple[int, int] | None = None
    #: ``frame_shape_sha256`` as read from ``header.json``; :meth:`frame_shape_problem`
    #: compares it with the header's sizes.
    recorded_shape_check: str = ""

    @property
    def shape_check(self) -> str:
        """A checksum of the frame and depth shapes: an ``image_size`` edited in
        ``header.json`` (e.g. swapped to [88, 64], the same byte count) no longer matches
        it, while the byte count alone cannot tell."""
        shape = [self.num_samples, FRAMES_PER_SAMPLE, *self.image_size, 3]
        if self.depth_size is not None:
            shape += [*self.depth_size]
        return hashlib.sha256(json.dumps(shape).encode()).hexdigest()[:16]

    def frame_shape_problem(self) -> str | None:
        """Why the header's sizes are not the ones the store was written with, or None."""
        if self.recorded_shape_check == self.shape_check:
            return None
        height, width = self.image_size
        return (
            f"{HEADER_FILE}: image_size {height}x{width} (or num_samples, depth_size) is not "
            f"what the store was written with (frame_shape_sha256 differs): the header was "
            f"edited; frames read with the wrong shape would be garbage"
        )

    def to_dict(self) -> dict[str, Any]:
        data = {
            "format_version": self.format_version,
            "num_samples": self.num_samples,
            "image_size": list(self.image_size),
            "frames_per_sample": FRAMES_PER_SAMPLE,
            "frames_dtype": "uint8",
            "frames_file": FRAMES_FILE,
            "frames_encoding": "u = floor(x * 255); x = (u + 0.5) / 255",
            "channel_order": self.channel_order,
            "source": self.source,
            "created": self.created,
            "package_version": self.package_version,
            "creation_parameters": self.creation_parameters,
        }
        if self.depth_size is not None:
            data["depth_size"] = list(self.depth_size)
            data |= {"depth_file": DEPTH_FILE, "depth_dtype": "float16", "depth_unit": "mm"}
        return data | {"frame_shape_sha256": self.shape_check}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> StoreHeader:
        if not isinstance(data, dict):
            raise StoreError(f"{HEADER_FILE} is malformed: not a JSON object")
        for key in ("format_version", "num_samples"):
            value = data.get(key)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise StoreError(f"{HEADER_FILE} is malformed: {key} {value!r} is not an integer")
        try:
            return cls(
                format_version=int(data["format_version"]),
                num_samples=int(data["num_samples"]),
                image_size=check_size(data["image_size"], "image_size"),
                channel_order=str(data["channel_order"]),
                source=str(data["source"]),
                created=str(data.get("created", "")),
                package_version=str(data.get("package_version", "")),
                creation_parameters=dict(data.get("creation_parameters", {})),
                depth_size=(
                    check_size(data["depth_size"], "depth_size")
                    if data.get("depth_size") is not None
                    else None
                ),
                recorded_shape_check=str(data["frame_shape_sha256"]),
            )
        except (KeyError, TypeError, ValueError, IndexError) as err:
            raise StoreError(f"{HEADER_FILE} is malformed: {err!r}") from err


def read_store_header(path: str | Path) -> StoreHeader:
    """A store's ``header.json`` alone: the report reads it where the frames are not copied.

    Raises:
        StoreError: no header, or a malformed one.
    """
    header_path = Path(path) / HEADER_FILE
    if not header_path.is_file():
        raise StoreError(f"{path}: not a GraspStore ({HEADER_FILE} missing)")
    try:
        return StoreHeader.from_dict(json.loads(header_path.read_text()))
    except json.JSONDecodeError as err:
        raise StoreError(f"{header_path}: invalid JSON ({err})") from err
    except RecursionError:
        raise StoreError(f"{header_path}: invalid JSON (nested too deeply)") from None


def read_samples_table(path: str | Path) -> pd.DataFrame:
    """A store's ``samples.parquet`` alone (not checked against the header).

    Raises:
        StoreError: missing, truncated or not parquet.
    """
    table = Path(path) / SAMPLES_FILE
    try:
        samples = pd.read_parquet(table)
    except Exception as err:  # missing, truncated or not parquet (pyarrow's errors vary)
        raise StoreError(f"{table}: cannot read the table ({err})") from err
    if "sample_id" in samples.columns and not any(c in samples.columns for c in _LATER_COLUMNS):
        # Written before the rig-corrected estimates: it has none.
        for column in _LATER_COLUMNS:
            samples[column] = np.nan
        samples = samples[[c for c in SAMPLE_COLUMNS if c in samples.columns]]
    return samples


def _map_array(path: Path, dtype: type[np.generic], shape: tuple[int, ...], what: str) -> Any:
    """``path`` mapped read-only as ``shape``; :class:`StoreError` unless its size fits."""
    expected = int(np.prod(shape)) * np.dtype(dtype).itemsize
    actual = path.stat().st_size if path.exists() else -1
    if actual != expected:
        raise StoreError(
            f"{path}: expected {expected} bytes for {what} of shape {shape}, found {actual}"
        )
    if expected == 0:  # np.memmap cannot map an empty file
        return np.zeros(shape, dtype=dtype)
    return np.memmap(path, dtype=dtype, mode="r", shape=shape)


class GraspStore:
    """Read access to a store directory; frames stay on disk until indexed."""

    def __init__(self, path: Path, header: StoreHeader, samples: pd.DataFrame) -> None:
        self.path = path
        self.header = header
        self.samples = samples
        self._frames_path = path / FRAMES_FILE
        self._depth_path = path / DEPTH_FILE
        self._sample_bytes = FRAMES_PER_SAMPLE * int(np.prod(header.image_size)) * 3
        self._fd: int | None = None
        self._fd_pid = -1
        self._map_files()

    def _map_files(self) -> None:
        """Map the frames and, when the header names them, the depth maps (sizes checked)."""
        samples = (self.header.num_samples, FRAMES_PER_SAMPLE)
        shape = (*samples, *self.header.image_size, 3)
        self.frames: np.ndarray = _map_array(self._frames_path, np.uint8, shape, "frames")
        self.depth: np.ndarray | None = None
        if self.header.depth_size is not None:
            shape = (*samples, *self.header.depth_size)
            self.depth = _map_array(self._depth_path, np.float16, shape, "depth maps (float16)")

    @classmethod
    def open(cls, path: str | Path, *, validate: bool = True) -> GraspStore:
        """Open an existing store; raises :class:`StoreError` naming what is wrong.

        ``validate`` (default) also checks the table with :func:`validate_samples`;
        ``validate=False`` opens a store with bad values anyway (to inspect).
        """
        path = Path(path)
        if not path.is_dir():
            raise StoreError(f"{path}: no such store directory")
        header = read_store_header(path)
        problem = header.frame_shape_problem()
        if problem:
            raise StoreError(f"{path}: {problem}")
        try:
            check_format_version(header.format_version, FORMAT_VERSION, f"{path}: store")
        except ValueError as err:
            raise StoreError(str(err)) from None
        samples = read_samples_table(path)
        if len(samples) != header.num_samples:
            raise StoreError(
                f"{path}: {SAMPLES_FILE} has {len(samples)} rows, header says {header.num_samples}"
            )
        missing = [c for c in SAMPLE_COLUMNS if c not in samples.columns]
        if missing:
            raise StoreError(f"{path / SAMPLES_FILE}: missing columns {missing}")
        if validate:
            problems = validate_samples(samples)
            if problems:
                raise StoreError(f"{path / SAMPLES_FILE}: " + "; ".join(problems))
        return cls(path, header, samples)

    def __len__(self) -> int:
        return self.header.num_samples

    def __repr__(self) -> str:
        height, width = self.header.image_size
        return (
            f"GraspStore({str(self.path)!r}, samples={len(self)}, "
            f"objects={self.samples['object'].nunique()}, size={height}x{width}, "
            f"source={self.header.source!r})"
        )

    @property
    def image_size(self) -> tuple[int, int]:
        """Frame size (height, width) in pixels."""
        return self.header.image_size

    @property
    def units(self) -> GraspUnits:
        """What the stored analytical estimates were made with, read from the rows
        (:data:`UNIT_COLUMNS`); an empty store is in ``DATASET_UNITS``.

        Raises:
            StoreError: rows in two units (naming a row of each): their estimates cannot
                be used together.
        """
        columns = self.samples[list(UNIT_COLUMNS)]
        groups = columns.groupby(list(UNIT_COLUMNS), dropna=False, sort=False).indices
        if not groups:
            return DATASET_UNITS
        found = [(row_units(*key), int(rows.min())) for key, rows in groups.items()]
        found.sort(key=lambda item: item[1])
        if len({units for units, _ in found}) > 1:
            (one, a), (other, b) = found[:2]
            name = self.samples["object"]
            raise StoreError(
                f"{self.path}: rows in two units: sample {a} ({name.iloc[a]}) has "
                f"{one.describe()}, sample {b} ({name.iloc[b]}) {other.describe()}; their "
                "estimates cannot be used together: import each sensor's grasps into a "
                "store of their own"
            )
        return found[0][0]

    @property
    def analytical_estimator(self) -> AnalyticalEstimator:
        """The estimator that made the stored analytical estimates, at their pixel density
        (:attr:`units`; StoreError: rows in two units)."""
        units = self.units
        return AnalyticalEstimator(units.estimator, units.sensor.px_per_mm)

    @property
    def sensor_units(self) -> SensorUnits:
        """Depth model and pixel density of the stored analytical estimates (:attr:`units`;
        StoreError: rows in two units)."""
        return self.units.sensor

    @property
    def has_depth(self) -> bool:
        """Whether the store holds depth maps (``depth.f16``)."""
        return self.depth is not None

    @property
    def depth_size(self) -> tuple[int, int] | None:
        """Size (h, w) px of the stored depth maps, or None when the store has none."""
        return self.header.depth_size

    def require_depth(self) -> None:
        """Raise :class:`StoreError` (saying how to get them) when the store has no depth maps."""
        if self.depth is None:
            raise StoreError(
                f"{self.path}: the store holds no depth maps; re-import it with "
                "`tactile-compliance import burgess SRC --out STORE --depth`"
            )

    def read_depth(self, indices: int | Sequence[int] | np.ndarray) -> np.ndarray:
        """Depth maps of the given sample ids in mm, float32 (n, 3, h, w); NaN = none.

        Raises:
            StoreError: the store holds no depth maps (imported with ``--no-depth`` or
                before depth was kept: re-import it).
        """
        self.require_depth()
        idx = np.atleast_1d(np.asarray(indices, dtype=np.int64))
        if idx.size and (idx.min() < 0 or idx.max() >= len(self)):
            raise IndexError(f"sample ids out of range (store has {len(self)})")
        return np.asarray(self.depth[idx], dtype=np.float32)

    def load_frames(self, indices: int | Sequence[int] | np.ndarray) -> np.ndarray:
        """Frames of the given sample ids as float32 in (0, 1), shape (n, 3, H, W, 3), RGB."""
        return frames_from_uint8(self.read_samples(indices))

    def read_samples(self, indices: int | Sequence[int] | np.ndarray) -> np.ndarray:
        """Frames of the given sample ids (any order, repeats allowed), uint8
        (n, 3, H, W, 3), read with ``os.pread`` like :meth:`read_sample`."""
        idx = np.atleast_1d(np.asarray(indices, dtype=np.int64))
        out = np.empty((len(idx), *self.frames.shape[1:]), dtype=np.uint8)
        for i, sample_id in enumerate(idx):
            out[i] = self.read_sample(int(sample_id))
        return out

    def read_block(self, start: int, stop: int) -> np.ndarray:
        """Frames of samples ``start..stop-1``, uint8 (n, 3, H, W, 3), in one ``os.pread``.

        Unlike slicing the memmap, this maps no file pages into the process: a pass over a
        6 GB store (a training epoch, the feature cache) would otherwise count all 6 GB in
        the process's resident memory (the OS page cache still speeds up repeated reads).
        """
        if not 0 <= start <= stop <= len(self):
            raise IndexError(f"samples {start}..{stop} out of range (store has {len(self)})")
        size, offset = (stop - start) * self._sample_bytes, start * self._sample_bytes
        chunks, done = [], 0
        while done < size:  # pread may return less than asked (e.g. above 2 GB on Linux)
            chunk = os.pread(self._descriptor(), size - done, offset + done)
            if not chunk:
                raise StoreError(f"{self._frames_path}: file ends before sample {stop - 1}")
            chunks.append(chunk)
            done += len(chunk)
        data = chunks[0] if len(chunks) == 1 else b"".join(chunks)
        return np.frombuffer(data, dtype=np.uint8).reshape(stop - start, *self.frames.shape[1:])

    def _descriptor(self) -> int:
        """This process's read-only descriptor of the frames file (one per process)."""
        if self._fd is None or self._fd_pid != os.getpid():
            self._fd = os.open(self._frames_path, os.O_RDONLY)
            self._fd_pid = os.getpid()
        return self._fd

    def read_sample(self, sample_id: int) -> np.ndarray:
        """One sample's frames, uint8 (3, H, W, 3), read like :meth:`read_block` (safe in
        DataLoader workers: each process opens its own descriptor)."""
        if not 0 <= sample_id < len(self):
            raise IndexError(f"sample {sample_id} out of range (store has {len(self)})")
        return self.read_block(sample_id, sample_id + 1)[0]

    def __getstate__(self) -> dict[str, Any]:
        # Pickling a memmap would copy the whole frame array; worker processes reopen it.
        state = self.__dict__.copy()
        state["_fd"] = None
        state["frames"] = None
        state["depth"] = None
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._map_files()

    def forces_n(self) -> np.ndarray:
        """Normal force at the three frames, (N, 3) in N."""
        return self.samples[list(FORCE_COLUMNS)].to_numpy(dtype=np.float64)

    def widths_m(self) -> np.ndarray:
        """Gripper width at the three frames, (N, 3) in m."""
        return self.samples[list(WIDTH_COLUMNS)].to_numpy(dtype=np.float64)

    def estimates_pa(self) -> np.ndarray:
        """Analytical estimates (elastic E, Hertz E*), (N, 2) in Pa."""
        return self.samples[list(ESTIMATE_COLUMNS)].to_numpy(dtype=np.float64)

    def moduli_pa(self) -> np.ndarray:
        """Ground-truth Young's modulus, (N,) in Pa."""
        return self.samples["modulus_pa"].to_numpy(dtype=np.float64)

    def summary(self) -> dict[str, Any]:
        """Counts by material and shape, modulus range, resolution (what `info` prints)."""
        s = self.samples
        moduli = s["modulus_pa"].to_numpy(dtype=np.float64)
        return {
            "path": str(self.path),
            "source": self.header.source,
            "num_samples": len(s),
            "num_objects": int(s["object"].nunique()),
            "num_grasps": int(s.groupby(["object", "grasp"]).ngroups) if len(s) else 0,
            "image_size": list(self.header.image_size),
            "channel_order": self.header.channel_order,
            "fingers": {str(k): int(v) for k, v in s["finger"].value_counts().items()},
            "materials": {str(k): int(v) for k, v in s["material"].value_counts().items()},
            "shapes": {str(k): int(v) for k, v in s["shape"].value_counts().items()},
            "modulus_pa_min": float(moduli.min()) if len(s) else None,
            "modulus_pa_max": float(moduli.max()) if len(s) else None,
            "has_force_width": bool(s[list(FORCE_COLUMNS)].notna().any().any()),
            "has_estimates": bool(s[list(ESTIMATE_COLUMNS)].notna().any().any()),
            # The rig stiffnesses [N/m] of the rig-corrected estimates (none: empty).
            "rig_stiffnesses_n_per_m": sorted(
                float(k)
                for k in s.loc[
                    s[list(RIG_ESTIMATE_COLUMNS)].notna().any(axis=1), "rig_stiffness_n_per_m"
                ]
                .dropna()
                .unique()
            ),
            "frames_bytes": int(np.prod(self.frames.shape)),
            # Samples with a depth file have a finite maximum depth in the table.
            "depth": (
                {
                    "size": list(self.header.depth_size),
                    "dtype": "float16",
                    "unit": "mm",
                    "samples_with_depth": int(s[list(DEPTH_COLUMNS)].notna().all(axis=1).sum()),
                    "bytes": int(np.prod(self.depth.shape)) * 2,
                }
                if self.depth is not None
                else None
            ),
            "created": self.header.created,
            "package_version": self.header.package_version,
            "creation_parameters": self.header.creation_parameters,
        }
