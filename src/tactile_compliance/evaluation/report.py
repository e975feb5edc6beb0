"""``build_report``: the paper's tables and figures from a results store, as MD / HTML / LaTeX.

Runs the sections in order and writes the documents. See docs/reporting.md.
"""

from __future__ import annotations

import json
import logging
import traceback
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import pandas as pd

from tactile_compliance import __version__
from tactile_compliance.evaluation import figures
from tactile_compliance.evaluation.loading import complete_rows, load_results, store_header
from tactile_compliance.evaluation.parts import ReportParts, safe_name
from tactile_compliance.evaluation.render import (
    Heading,
    Paragraph,
    latex_table,
    render_html,
    render_latex,
    render_markdown,
)
from tactile_compliance.evaluation.run_report import is_run_dir, run_report_parts
from tactile_compliance.evaluation.tables import (
    PRESET_HINTS,
    STD_DDOF,
    describe_weights,
    failed_table,
    group_metric_tables,
    paper_tables,
    shore_table,
    softhard_subset_table,
)
from tactile_compliance.outputs import atomic_file, claim_output_dir
from tactile_compliance.runs.results import STATUS_COMPLETE, STATUS_FAILED

__all__ = ["FORMATS", "ReportSummary", "build_report"]

log = logging.getLogger(__name__)

FORMATS: tuple[str, ...] = ("md", "html", "tex")


@dataclass
class ReportSummary:
    """What :func:`build_report` wrote and what it had to skip.

    Attributes:
        documents: format (``md``/``html``/``tex``) -> file.
        figures: figure id (``fig1-<store>``, ``fig5``, ``fig6``, ...) -> PNG.
        tables: table id -> tidy DataFrame of its numbers (``mean``, ``std``, ``n``, ...).
        notes: one line per skipped or degraded part (also in the report).
    """

    results_dir: Path
    out_dir: Path
    documents: dict[str, Path] = field(default_factory=dict)
    figures: dict[str, Path] = field(default_factory=dict)
    tables: dict[str, pd.DataFrame] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    n_rows: int = 0
    n_complete: int = 0
    n_failed: int = 0

    def __str__(self) -> str:
        lines = [
            f"report of {self.results_dir}: {self.n_complete} complete / {self.n_rows} rows "
            f"({self.n_failed} failed)",
            *(f"  {fmt}: {path}" for fmt, path in self.documents.items()),
            f"  {len(self.figures)} figure(s), {len(self.tables)} table(s) in {self.out_dir}",
        ]
        lines += [f"  skipped: {note}" for note in self.notes]
        return "\n".join(lines)


