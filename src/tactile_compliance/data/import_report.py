"""What an importer skipped and why, and the path checks, shared by every importer.

Importers never stop at the first bad file (unless ``strict``): they record the problem
against the file or object it concerns, skip that sample or object, and carry on. The
report is printed at the end and returned to the caller.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any


class DataImportError(Exception):
    """An import cannot proceed (strict mode, or nothing importable was found)."""


def import_paths(src_dir: str | Path, out_dir: str | Path, overwrite: bool) -> tuple[Path, Path]:
    """The source and store paths of an import, checked before any work starts.

    Raises:
        DataImportError: the source directory does not exist.
        FileExistsError: the store path exists and ``overwrite`` is false.
    """
    src, out = Path(src_dir), Path(out_dir)
    if not src.is_dir():
        raise DataImportError(f"{src}: source directory not found")
    if out.exists() and not overwrite:
        raise FileExistsError(f"{out} already exists; pass --overwrite to replace it")
    return src, out


@dataclass
class ImportReport:
    """Counts and per-file problems of one import run."""

    source: str
    source_dir: str
    store_dir: str = ""
    samples_imported: int = 0
    objects_imported: int = 0
    objects_seen: int = 0
    seconds: float = 0.0
    problems: list[tuple[str, str]] = field(default_factory=list)  # (path, reason)
    strict: bool = False

    def problem(self, path: str | Path, reason: str) -> None:
        """Record a skipped file/object; in strict mode the first problem is fatal."""
        self.problems.append((str(path), reason))
        if self.strict:
            raise DataImportError(f"{path}: {reason} (strict mode: stopping at the first problem)")

    @property
    def samples_per_second(self) -> float:
        return self.samples_imported / self.seconds if self.seconds > 0 else float("nan")

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
            "seconds": round(self.seconds, 3),
            "problems": [{"path": p, "reason": r} for p, r in self.problems],
            "problem_counts": dict(self.reasons()),
        }

    def format(self, max_listed: int = 20) -> str:
        """Human-readable summary: totals, counts per reason, the first problems."""
        lines = [
            f"Imported {self.samples_imported} samples from {self.objects_imported}/"
            f"{self.objects_seen} objects ({self.source}) into {self.store_dir} "
            f"in {self.seconds:.1f} s ({self.samples_per_second:.1f} samples/s).",
        ]
        if self.problems:
            lines.append(f"Skipped {len(self.problems)} item(s):")
            for reason, count in self.reasons().most_common():
                lines.append(f"  {count:6d}  {reason}")
            lines.append("First problems:")
            for path, reason in self.problems[:max_listed]:
                lines.append(f"  {path}: {reason}")
            if len(self.problems) > max_listed:
                lines.append(f"  ... and {len(self.problems) - max_listed} more")
        else:
            lines.append("No problems.")
        return "\n".join(lines)
