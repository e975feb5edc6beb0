"""What an importer skipped and why, the import errors (one :class:`DataImportError`
subclass per cause; nothing is left behind), and the path checks, shared by every importer.

See docs/data.md, "Bad input: what is skipped and reported, what stops an import".
"""

from __future__ import annotations

import os
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from tactile_compliance.data.store import (
    NotAStoreError,
    StoreWriteError,
    is_store_dir,
    recover_interrupted_writes,
    store_kind_hint,
)
from tactile_compliance.data.store_writer import GraspStoreWriter
from tactile_compliance.outputs import OutputExistsError


class DataImportError(Exception):
    """An import cannot proceed; nothing was written. ``report``: the problems so far."""

    def __init__(self, *args: object, report: ImportReport | None = None) -> None:
        super().__init__(*args)
        self.report = report


class ImportPathError(DataImportError):
    """The source or the store path of an import is unusable (bad usage)."""


class StoreExistsError(ImportPathError, OutputExistsError):
    """``--out`` is an existing store and ``overwrite`` was not given."""


class NothingImportedError(DataImportError):
    """The source holds no importable sample: every one was skipped (see ``report``)."""


class StrictModeError(DataImportError):
    """Strict mode: the first problem stops the import."""


class ImportUnitsError(DataImportError):
    """The source's grasps are in two units (estimator, depth model, pixel density), or a
    grasp's units file is damaged: their estimates cannot share a store."""


class ImportWriteError(DataImportError):
    """Writing the store failed (full disk, permissions, I/O error); nothing was left."""


def printable_path(path: str | Path) -> str:
    """``path`` as text that can always be printed and saved as UTF-8: bytes that are not
    UTF-8 (file names are bytes on Linux) appear as ``\\xNN``."""
    text = str(path)
    try:
        raw = text.encode("utf-8", "surrogateescape")
    except UnicodeEncodeError:  # a surrogate that no file name decoding produces
        return text.encode("utf-8", "backslashreplace").decode("utf-8")
    return raw.decode("utf-8", "backslashreplace")


def utf8_problem(text: str) -> str | None:
    """None when ``text`` can be stored (valid UTF-8), else why not."""
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return f"not valid UTF-8: {printable_path(text)!r}"
    return None


def _contains(outer: Path, inner: Path) -> bool:
    return inner == outer or inner.is_relative_to(outer)


def import_paths(src_dir: str | Path, out_dir: str | Path, overwrite: bool) -> tuple[Path, Path]:
    """The source and store paths of an import, checked before any work starts.

    Also tidies what interrupted imports to the same ``out_dir`` left behind
    (:func:`~tactile_compliance.data.store.recover_interrupted_writes`).

    Raises:
        ImportPathError: the source is missing, the two paths nest, or ``out_dir`` exists
            and is not a GraspStore (``overwrite`` never deletes those).
        StoreExistsError: ``out_dir`` is a store and ``overwrite`` is false.
    """
    src, out = Path(src_dir), Path(out_dir)
    if not src.is_dir():
        raise ImportPathError(f"{src}: source directory not found")
    real_src, real_out = src.resolve(), out.resolve()
    if _contains(real_src, real_out):
        raise ImportPathError(
            f"--out {out} is inside the source directory {src}; choose a path outside it"
        )
    if _contains(real_out, real_src):
        raise ImportPathError(
            f"the source directory {src} is inside --out {out}; replacing the store would "
            "delete the data being imported"
        )
    recover_interrupted_writes(out)
    if os.path.lexists(out):
        if not overwrite:
            raise StoreExistsError(f"{out} already exists; pass --overwrite to replace it")
        if not is_store_dir(out):
            raise ImportPathError(
                f"{out} exists and is not a GraspStore ({store_kind_hint(out)}); --overwrite "
                "only replaces a store. Choose another --out or remove it yourself"
            )
    return src, out


class ImportTarget:
    """The store an import writes: created with its first good sample (when the frame
    size is known), committed at the end, removed again if anything fails."""

    def __init__(self, report: ImportReport, make_writer: Callable[[], GraspStoreWriter]):
        self.report = report
        self.make_writer = make_writer
        self.writer: GraspStoreWriter | None = None

    def append(
        self,
        frames: np.ndarray,
        row: dict[str, Any],
        source: Path,
        depth: np.ndarray | None = None,
    ) -> bool:
        """Add one sample (``depth``: its depth maps in mm, for a store that keeps them);
        a value the store cannot hold is reported against ``source``."""
        if self.writer is None:
            self.writer = self.make_writer()
        try:
            self.writer.append(frames, row, depth)
        except ValueError as err:
            self.report.problem(source, f"invalid sample: {err}")
            return False
        self.report.samples_imported += 1
        # The writer is the one place frames are encoded, so its counts are the truth.
        self.report.frame_values = self.writer.frame_values
        self.report.clipped_frame_values = self.writer.clipped_frame_values
        self.report.samples_with_clipped_frames = self.writer.samples_with_clipped_frames
        return True

    def commit(self, nothing: str) -> None:
        """Commit the store, or fail the import when every sample was skipped.

        Raises:
            NothingImportedError: no sample was imported (``nothing`` says what was skipped).
        """
        if self.writer is None or self.report.samples_imported == 0:
            raise NothingImportedError(f"{nothing}\n{self.report.format()}", report=self.report)
        self.writer.commit()