class _Builder:
    """The report's inputs and its sections; figures come from :mod:`figures`."""

    def __init__(
        self,
        frame: pd.DataFrame,
        results_dir: Path,
        out_dir: Path,
        ddof: int,
        extra_stores: Sequence[Path],
        strict: bool,
    ) -> None:
        self.frame = frame
        self.done = complete_rows(frame)
        self.results_dir = results_dir
        self.fig_dir = out_dir / "figures"
        self.ddof = ddof
        self.extra_stores = list(extra_stores)
        self.strict = strict
        self.parts = ReportParts()

    def section(self, name: str, build: Callable[[], None]) -> None:
        """Run one section; a bug or unreadable file becomes a note, not a crashed report."""
        try:
            build()
        except Exception as err:
            if self.strict:
                raise
            log.warning("report section %s failed:\n%s", name, traceback.format_exc())
            self.parts.note(f"{name} could not be built: {type(err).__name__}: {err}")

    # ------------------------------------------------------------------ provenance
    def provenance(self, title: str) -> None:
        """The title and where every number comes from: store, presets, seeds, versions."""
        frame, done = self.frame, self.done
        n_failed = int((frame["status"] == STATUS_FAILED).sum())
        other = len(frame) - len(done) - n_failed
        lines = [
            f"- Results store: `{self.results_dir}` — {len(frame)} rows: {len(done)} complete, "
            f"{n_failed} failed" + (f", {other} other (unfinished)" if other else ""),
        ]
        counts = [
            f"`{preset or '(none)'}` ({(rows['status'] == STATUS_COMPLETE).sum()}/{len(rows)} "
            "complete)"
            for preset, rows in frame.groupby("preset", sort=True)
        ]
        if counts:
            lines.append(f"- Presets: {', '.join(counts)}")
        if not done.empty:
            cell_keys = ["preset", "model", "inputs", "protocol", "sampling"]
            per_cell = (
                done.assign(_s=done["subset_value"].astype(str))
                .groupby([*cell_keys, "_s"], dropna=False)["seed"]
                .nunique()
            )
            seeds = sorted(int(s) for s in done["seed"].dropna().unique())
            lines.append(
                f"- Seeds per cell: {per_cell.min()}–{per_cell.max()} "
                f"({len(per_cell)} cells; seeds used: {', '.join(map(str, seeds))})"
            )
        stores = list(
            dict.fromkeys([*frame["store"].dropna().astype(str), *map(str, self.extra_stores)])
        )
        for store in stores:
            header = store_header(store)
            if header is None:
                lines.append(f"- Store `{store}`: header not reachable from here")
            else:
                lines.append(
                    f"- Store `{store}`: source {header.source}, "
                    f"{header.num_samples} samples, frames "
                    f"{'x'.join(map(str, header.image_size))} px, created "
                    f"{header.created or '?'} by tactile-compliance "
                    f"{header.package_version or '?'}"
                )
        if not done.empty:
            lines.append(f"- Backbone weights: {describe_weights(done)}")
        lines.append(
            f"- Report: tactile-compliance {__version__}, built "
            f"{datetime.now(timezone.utc).isoformat(timespec='seconds')}; std over seeds with "
            f"ddof={self.ddof}; metrics on each run's test split with its best checkpoint"
        )
        lines.append(
            "- Metrics: log₁₀ accuracy = share of test samples within one decade of the true "
            "modulus; N-MSE = mean squared error of the log-min-max normalised modulus "
            "(range [1e3, 1e12] Pa unless a run's config says otherwise); R² on the same scale"
        )
        self.parts.blocks += [
            Heading(title, 1),
            Heading("Provenance", 2),
            Paragraph("\n".join(lines)),
        ]

    # ------------------------------------------------------------------ Tables I / II
    def paper_table_section(self, sampling: str, number: str, preset: str) -> None:
        """Table I or II: one table per (preset, store) of the main grid with ``sampling``."""
        strategy = " (Balanced strategy)" if sampling == "balanced" else ""
        self.parts.blocks.append(Heading(f"Table {number}: {sampling} sampling{strategy}", 2))
        built = paper_tables(self.frame, sampling, number, self.ddof)
        if not built:
            self.parts.note(
                f"Table {number} skipped: no complete runs with sampling={sampling} on the "
                f"whole dataset; produced by the `{preset}` preset."
            )
            return
        for index, paper in enumerate(built):
            key = f"table{number}" if len(built) == 1 else f"table{number}-{index + 1}"
            self.parts.add_table(key, paper)

    # ------------------------------------------------------------------ Table III
    def table3(self) -> None:
        """Table III: the Shore-hardness runs."""
        self.parts.blocks.append(Heading("Table III: new dataset (Shore hardness)", 2))
        paper = shore_table(self.frame, self.ddof)
        if paper is None:
            self.parts.note(
                f"Table III and Fig. 8 skipped: no complete runs on a Shore-hardness store; "
                f"produced by the `{PRESET_HINTS['table3']}` preset."
            )
            return
        self.parts.add_table("table3", paper)

    # ------------------------------------------------------------------ extras
    def extras(self) -> None:
        """Per-group errors and learning curves of the headline runs; soft / hard subsets."""
        self.parts.blocks.append(Heading("Extra analyses", 2))
        headline = figures.headline_runs(self.frame)
        if headline is None:
            self.parts.note(
                "Per-material tables and learning curves skipped: no complete runs on the "
                "whole dataset (presets `table1` / `table2`)."
            )
        else:
            rows, setting = headline
            built = group_metric_tables(rows, self.results_dir, setting, self.ddof)
            if built:
                self.parts.blocks.append(Heading("Errors per material, shape and stiffness", 3))
                for paper in built:
                    self.parts.add_table(paper.table.label, paper)
            else:
                self.parts.note(
                    "Per-material tables skipped: no run of the headline setting has a "
                    "readable groups.csv."
                )
            figures.learning_curves(self.parts, rows, setting, self.results_dir, self.fig_dir)
        softhard = softhard_subset_table(self.frame, self.ddof)
        if softhard is not None:
            self.parts.blocks.append(Heading("Soft / hard training subsets", 3))
            self.parts.add_table("softhard-subsets", softhard)

    def failures(self) -> None:
        """Every run that did not complete, with its error."""
        table = failed_table(self.frame)
        self.parts.blocks.append(Heading("Failed runs", 2))
        if table is None:
            self.parts.blocks.append(Paragraph("Every recorded run completed."))
            return
        self.parts.blocks.append(table)
        self.parts.latex_tables["failed-runs"] = table


