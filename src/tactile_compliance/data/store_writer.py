"""``GraspStoreWriter``: the GraspStore's one writer; a new store appears atomically on
``commit``. See docs/data.md, "The GraspStore format (version 1)".
"""

from __future__ import annotations

import contextlib
import json
import os
import secrets
import shutil
import socket
import time
from collections.abc import Iterator
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from tactile_compliance import __version__
from tactile_compliance.data.plausibility import (
    FRAME,
    as_real_number,
)
from tactile_compliance.data.store import (
    _INT_COLUMNS,
    _STRING_COLUMNS,
    COLUMN_RULES,
    DEPTH_FILE,
    FORMAT_VERSION,
    FRAMES_FILE,
    FRAMES_PER_SAMPLE,
    HEADER_FILE,
    MAX_ABS_DEPTH_MM,
    PARTIAL_MARKER,
    SAMPLE_COLUMNS,
    SAMPLES_FILE,
    STORE_KIND,
    STORE_MARKER,
    UNIT_COLUMNS,
    GraspStore,
    NotAStoreError,
    StoreError,
    StoreHeader,
    StoreWriteError,
    encode_frames,
    is_store_dir,
    recover_interrupted_writes,
    row_units,
    store_kind_hint,
    validate_samples,
)
from tactile_compliance.outputs import (
    commit_path,
    process_start,
)
from tactile_compliance.physics.estimators import (
    DATASET_UNITS,
)

__all__ = ["GraspStoreWriter"]


def _write_all(file: Any, data: bytes) -> None:
    """Append ``data`` to an open binary file (one place, so tests can fill the disk)."""
    file.write(data)


def _write_json(path: Path, content: Any) -> None:
    """Write ``content`` as JSON text (mode from the umask, like every store file)."""
    with open(path, "w", encoding="utf-8") as file:
        file.write(json.dumps(content, indent=2) + "\n")


