"""What a report collects while it is built: document blocks, figures, tables and notes.

Every section writes into one :class:`ReportParts`, so the order of the blocks is the
order of the document.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from tactile_compliance.evaluation.render import Block, Figure, Note, Table
from tactile_compliance.evaluation.tables import PaperTable

__all__ = ["ReportParts", "safe_name"]


def safe_name(text: str) -> str:
    """``text`` with anything but letters, digits and ``-_.`` replaced: a file-name stem."""
    return "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in text) or "x"


@dataclass
class ReportParts:
    """The growing report; figure and table ids name their files (``tables/ID.csv``)."""

    blocks: list[Block] = field(default_factory=list)
    figures: dict[str, Path] = field(default_factory=dict)
    tables: dict[str, pd.DataFrame] = field(default_factory=dict)
    latex_tables: dict[str, Table] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def note(self, text: str) -> None:
        """Say in the document, and in the summary, what is missing or degraded."""
        self.notes.append(text)
        self.blocks.append(Note(text))

    def add_table(self, key: str, paper: PaperTable) -> None:
        """Add a table to the document and register its numbers and LaTeX under ``key``."""
        self.blocks.append(paper.table)
        self.tables[key] = paper.cells
        self.latex_tables[key] = paper.table  # tables/KEY.tex next to tables/KEY.csv

    def add_figure(self, key: str, path: Path, caption: str, provenance: str) -> None:
        """Add a drawn figure to the document, labelled and registered as ``key``."""
        self.figures[key] = path
        self.blocks.append(Figure(path, caption, provenance, label=key))