# ============================================================================ helpers
def _normalise_formats(formats: str | Iterable[str]) -> list[str]:
    items = formats.split(",") if isinstance(formats, str) else list(formats)
    wanted = [f.strip().lower().lstrip(".") for f in items if f.strip()]
    wanted = ["md" if f == "markdown" else "tex" if f == "latex" else f for f in wanted]
    unknown = sorted(set(wanted) - set(FORMATS))
    if unknown:
        raise ValueError(f"unknown report format(s) {unknown}; choose from {', '.join(FORMATS)}")
    return list(dict.fromkeys(wanted))


# ============================================================================ entry point
def build_report(
    results_dir: str | Path,
    out_dir: str | Path | None = None,
    formats: str | Iterable[str] = ("md", "html"),
    *,
    stores: Sequence[str | Path] = (),
    ddof: int = STD_DDOF,
    title: str = "Young's modulus from GelSight grasps — results report",
    strict: bool = False,
) -> ReportSummary:
    """Build the report of a results store: tables, figures, and the documents.

    Only rows with ``status == "complete"`` count. A part whose rows are missing, or that
    fails, is skipped with a note in the report (and in ``ReportSummary.notes``) naming
    the preset that produces it; the rest is still written. Files written under
    ``out_dir`` (claimed: a directory ``report`` did not write is refused)::

        report.md, report.html (self-contained), report.tex   as ``formats`` asks
        report.json                  documents, figures, tables and notes
        figures/*.png
        tables/*.tex, tables/*.csv   one booktabs table and its tidy numbers per table

    Args:
        results_dir: the results store (``RESULTS/rows/*.json``), or one run directory
            (it holds ``metrics.json``): then the report is that run's metrics table and
            its predicted-against-true figure (``run_report.run_report_parts``).
        out_dir: where to write; default ``RESULTS/report``.
        formats: any of ``md``, ``html``, ``tex`` (a list or ``"md,html"``).
        stores: extra GraspStore directories to draw in Fig. 1 (besides the runs' stores).
        ddof: delta degrees of freedom of the std over seeds (1: sample std).
        strict: re-raise errors inside a section instead of turning them into a note.

    Raises:
        FileNotFoundError: ``results_dir`` does not exist.
        ValueError: an unknown format.
    """
    wanted = _normalise_formats(formats)
    results = Path(results_dir)
    if is_run_dir(results):
        return _build_run_report(results, out_dir, wanted)
    frame = load_results(results)
    out = claim_output_dir(Path(out_dir) if out_dir is not None else results / "report", "report")
    builder = _Builder(frame, results, out, ddof, [Path(s) for s in stores], strict)
    parts, fig_dir = builder.parts, builder.fig_dir

    builder.provenance(title)
    if builder.done.empty:
        parts.note(
            "No complete runs yet: every table and figure below is skipped. Run a grid preset "
            "(`table1`, `table2`, `rolling-window`, `shape-test`, `new-dataset`) first."
        )
    builder.section(
        "Table I", lambda: builder.paper_table_section("random", "I", PRESET_HINTS["table1"])
    )
    builder.section(
        "Table II", lambda: builder.paper_table_section("balanced", "II", PRESET_HINTS["table2"])
    )
    builder.section("Fig. 1", lambda: figures.fig1(parts, frame, builder.extra_stores, fig_dir))
    builder.section("Fig. 5", lambda: figures.fig5(parts, frame, results, fig_dir))
    builder.section("Fig. 6", lambda: figures.fig6(parts, frame, fig_dir, ddof))
    builder.section("Fig. 7", lambda: figures.fig7(parts, frame, fig_dir, ddof))
    builder.section("Table III", builder.table3)
    builder.section("Fig. 8", lambda: figures.fig8(parts, frame, results, fig_dir))
    builder.section("Extras", builder.extras)
    builder.section("Failed runs", builder.failures)

    summary = ReportSummary(
        results_dir=results,
        out_dir=out,
        figures=dict(parts.figures),
        tables=dict(parts.tables),
        notes=list(parts.notes),
        n_rows=len(frame),
        n_complete=len(builder.done),
        n_failed=int((frame["status"] == STATUS_FAILED).sum()),
    )
    _write_documents(parts, out, wanted, title, summary)
    return summary