#: A row that names no units is in the public dataset's (``DATASET_UNITS``): the writer's
#: callers that hold estimates (``import burgess``) always name them.
_DEFAULTS = {
    "analytical_estimator": DATASET_UNITS.estimator,
    "depth_model": DATASET_UNITS.sensor.depth_model,
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
            text = str(row.get(column, _DEFAULTS.get(column, "")))
            try:
                text.encode("utf-8")
            except UnicodeEncodeError:
                shown = text.encode("utf-8", "surrogateescape").decode("utf-8", "replace")
                raise ValueError(f"{column} is not valid UTF-8 text: {shown!r}") from None
            out[column] = text
        elif column in _INT_COLUMNS:
            out[column] = int(row.get(column, 0))
        else:
            value = row.get(column, np.nan)
            try:
                out[column] = as_real_number(value)
            except ValueError as err:
                raise ValueError(f"{column}: {err}") from None
    row_units(*(out[column] for column in UNIT_COLUMNS))  # ValueError: invalid units
    for column, rule in COLUMN_RULES.items():
        value = out[column]
        if column == "modulus_pa" and not rule.contains(value):
            raise ValueError(
                f"modulus_pa must be {rule.requirement()}, got {value!r} ({rule.reason})"
            )
        problem = rule.violation(value)
        if problem:
            raise ValueError(f"{column}: {problem}")
    return out


def _missing_ancestors(directory: Path) -> list[Path]:
    """``directory`` and its ancestors that do not exist yet, outermost first."""
    missing = []
    while not os.path.lexists(directory) and directory.parent != directory:
        missing.append(directory)
        directory = directory.parent
    return missing[::-1]


class GraspStoreWriter:
    """Stream samples into a new store; the store appears atomically on :meth:`commit`.

    Use as a context manager: an exception inside the block discards the temporary
    directory and leaves any previous store untouched::

        with GraspStoreWriter(out, image_size=(250, 350), source="burgess") as writer:
            writer.append(frames, {"object": "foam_cube", "modulus_pa": 2e4, ...})

    Guarantees (docs/data.md, "Writing, replacing, interruptions"):

    - Samples go to a hidden sibling ``.NAME.partial-XXXXXXXX``; :meth:`commit` writes the
      table, the marker and ``header.json`` (last) there and only then renames it to
      ``NAME``, so no reader sees a half-written store.
    - An existing ``NAME`` is a ``FileExistsError`` without ``overwrite``; with it, only a
      store (:func:`is_store_dir`) is replaced, anything else is :class:`NotAStoreError`
      and left untouched.
    - An ``OSError`` while writing (full disk, ...) is a :class:`StoreWriteError` after the
      temporary directory and the parent directories this writer created are removed.
    - A killed writer's leftovers are tidied by the next writer to the same path
      (:func:`recover_interrupted_writes`).
    - Directories and files get the default modes: the umask decides.
    """

    def __init__(
        self,
        path: str | Path,
        image_size: tuple[int, int],
        source: str,
        creation_parameters: dict[str, Any] | None = None,
        overwrite: bool = False,
        depth_size: tuple[int, int] | None = None,
    ) -> None:
        self.path = Path(path)
        self.image_size = (int(image_size[0]), int(image_size[1]))
        #: (h, w) px of the depth maps :meth:`append` takes, or None: the store keeps none.
        self.depth_size = (
            (int(depth_size[0]), int(depth_size[1])) if depth_size is not None else None
        )
        self.source = source
        self.creation_parameters = dict(creation_parameters or {})
        self.overwrite = overwrite
        self._rows: list[dict[str, Any]] = []
        self._closed = False
        #: Frame values written so far, and how many of them the uint8 encoding clipped
        #: (:func:`encode_frames`); the importers put both into their report.
        self.frame_values = 0
        self.clipped_frame_values = 0
        #: Samples with at least one clipped frame value.
        self.samples_with_clipped_frames = 0
        recover_interrupted_writes(self.path)
        self._check_target()
        self._created = _missing_ancestors(self.path.parent)
        self._tmp = self.path.with_name(f".{self.path.name}.partial-{secrets.token_hex(4)}")
        with self._discarded_on_os_error():
            for directory in list(self._created):
                try:
                    os.mkdir(directory)
                except FileExistsError:  # made meanwhile by someone else: not ours to remove
                    self._created.remove(directory)
            os.mkdir(self._tmp)  # mode 0o777 minus the umask, unlike tempfile.mkdtemp
            _write_json(
                self._tmp / PARTIAL_MARKER,
                {
                    "kind": STORE_KIND,
                    "pid": os.getpid(),
                    "host": socket.gethostname(),
                    "start": process_start(os.getpid()),
                    "created": time.time(),
                },
            )
            self._frames_file = open(self._tmp / FRAMES_FILE, "wb")  # noqa: SIM115 (closed in commit/abort)
            self._depth_file = (
                open(self._tmp / DEPTH_FILE, "wb")  # noqa: SIM115 (closed in commit/abort)
                if self.depth_size is not None
                else None
            )

    def _check_target(self) -> None:
        if not os.path.lexists(self.path):
            return
        if not self.overwrite:
            raise FileExistsError(f"{self.path} already exists; pass --overwrite to replace it")
        if not is_store_dir(self.path):
            raise NotAStoreError(
                f"{self.path} is not a GraspStore ({store_kind_hint(self.path)}); "
                "refusing to replace it"
            )

    @contextlib.contextmanager
    def _discarded_on_os_error(self) -> Iterator[None]:
        """An ``OSError`` (full disk, ...) discards everything: :class:`StoreWriteError`."""
        try:
            yield
        except OSError as err:
            self.abort()
            reason = f"[Errno {err.errno}] {err.strerror}" if err.strerror else str(err)
            message = f"{self.path}: cannot write the store: {reason}"
            raise StoreWriteError(message, reason, err.errno) from err

    def abort(self) -> None:
        """Discard everything written so far: the temporary directory and the parent
        directories this writer made."""
        for handle in (getattr(self, "_frames_file", None), getattr(self, "_depth_file", None)):
            if handle is not None and not handle.closed:
                # The data is discarded anyway (e.g. a full disk on the last flush).
                with contextlib.suppress(OSError):
                    handle.close()
        shutil.rmtree(self._tmp, ignore_errors=True)
        for directory in reversed(self._created):
            try:
                directory.rmdir()  # only while empty
            except OSError:
                break
        self._closed = True

    def __len__(self) -> int:
        return len(self._rows)

    def append(
        self, frames: np.ndarray, row: dict[str, Any], depth: np.ndarray | None = None
    ) -> int:
        """Add one sample: frames (3, H, W, 3) RGB, float in [0, 1] or uint8. Returns its id.

        ``depth``: the sample's depth maps in mm, (3, h, w) at the writer's ``depth_size``
        (the caller resizes), stored as float16; None stores NaN (no depth file). Ignored
        by a writer without ``depth_size``. NaN is allowed (missing), inf and
        |depth| > :data:`MAX_ABS_DEPTH_MM` are not.

        Raises ``ValueError`` for a bad sample (shape, dtype, NaN frames, frames or values
        outside their plausibility rule, an unknown field, text that is not UTF-8): nothing
        is written for it.
        """
        if self._closed:
            raise RuntimeError("writer is closed")
        frames = np.asarray(frames)
        expected = (FRAMES_PER_SAMPLE, *self.image_size, 3)
        if frames.shape != expected:
            raise ValueError(f"frames have shape {frames.shape}, expected {expected}")
        if frames.dtype != np.uint8:
            if frames.dtype.kind != "f":
                raise ValueError(
                    f"frames must be uint8 (0..255) or float in [0, 1], got dtype {frames.dtype}"
                )
            if not np.all(np.isfinite(frames)):
                raise ValueError("frames contain NaN or inf")
            problem = FRAME.violation(frames)
            if problem:
                raise ValueError(f"frames: {problem}")
        sample_id = len(self._rows)
        normalised = _normalise_row(row, sample_id)
        depth_bytes = self._depth_bytes(depth)
        encoded, clipped = encode_frames(frames)
        with self._discarded_on_os_error():
            _write_all(self._frames_file, np.ascontiguousarray(encoded).tobytes())
            if self._depth_file is not None:
                _write_all(self._depth_file, depth_bytes)
        self._rows.append(normalised)
        self.frame_values += int(encoded.size)
        self.clipped_frame_values += clipped
        self.samples_with_clipped_frames += clipped > 0
        return sample_id

    def _depth_bytes(self, depth: np.ndarray | None) -> bytes:
        """One sample's depth maps as float16 bytes (NaN when None); ValueError if bad."""
        if self.depth_size is None:
            return b""
        shape = (FRAMES_PER_SAMPLE, *self.depth_size)
        if depth is None:
            return np.full(shape, np.nan, dtype=np.float16).tobytes()
        depth = np.asarray(depth)
        if depth.shape != shape:
            raise ValueError(f"depth maps have shape {depth.shape}, expected {shape}")
        if depth.dtype.kind not in "iuf":
            raise ValueError(f"depth maps must be numbers (mm), got dtype {depth.dtype}")
        values = depth.astype(np.float64)
        finite = values[~np.isnan(values)]
        if np.isinf(finite).any() or (finite.size and np.abs(finite).max() > MAX_ABS_DEPTH_MM):
            raise ValueError(
                f"depth maps must be finite and within +-{MAX_ABS_DEPTH_MM:g} mm "
                f"(max |depth| {np.abs(finite).max():.4g} mm)"
            )
        return values.astype(np.float16).tobytes()

    def commit(self) -> GraspStore:
        """Write the table and header, then move the store into place."""
        if self._closed:
            raise RuntimeError("writer is closed")
        samples = pd.DataFrame(self._rows, columns=list(SAMPLE_COLUMNS)).astype(
            dict.fromkeys(_INT_COLUMNS, np.int64) | dict.fromkeys(_STRING_COLUMNS, str)
        )
        problems = validate_samples(samples)
        if problems:
            self.abort()
            raise StoreError(f"{self.path}: not written: " + "; ".join(problems))
        header = StoreHeader(
            format_version=FORMAT_VERSION,
            num_samples=len(samples),
            image_size=self.image_size,
            channel_order="RGB",
            source=self.source,
            created=datetime.now(timezone.utc).isoformat(timespec="seconds"),
            package_version=__version__,
            creation_parameters=self.creation_parameters,
            depth_size=self.depth_size,
        )
        with self._discarded_on_os_error():
            self._frames_file.close()  # a full disk may only show on this last flush
            if self._depth_file is not None:
                self._depth_file.close()
            samples.to_parquet(self._tmp / SAMPLES_FILE, index=False)
            _write_json(
                self._tmp / STORE_MARKER, {"kind": STORE_KIND, "format_version": FORMAT_VERSION}
            )
            # header.json is written last: with it the directory is a complete store.
            _write_json(self._tmp / HEADER_FILE, header.to_dict())
        try:
            self._check_target()
        except (FileExistsError, NotAStoreError):
            self.abort()
            raise
        with self._discarded_on_os_error():
            commit_path(self._tmp, self.path, replace=True)
        self._closed = True
        # A leftover marker would be harmless: only .NAME.partial-* directories are tidied.
        with contextlib.suppress(OSError):
            (self.path / PARTIAL_MARKER).unlink()
        return GraspStore.open(self.path)

    def __enter__(self) -> GraspStoreWriter:
        return self

    def __exit__(self, exc_type: object, exc: object, tb: object) -> None:
        if self._closed:
            return
        if exc_type is None:
            self.commit()
        else:
            self.abort()