@contextmanager
def store_writing(
    out: Path, report: ImportReport, make_writer: Callable[[], GraspStoreWriter]
) -> Iterator[ImportTarget]:
    """The import's :class:`ImportTarget`; on any error its partial store is removed and
    the store writer's errors become import errors naming ``out``."""
    target = ImportTarget(report, make_writer)
    try:
        yield target
    except BaseException as exc:
        if target.writer is not None:
            target.writer.abort()
        if isinstance(exc, StoreWriteError):
            raise ImportWriteError(
                f"cannot write the store {out}: {exc.reason}; nothing was written", report=report
            ) from exc
        if isinstance(exc, NotAStoreError):
            raise ImportPathError(str(exc), report=report) from exc
        if isinstance(exc, FileExistsError) and not isinstance(exc, DataImportError):
            raise StoreExistsError(str(exc), report=report) from exc  # --out appeared meanwhile
        raise


@dataclass
class ImportReport:
    """Counts and per-file problems of one import run; the clipped frame values are
    explained in docs/data.md, "The encoding clips large differences"."""

    source: str
    source_dir: str
    store_dir: str = ""
    samples_imported: int = 0
    objects_imported: int = 0
    objects_seen: int = 0
    seconds: float = 0.0
    problems: list[tuple[str, str]] = field(default_factory=list)  # (path, reason)
    strict: bool = False
    frame_values: int = 0
    clipped_frame_values: int = 0
    samples_with_clipped_frames: int = 0
    #: What the imported estimates are in (``GraspUnits.describe``); "" when not known.
    units: str = ""
    #: Grasps without a units file (``raw_layout.UNITS_FILE``: the public dataset's), taken
    #: to be in the dataset's units by its heuristic.
    grasps_without_units: int = 0
    #: Set when a finger was left out because no sample has its files (``burgess``).
    fingers_note: str = ""

    def require_sources(self, sources: Sequence[Path], src: Path, expected: str) -> None:
        """Fail the import when the source directory holds nothing to import.

        Raises:
            NothingImportedError: ``sources`` is empty (``expected``: what was looked for).
        """
        if not sources:
            raise NothingImportedError(f"{src}: no {expected}", report=self)

    def problem(self, path: str | Path, reason: str) -> None:
        """Record a skipped file/object; in strict mode the first problem is fatal."""
        shown, reason = printable_path(path), printable_path(reason)
        self.problems.append((shown, reason))
        if self.strict:
            raise StrictModeError(
                f"{shown}: {reason} (strict mode: stopping at the first problem)", report=self
            )

    @property
    def samples_per_second(self) -> float:
        return self.samples_imported / self.seconds if self.seconds > 0 else float("nan")

    @property
    def clipped_frame_share(self) -> float:
        """Share of the written frame values that were clipped (0 when none were written)."""
        return self.clipped_frame_values / self.frame_values if self.frame_values else 0.0

    def reasons(self) -> Counter[str]:
        """How many problems of each kind (the reason's text up to the first colon)."""
        return Counter(reason.split(":")[0] for _, reason in self.problems)

    def to_dict(self) -> dict[str, Any]:
        return {
            "source": self.source,
            "source_dir": self.source_dir,
            "store_dir": self.store_dir,
            "objects_seen": self.objects_seen,
            "objects_imported": self.objects_imported,
            "samples_imported": self.samples_imported,
            "frame_values": self.frame_values,
            "clipped_frame_values": self.clipped_frame_values,
            "clipped_frame_share": self.clipped_frame_share,
            "samples_with_clipped_frames": self.samples_with_clipped_frames,
            "units": self.units,
            "grasps_without_units": self.grasps_without_units,
            "fingers_note": self.fingers_note,
            "seconds": round(self.seconds, 3),
            "problems": [{"path": p, "reason": r} for p, r in self.problems],
            "problem_counts": dict(self.reasons()),
        }

    def units_line(self) -> str:
        """What the estimates are in, and whether that was read or assumed."""
        if not self.grasps_without_units:
            return f"Units: {self.units} (each grasp's units.json)."
        return (
            f"Units: {self.grasps_without_units} grasp(s) name no units (no units.json, as in "
            f"the public dataset): their estimates are taken, by the dataset's heuristic, to "
            f"be from {self.units}."
        )

    def format(self, max_listed: int = 20) -> str:
        """Human-readable summary: totals, counts per reason, the first problems."""
        lines = [
            f"Imported {self.samples_imported} samples from {self.objects_imported}/"
            f"{self.objects_seen} objects ({self.source}) into {self.store_dir} "
            f"in {self.seconds:.1f} s ({self.samples_per_second:.1f} samples/s).",
        ]
        if self.frame_values:
            lines.append(
                f"Clipped frame values: {self.clipped_frame_values:,} of {self.frame_values:,} "
                f"({100 * self.clipped_frame_share:.4f} %) in {self.samples_with_clipped_frames} "
                "samples (differences beyond -127/+128 grey levels, stored as -127/+128)."
            )
        if self.units:
            lines.append(self.units_line())
        if self.fingers_note:
            lines.append(self.fingers_note)
        if self.problems:
            lines.append(f"Skipped {len(self.problems)} item(s):")
            lines += [f"  {count:6d}  {reason}" for reason, count in self.reasons().most_common()]
            lines.append("First problems:")
            lines += [f"  {path}: {reason}" for path, reason in self.problems[:max_listed]]
            if len(self.problems) > max_listed:
                lines.append(f"  ... and {len(self.problems) - max_listed} more")
        else:
            lines.append("No problems.")
        return "\n".join(lines)