def _build_run_report(
    run_dir: Path, out_dir: str | Path | None, wanted: list[str]
) -> ReportSummary:
    """:func:`build_report` of one run directory (``run_report.run_report_parts``)."""
    out = claim_output_dir(Path(out_dir) if out_dir is not None else run_dir / "report", "report")
    parts, result = run_report_parts(run_dir, out / "figures")
    complete = result.get("status") == STATUS_COMPLETE
    summary = ReportSummary(
        results_dir=run_dir,
        out_dir=out,
        figures=dict(parts.figures),
        tables=dict(parts.tables),
        notes=list(parts.notes),
        n_rows=1,
        n_complete=int(complete),
        n_failed=int(result.get("status") == STATUS_FAILED),
    )
    title = f"Young's modulus from GelSight grasps — run {run_dir.name}"
    _write_documents(parts, out, wanted, title, summary)
    return summary


def _write_documents(
    parts: ReportParts, out: Path, wanted: list[str], title: str, summary: ReportSummary
) -> None:
    """The tables, the documents in ``wanted`` formats and ``report.json`` under ``out``."""
    results = summary.results_dir
    _write_tables(parts, out / "tables")
    renderers = {
        "md": lambda: render_markdown(parts.blocks, out),
        "html": lambda: render_html(parts.blocks, title),
        "tex": lambda: render_latex(parts.blocks, out, title),
    }
    for fmt in (f for f in FORMATS if f in wanted):
        summary.documents[fmt] = out / f"report.{fmt}"
        _write_text(summary.documents[fmt], renderers[fmt]())
    _write_text(
        out / "report.json",
        json.dumps(
            {
                "results_dir": str(results),
                "package_version": __version__,
                "built": datetime.now(timezone.utc).isoformat(timespec="seconds"),
                "rows": summary.n_rows,
                "complete": summary.n_complete,
                "failed": summary.n_failed,
                "documents": {k: str(v) for k, v in summary.documents.items()},
                "figures": {k: str(v) for k, v in summary.figures.items()},
                "tables": sorted(summary.tables),
                "notes": summary.notes,
            },
            indent=2,
        )
        + "\n",
    )


def _write_tables(parts: ReportParts, table_dir: Path) -> None:
    """Each table as a standalone booktabs ``.tex`` and its tidy numbers as ``.csv``."""
    if not parts.latex_tables and not parts.tables:
        return
    table_dir.mkdir(parents=True, exist_ok=True)
    for label, table in parts.latex_tables.items():
        _write_text(table_dir / f"{safe_name(label)}.tex", latex_table(table) + "\n")
    for key, cells in parts.tables.items():
        with atomic_file(table_dir / f"{safe_name(key)}.csv") as handle:
            cells.to_csv(handle, index=False)


def _write_text(path: Path, text: str) -> None:
    """Write a file of the report (``outputs.atomic_file``: whole, never through a link)."""
    with atomic_file(path) as handle:
        handle.write(text)
