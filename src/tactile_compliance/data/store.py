"""GraspStore: the one on-disk format every data source is imported into.

A store is a directory::

    STORE/
      header.json       format version, frame shape, channel order, source, creation parameters
      samples.parquet   one row per sample (labels, F, W, estimates, provenance)
      frames.u8         raw uint8 array (N, 3 frames, H, W, 3 channels), RGB, memory-mapped

Frames are difference images (values centred near 0.5) quantised to uint8 as
``floor(x * 255)`` and decoded as ``(u + 0.5) / 255`` (see :func:`frames_to_uint8`); that
is the camera's own quantisation step, and it makes a
7,840-sample full-resolution store 6.2 GB on disk instead of 25 GB of float32, read
lazily through ``np.memmap`` so nothing is loaded into RAM until a sample is asked for.

Stores are written by :class:`GraspStoreWriter`, which streams frames into a temporary
sibling directory and renames it into place only when everything is written: an
interrupted import never leaves a directory that looks like a complete store.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from tactile_compliance import __version__

FORMAT_VERSION = 1
HEADER_FILE = "header.json"
SAMPLES_FILE = "samples.parquet"
FRAMES_FILE = "frames.u8"
FRAMES_PER_SAMPLE = 3

FINGERS = ("markerless", "markers")

# Column order of samples.parquet. Units: forces in N, widths in m, moduli and
# estimates in Pa, depths in mm. Missing values are NaN (e.g. the Shore-hardness
# videos have no force, width, estimates or depth).
SAMPLE_COLUMNS: tuple[str, ...] = (
    "sample_id",
    "object",
    "grasp",
    "augmentation",
    "finger",
    "material",
    "shape",
    "modulus_pa",
    "force_n_0",
    "force_n_1",
    "force_n_2",
    "width_m_0",
    "width_m_1",
    "width_m_2",
    "elastic_estimate_pa",
    "hertz_estimate_pa",
    "depth_max_mm_0",
    "depth_max_mm_1",
    "depth_max_mm_2",
    "source_path",
)
FORCE_COLUMNS = ("force_n_0", "force_n_1", "force_n_2")
WIDTH_COLUMNS = ("width_m_0", "width_m_1", "width_m_2")
ESTIMATE_COLUMNS = ("elastic_estimate_pa", "hertz_estimate_pa")
DEPTH_COLUMNS = ("depth_max_mm_0", "depth_max_mm_1", "depth_max_mm_2")
_STRING_COLUMNS = ("object", "finger", "material", "shape", "source_path")
_INT_COLUMNS = ("sample_id", "grasp", "augmentation")


class StoreError(Exception):
    """A store is missing, incomplete or inconsistent."""


#: Decoding is ``(u + FRAME_DECODE_OFFSET) / 255``; see :func:`frames_to_uint8`.
FRAME_DECODE_OFFSET = 0.5


def frames_to_uint8(frames: np.ndarray) -> np.ndarray:
    """Quantise float difference images in [0, 1] (any shape) to uint8 ``floor(x * 255)``.

    The recording pipeline's values are ``k / 255 + 0.5`` with an integer k (uint8 frame
    minus uint8 blurred reference), so ``x * 255`` always ends in .5: rounding would merge
    neighbouring grey levels, while ``floor`` keeps every level and the decoder
    (:func:`frames_from_uint8`, ``(u + 0.5) / 255``) recovers the value exactly. Arbitrary
    floats are reproduced within half a grey level, without bias. uint8 input (raw camera
    frames) is stored unchanged.
    """
    frames = np.asarray(frames)
    if frames.dtype == np.uint8:
        return frames
    # float64 keeps k/255 + 0.5 exact enough that floor never drops a level.
    return np.clip(np.floor(frames.astype(np.float64) * 255.0), 0, 255).astype(np.uint8)


def frames_from_uint8(frames: np.ndarray) -> np.ndarray:
    """Decode stored uint8 frames to float32 ``(u + 0.5) / 255`` (inverse of the encoding)."""
    return (np.asarray(frames, dtype=np.float32) + np.float32(FRAME_DECODE_OFFSET)) / np.float32(
        255.0
    )


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

    def to_dict(self) -> dict[str, Any]:
        return {
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

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> StoreHeader:
        try:
            return cls(
                format_version=int(data["format_version"]),
                num_samples=int(data["num_samples"]),
                image_size=(int(data["image_size"][0]), int(data["image_size"][1])),
                channel_order=str(data["channel_order"]),
                source=str(data["source"]),
                created=str(data.get("created", "")),
                package_version=str(data.get("package_version", "")),
                creation_parameters=dict(data.get("creation_parameters", {})),
            )
        except (KeyError, TypeError, ValueError, IndexError) as err:
            raise StoreError(f"{HEADER_FILE} is malformed: {err!r}") from err


class GraspStore:
    """Read access to a store directory; frames stay on disk until indexed."""

    def __init__(self, path: Path, header: StoreHeader, samples: pd.DataFrame) -> None:
        self.path = path
        self.header = header
        self.samples = samples
        height, width = header.image_size
        shape = (header.num_samples, FRAMES_PER_SAMPLE, height, width, 3)
        frames_path = path / FRAMES_FILE
        expected_bytes = int(np.prod(shape))
        actual_bytes = frames_path.stat().st_size if frames_path.exists() else -1
        if actual_bytes != expected_bytes:
            raise StoreError(
                f"{frames_path}: expected {expected_bytes} bytes for frames of shape {shape}, "
                f"found {actual_bytes}"
            )
        if expected_bytes == 0:
            self.frames = np.zeros(shape, dtype=np.uint8)
        else:
            self.frames = np.memmap(frames_path, dtype=np.uint8, mode="r", shape=shape)
        self._frames_path = frames_path
        self._sample_bytes = int(np.prod(shape[1:]))
        self._fd: int | None = None
        self._fd_pid = -1

    @classmethod
    def open(cls, path: str | Path) -> GraspStore:
        """Open an existing store; raises :class:`StoreError` naming what is wrong."""
        path = Path(path)
        if not path.is_dir():
            raise StoreError(f"{path}: no such store directory")
        header_path = path / HEADER_FILE
        if not header_path.is_file():
            raise StoreError(f"{path}: not a GraspStore ({HEADER_FILE} missing)")
        try:
            header = StoreHeader.from_dict(json.loads(header_path.read_text()))
        except json.JSONDecodeError as err:
            raise StoreError(f"{header_path}: invalid JSON ({err})") from err
        if header.format_version > FORMAT_VERSION:
            raise StoreError(
                f"{path}: store format {header.format_version} is newer than this package "
                f"supports ({FORMAT_VERSION}); upgrade tactile-compliance"
            )
        samples = pd.read_parquet(path / SAMPLES_FILE)
        if len(samples) != header.num_samples:
            raise StoreError(
                f"{path}: {SAMPLES_FILE} has {len(samples)} rows, header says {header.num_samples}"
            )
        missing = [c for c in SAMPLE_COLUMNS if c not in samples.columns]
        if missing:
            raise StoreError(f"{path / SAMPLES_FILE}: missing columns {missing}")
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

        Like :meth:`read_sample`, this maps no file pages into the process: slicing the
        memmap instead made a pass over a 6 GB store (the feature cache) count all 6 GB
        in the process's resident memory.
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
        """One sample's frames, uint8 (3, H, W, 3), read with ``os.pread``.

        Unlike indexing the memmap, this keeps no file pages mapped into the process, so
        a training epoch over a 6 GB store does not grow the process's resident memory
        (the OS page cache still speeds up repeated reads). Safe in DataLoader workers:
        each process opens its own descriptor.
        """
        if not 0 <= sample_id < len(self):
            raise IndexError(f"sample {sample_id} out of range (store has {len(self)})")
        return self.read_block(sample_id, sample_id + 1)[0]

    def __getstate__(self) -> dict[str, Any]:
        # Pickling a memmap would copy the whole frame array; worker processes reopen it.
        state = self.__dict__.copy()
        state["_fd"] = None
        state["frames"] = None
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        shape = (self.header.num_samples, FRAMES_PER_SAMPLE, *self.header.image_size, 3)
        if self._sample_bytes * self.header.num_samples == 0:
            self.frames = np.zeros(shape, dtype=np.uint8)
        else:
            self.frames = np.memmap(self._frames_path, dtype=np.uint8, mode="r", shape=shape)

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
            "frames_bytes": int(np.prod(self.frames.shape)),
            "created": self.header.created,
            "package_version": self.header.package_version,
            "creation_parameters": self.header.creation_parameters,
        }


def _normalise_row(row: dict[str, Any], sample_id: int) -> dict[str, Any]:
    unknown = set(row) - set(SAMPLE_COLUMNS)
    if unknown:
        raise ValueError(f"unknown sample fields {sorted(unknown)}")
    out: dict[str, Any] = {}
    for column in SAMPLE_COLUMNS:
        if column == "sample_id":
            out[column] = sample_id
        elif column in _STRING_COLUMNS:
            out[column] = str(row.get(column, ""))
        elif column in _INT_COLUMNS:
            out[column] = int(row.get(column, 0))
        else:
            value = row.get(column, np.nan)
            out[column] = float(np.nan if value is None else value)
    return out


class GraspStoreWriter:
    """Stream samples into a new store; the store appears atomically on :meth:`commit`.

    Use as a context manager: an exception inside the block discards the temporary
    directory and leaves any previous store untouched::

        with GraspStoreWriter(out, image_size=(250, 350), source="burgess") as writer:
            writer.append(frames, {"object": "foam_cube", "modulus_pa": 2e4, ...})
    """

    def __init__(
        self,
        path: str | Path,
        image_size: tuple[int, int],
        source: str,
        creation_parameters: dict[str, Any] | None = None,
        overwrite: bool = False,
    ) -> None:
        self.path = Path(path)
        if self.path.exists() and not overwrite:
            raise FileExistsError(f"{self.path} already exists; pass --overwrite to replace it")
        self.image_size = (int(image_size[0]), int(image_size[1]))
        self.source = source
        self.creation_parameters = dict(creation_parameters or {})
        self.overwrite = overwrite
        self.path.parent.mkdir(parents=True, exist_ok=True)
        # The temp dir is a sibling so the final rename stays on one filesystem (atomic).
        self._tmp = Path(
            tempfile.mkdtemp(prefix=f".{self.path.name}.partial-", dir=self.path.parent)
        )
        self._frames_file = open(self._tmp / FRAMES_FILE, "wb")  # noqa: SIM115 (closed in commit/abort)
        self._rows: list[dict[str, Any]] = []
        self._closed = False

    def __len__(self) -> int:
        return len(self._rows)

    def append(self, frames: np.ndarray, row: dict[str, Any]) -> int:
        """Add one sample: frames (3, H, W, 3) RGB, float in [0, 1] or uint8. Returns its id."""
        if self._closed:
            raise RuntimeError("writer is closed")
        frames = np.asarray(frames)
        expected = (FRAMES_PER_SAMPLE, *self.image_size, 3)
        if frames.shape != expected:
            raise ValueError(f"frames have shape {frames.shape}, expected {expected}")
        if frames.dtype != np.uint8 and not np.all(np.isfinite(frames)):
            raise ValueError("frames contain NaN or inf")
        sample_id = len(self._rows)
        normalised = _normalise_row(row, sample_id)
        self._frames_file.write(np.ascontiguousarray(frames_to_uint8(frames)).tobytes())
        self._rows.append(normalised)
        return sample_id

    def commit(self) -> GraspStore:
        """Write the table and header, then move the store into place."""
        if self._closed:
            raise RuntimeError("writer is closed")
        self._frames_file.close()
        samples = pd.DataFrame(self._rows, columns=list(SAMPLE_COLUMNS))
        for column in _INT_COLUMNS:
            samples[column] = samples[column].astype(np.int64)
        for column in _STRING_COLUMNS:
            samples[column] = samples[column].astype(str)
        samples.to_parquet(self._tmp / SAMPLES_FILE, index=False)
        header = StoreHeader(
            format_version=FORMAT_VERSION,
            num_samples=len(samples),
            image_size=self.image_size,
            channel_order="RGB",
            source=self.source,
            created=datetime.now(timezone.utc).isoformat(timespec="seconds"),
            package_version=__version__,
            creation_parameters=self.creation_parameters,
        )
        # header.json is written last: it is what marks a directory as a store.
        (self._tmp / HEADER_FILE).write_text(json.dumps(header.to_dict(), indent=2) + "\n")
        if self.path.exists():
            if not self.overwrite:
                self.abort()
                raise FileExistsError(f"{self.path} appeared while writing; not replacing it")
            backup = self.path.with_name(f".{self.path.name}.old-{os.getpid()}")
            os.replace(self.path, backup)
            os.replace(self._tmp, self.path)
            shutil.rmtree(backup, ignore_errors=True)
        else:
            os.replace(self._tmp, self.path)
        self._closed = True
        return GraspStore.open(self.path)

    def abort(self) -> None:
        """Discard everything written so far."""
        if not self._frames_file.closed:
            self._frames_file.close()
        shutil.rmtree(self._tmp, ignore_errors=True)
        self._closed = True

    def __enter__(self) -> GraspStoreWriter:
        return self

    def __exit__(self, exc_type: object, exc: object, tb: object) -> None:
        if self._closed:
            return
        if exc_type is None:
            self.commit()
        else:
            self.abort()
