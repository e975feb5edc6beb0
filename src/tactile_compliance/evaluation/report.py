"""``build_report``: the paper's tables and figures from a results store, as MD / HTML / LaTeX.

What goes where (only ``status == "complete"`` rows count; each part is skipped with a note
naming the preset that produces it when its rows are missing):

* Table I / II — :func:`tables.paper_tables` (random / balanced sampling, whole dataset);
* Table III and Fig. 8 — Shore-hardness runs (header source ``yuan`` or preset
  ``new-dataset``);
* Fig. 1 — the distribution of the normalised modulus by shape in each store the runs used;
* Fig. 5 — predicted vs true modulus per material for Image and ALL of each model, from the
  ``predictions.csv`` (test split) of the run with the lowest test N-MSE, preferring
  balanced + seen runs as the paper does and falling back to what exists;
* Fig. 6 / Fig. 7 — N-MSE box plots over seeds per rolling window / shape, with the numbers
  in a companion table;
* extras — per-material / shape / soft-hard errors (from ``groups.csv``), soft/hard subset
  runs, learning curves (from ``logs/metrics.csv``), failed runs.

Output directory::

    OUT/report.md  report.html (self-contained)  report.tex  report.json
    OUT/figures/*.png
    OUT/tables/*.tex (one booktabs table per file)  tables/*.csv (the tidy numbers)
"""

from __future__ import annotations

import json
import logging
import math
import traceback
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from tactile_compliance import __version__
from tactile_compliance.data.normalisation import NormalisationConstants
from tactile_compliance.data.store import GraspStore, StoreError
from tactile_compliance.evaluation import plots
from tactile_compliance.evaluation.render import (
    Block,
    Cell,
    Figure,
    Heading,
    Note,
    Paragraph,
    Table,
    latex_table,
    render_html,
    render_latex,
    render_markdown,
)
from tactile_compliance.evaluation.tables import (
    CONDITION_LABELS,
    MODEL_ORDER,
    PRESET_HINTS,
    SETTING_PREFERENCE,
    STD_DDOF,
    PaperTable,
    complete_rows,
    describe_runs,
    describe_weights,
    failed_table,
    group_metric_tables,
    load_results,
    main_grid,
    model_label,
    ordered,
    paper_tables,
    resolve_run_dir,
    shore_table,
    softhard_subset_table,
    store_header,
    subset_summary_table,
    window_label,
)
from tactile_compliance.models.inputs import InputStrategy
from tactile_compliance.runs.results import STATUS_COMPLETE, STATUS_FAILED

__all__ = ["FORMATS", "ReportSummary", "build_report"]

log = logging.getLogger(__name__)

FORMATS: tuple[str, ...] = ("md", "html", "tex")
_DOC_NAMES = {"md": "report.md", "html": "report.html", "tex": "report.tex"}
_SHAPE_ORDER = ("Sphere", "Cylinder", "Rectangular", "Irregular")
_FIG5_INPUTS = ("Image", "ALL")
#: Fig. 1 draws at most this many stores (a results store normally uses one or two).
MAX_STORES = 4


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
    """Collects blocks, figures and tables; one method per report section."""

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
        self.out_dir = out_dir
        self.fig_dir = out_dir / "figures"
        self.ddof = ddof
        self.extra_stores = list(extra_stores)
        self.strict = strict
        self.blocks: list[Block] = []
        self.figures: dict[str, Path] = {}
        self.tables: dict[str, pd.DataFrame] = {}
        self.latex_tables: dict[str, Table] = {}
        self.notes: list[str] = []

    # ------------------------------------------------------------------ plumbing
    def note(self, text: str) -> None:
        self.notes.append(text)
        self.blocks.append(Note(text))

    def add_table(self, key: str, paper: PaperTable) -> None:
        self.blocks.append(paper.table)
        self.tables[key] = paper.cells
        self.latex_tables[key] = paper.table  # tables/KEY.tex next to tables/KEY.csv

    def section(self, name: str, build: Callable[[], None]) -> None:
        """Run one section; a bug or unreadable file becomes a note, not a crashed report."""
        try:
            build()
        except Exception as err:
            if self.strict:
                raise
            log.warning("report section %s failed:\n%s", name, traceback.format_exc())
            self.note(f"{name} could not be built: {type(err).__name__}: {err}")

    # ------------------------------------------------------------------ provenance
    def provenance(self, title: str) -> None:
        frame, done = self.frame, self.done
        n_failed = int((frame["status"] == STATUS_FAILED).sum())
        other = len(frame) - len(done) - n_failed
        lines = [
            f"- Results store: `{self.results_dir}` — {len(frame)} rows: {len(done)} complete, "
            f"{n_failed} failed" + (f", {other} other (unfinished)" if other else ""),
        ]
        presets = sorted(set(frame["preset"]))
        if presets:
            parts = []
            for preset in presets:
                rows = frame[frame["preset"] == preset]
                ok = int((rows["status"] == STATUS_COMPLETE).sum())
                parts.append(f"`{preset or '(none)'}` ({ok}/{len(rows)} complete)")
            lines.append(f"- Presets: {', '.join(parts)}")
        if not done.empty:
            cell_keys = ["preset", "model", "inputs", "condition", "sampling"]
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
                    f"- Store `{store}`: source {header.get('source')}, "
                    f"{header.get('num_samples')} samples, frames "
                    f"{'x'.join(map(str, header.get('image_size', [])))} px, created "
                    f"{header.get('created', '?')} by tactile-compliance "
                    f"{header.get('package_version', '?')}"
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
        self.blocks += [Heading(title, 1), Heading("Provenance", 2), Paragraph("\n".join(lines))]

    # ------------------------------------------------------------------ Tables I / II
    def paper_table_section(self, sampling: str, number: str, preset: str) -> None:
        self.blocks.append(
            Heading(
                f"Table {number}: {sampling} sampling"
                + (" (Balanced strategy)" if sampling == "balanced" else ""),
                2,
            )
        )
        built = paper_tables(self.frame, sampling, number, self.ddof)
        if not built:
            self.note(
                f"Table {number} skipped: no complete runs with sampling={sampling} on the "
                f"whole dataset; produced by the `{preset}` preset."
            )
            return
        for index, paper in enumerate(built):
            key = f"table{number}" if len(built) == 1 else f"table{number}-{index + 1}"
            self.add_table(key, paper)

    # ------------------------------------------------------------------ Fig. 1
    def _load_samples(self, store: str) -> tuple[pd.DataFrame, str] | None:
        try:
            opened = GraspStore.open(store)
            return opened.samples, opened.header.source
        except (StoreError, OSError, ValueError):
            # Fig. 1 needs only the table: a store copied without its frames still plots.
            path = Path(store)
            header = store_header(store)
            if header is None or not (path / "samples.parquet").is_file():
                return None
            return pd.read_parquet(path / "samples.parquet"), str(header.get("source"))

    def fig1(self) -> None:
        self.blocks.append(Heading("Fig. 1: dataset distribution", 2))
        stores: list[str] = []
        seen: set[str] = set()
        for store in [
            *self.done["store"].dropna().astype(str),
            *self.frame["store"].dropna().astype(str),
            *map(str, self.extra_stores),
        ]:
            resolved = str(Path(store).expanduser().resolve())
            if resolved not in seen:
                seen.add(resolved)
                stores.append(store)
        if not stores:
            self.note(
                "Fig. 1 skipped: no store recorded; produced from the store of "
                f"{PRESET_HINTS['fig1']}."
            )
            return
        drawn = 0
        for store in stores[:MAX_STORES]:
            loaded = self._load_samples(store)
            if loaded is None:
                self.note(f"Fig. 1 skipped for `{store}`: the store is not reachable from here.")
                continue
            samples, source = loaded
            constants = (
                NormalisationConstants.for_shore_data()
                if source == "yuan"
                else NormalisationConstants()
            )
            name = Path(store).name or "store"
            out = self.fig_dir / f"fig1_dataset_{_safe(name)}.png"
            plots.plot_dataset_distribution(
                samples, out, constants, title=f"Dataset distribution: {name} ({source})"
            )
            self.figures[f"fig1-{_safe(name)}"] = out
            lo, hi = constants.label_range_pa
            self.blocks.append(
                Figure(
                    out,
                    f"Fig. 1 — normalised Young's modulus of `{name}` split by object shape.",
                    f"all {len(samples)} samples of store `{store}` (source {source}, before "
                    f"the training filters); modulus normalised as log10 min-max over "
                    f"[1e{math.log10(lo):.0f}, 1e{math.log10(hi):.0f}] Pa; blue dashed line: "
                    "the gel's 0.275 MPa.",
                    label=f"fig1-{_safe(name)}",
                )
            )
            drawn += 1
        if len(stores) > MAX_STORES:
            self.note(f"Fig. 1 drawn for the first {MAX_STORES} of {len(stores)} stores.")

    # ------------------------------------------------------------------ Fig. 5 / 8
    def _predictions(self, row: Any) -> pd.DataFrame | None:
        run_dir = resolve_run_dir(row.run_dir, self.results_dir)
        if run_dir is None or not (run_dir / "predictions.csv").is_file():
            return None
        predictions = pd.read_csv(run_dir / "predictions.csv")
        if "split" in predictions.columns:
            predictions = predictions[predictions["split"] == "test"]
        predictions = predictions[(predictions["modulus_pa"] > 0) & (predictions["pred_pa"] > 0)]
        return predictions if not predictions.empty else None

    def _span(self, row: Any, shore: bool) -> float:
        """Label span in decades (9 on [1e3, 1e12]) from the run's config, for the band."""
        run_dir = resolve_run_dir(row.run_dir, self.results_dir)
        if run_dir is not None and (run_dir / "config.yaml").is_file():
            try:
                import yaml

                config = yaml.safe_load((run_dir / "config.yaml").read_text()) or {}
                lo, hi = config.get("data", {}).get("label_range_pa")
                return math.log10(float(hi)) - math.log10(float(lo))
            except Exception:
                pass
        constants = NormalisationConstants.for_shore_data() if shore else NormalisationConstants()
        return constants.label_log10_span

    @staticmethod
    def _setting_rank(row: Any) -> int:
        key = (row.sampling, row.condition)
        return (
            SETTING_PREFERENCE.index(key) if key in SETTING_PREFERENCE else len(SETTING_PREFERENCE)
        )

    def _headline(self) -> tuple[pd.DataFrame, str] | None:
        """The runs of the preferred setting (balanced + seen first) and its preset."""
        rows = main_grid(self.frame)
        for sampling, condition in SETTING_PREFERENCE:
            part = rows[(rows["sampling"] == sampling) & (rows["condition"] == condition)]
            if part.empty:
                continue
            counts = part["preset"].value_counts()
            preset = sorted(counts[counts == counts.max()].index)[0]
            part = part[part["preset"] == preset]
            return (
                part,
                f"preset `{preset}`, {sampling} sampling, "
                f"{CONDITION_LABELS.get(condition, condition)}",
            )
        return None

    def _best_panels(
        self, rows: pd.DataFrame, inputs: Sequence[str], preferred: pd.DataFrame | None, shore: bool
    ) -> tuple[list[plots.ScatterPanel | str], list[list[Cell]], pd.DataFrame]:
        panels: list[plots.ScatterPanel | str] = []
        body: list[list[Cell]] = []
        tidy: list[dict[str, Any]] = []
        models = ordered(rows["model"], MODEL_ORDER)
        for inp in inputs:
            for model in models:
                cand = rows[(rows["model"] == model) & (rows["inputs"] == inp)]
                cand = cand.assign(
                    sel_pref=[
                        0 if preferred is not None and key in set(preferred["key"]) else 1
                        for key in cand["key"]
                    ],
                    sel_rank=[self._setting_rank(r) for r in cand.itertuples(index=False)],
                    sel_nmse=pd.to_numeric(
                        cand["test_nmse"] if "test_nmse" in cand.columns else np.nan,
                        errors="coerce",
                    ),
                ).dropna(subset=["sel_nmse"])
                cand = cand.sort_values(
                    ["sel_pref", "sel_rank", "preset", "sampling", "condition", "sel_nmse"]
                )
                chosen = None
                for row in cand.itertuples(index=False):
                    predictions = self._predictions(row)
                    if predictions is not None:
                        chosen = (row, predictions)
                        break
                if chosen is None:
                    panels.append(f"{model_label(model)} · {inp}\nno run with predictions")
                    continue
                row, predictions = chosen
                same = cand[
                    (cand["preset"] == row.preset)
                    & (cand["sampling"] == row.sampling)
                    & (cand["condition"] == row.condition)
                ]
                rank = int((same["sel_nmse"] < row.sel_nmse).sum()) + 1
                panel = plots.ScatterPanel(
                    title=f"{model_label(model)} · {inp}",
                    true_pa=predictions["modulus_pa"].to_numpy(dtype=float),
                    pred_pa=predictions["pred_pa"].to_numpy(dtype=float),
                    material=predictions.get("material", pd.Series(["?"] * len(predictions)))
                    .astype(str)
                    .to_numpy(),
                    nmse=float(row.sel_nmse),
                    span_decades=self._span(row, shore),
                    subtitle=f"{row.sampling}, {row.condition}, seed {row.seed}",
                )
                panels.append(panel)
                inside = panel.inside
                body.append(
                    [
                        Cell(text=model_label(model)),
                        Cell(text=str(inp)),
                        Cell(text=f"{row.preset}: {row.sampling}, {row.condition}"),
                        Cell(text=str(row.seed)),
                        Cell(text=f"{rank} of {len(same)}"),
                        Cell(float(row.sel_nmse)),
                        Cell(100 * inside, digits=1),
                        Cell(text=str(panel.true_pa.size)),
                        Cell(text=str(getattr(row, "run_name", "") or Path(str(row.run_dir)).name)),
                    ]
                )
                tidy.append(
                    {
                        "model": model,
                        "inputs": inp,
                        "preset": row.preset,
                        "sampling": row.sampling,
                        "condition": row.condition,
                        "seed": row.seed,
                        "nmse": float(row.sel_nmse),
                        "inside_band": inside,
                        "n": int(panel.true_pa.size),
                        "run_dir": row.run_dir,
                    }
                )
        return panels, body, pd.DataFrame(tidy)

    def _scatter_table(
        self, title: str, body: list[list[Cell]], label: str, caption: str, rows: pd.DataFrame
    ) -> Table:
        return Table(
            title=title,
            columns=[
                "Model",
                "Input",
                "Setting",
                "Seed",
                "N-MSE rank",
                "N-MSE",
                "inside band (%)",
                "test samples",
                "Run",
            ],
            rows=body,
            caption=caption,
            provenance=describe_runs(
                rows, "one point per test sample of the chosen run (predictions.csv, split test)"
            ),
            label=label,
        )

    def fig5(self) -> None:
        self.blocks.append(Heading("Fig. 5: material test (predicted vs true modulus)", 2))
        rows = main_grid(self.frame)
        rows = rows[rows["inputs"].isin(_FIG5_INPUTS)]
        if rows.empty:
            self.note(
                "Fig. 5 skipped: no complete Image/ALL runs on the whole dataset; produced by "
                f"{PRESET_HINTS['fig5']}."
            )
            return
        headline = self._headline()
        panels, body, tidy = self._best_panels(
            rows,
            [i for i in _FIG5_INPUTS if i in set(rows["inputs"])],
            headline[0] if headline else None,
            shore=False,
        )
        if tidy.empty:
            self.note(
                "Fig. 5 skipped: none of the candidate runs has a readable predictions.csv "
                "(run directories missing or moved)."
            )
            return
        out = plots.plot_prediction_panels(
            panels,
            self.fig_dir / "fig5_material_scatter.png",
            ncols=len(ordered(rows["model"], MODEL_ORDER)),
            suptitle="Predicted vs true Young's modulus per material (lowest-N-MSE seed)",
        )
        self.figures["fig5"] = out
        used = rows[rows["run_dir"].isin(tidy["run_dir"])]
        self.blocks.append(
            Figure(
                out,
                "Fig. 5 — predicted vs true Young's modulus per material, Image (top) and ALL "
                "(bottom) for each model. Red: y = x; blue: the gel's 0.275 MPa; grey: the "
                "N-MSE band y = x·f^±1 with f = 10^(9·√N-MSE); a point is inside when its squared "
                "normalised error is at most the run's N-MSE.",
                describe_runs(
                    used,
                    "the seed with the lowest test N-MSE of the preferred setting "
                    "(balanced + seen, else random + seen, ...); see the table below",
                ),
                label="fig5",
            )
        )
        self.tables["fig5"] = tidy
        self.blocks.append(
            self._scatter_table(
                "Fig. 5 runs",
                body,
                "fig5-runs",
                "The run behind each panel and the share of points in its band.",
                used,
            )
        )

    def fig8(self) -> None:
        done = self.done
        rows = done[done["is_shore"].astype(bool) & (done["subset_kind"] == "none")]
        if rows.empty:
            return  # Table III's note already says what is missing
        inputs = (
            ["Image"]
            if "Image" in set(rows["inputs"])
            else ordered(rows["inputs"], InputStrategy.names())[:1]
        )
        panels, body, tidy = self._best_panels(rows, inputs, None, shore=True)
        if tidy.empty:
            self.note("Fig. 8 skipped: no Shore-hardness run has a readable predictions.csv.")
            return
        out = plots.plot_prediction_panels(
            panels,
            self.fig_dir / "fig8_new_dataset_scatter.png",
            ncols=len(panels),
            suptitle="Shore-hardness data: predicted vs true Young's modulus (lowest-N-MSE seed)",
        )
        self.figures["fig8"] = out
        used = rows[rows["run_dir"].isin(tidy["run_dir"])]
        self.blocks.append(
            Figure(
                out,
                f"Fig. 8 — Shore-hardness data, {inputs[0]} input: predicted vs true modulus per "
                "material; band as in Fig. 5 on this data's label range.",
                describe_runs(used, "seed with the lowest test N-MSE per model"),
                label="fig8",
            )
        )
        self.tables["fig8"] = tidy
        self.blocks.append(
            self._scatter_table(
                "Fig. 8 runs", body, "fig8-runs", "The run behind each panel.", used
            )
        )

    # ------------------------------------------------------------------ Fig. 6 / 7
    def fig6(self) -> None:
        self.blocks.append(Heading("Fig. 6: rolling window (N-MSE per modulus range)", 2))
        done = self.done
        rows = done[(done["subset_kind"] == "window") & ~done["is_shore"].astype(bool)]
        if rows.empty:
            self.note(
                "Fig. 6 skipped: no complete rolling-window runs (subset 0-6); produced by "
                f"the `{PRESET_HINTS['fig6']}` preset."
            )
            return
        for preset, part in rows.groupby("preset", sort=True):
            suffix = "" if rows["preset"].nunique() == 1 else f"_{_safe(str(preset))}"
            data = part.assign(
                _x=part["subset_value"].astype(int),
                _series=_series_names(part),
            )
            windows = sorted(set(data["_x"]))
            labels = [window_label(k) for k in windows]
            series = list(dict.fromkeys(_series_names(part.sort_values("model", key=_model_key))))
            out = plots.plot_nmse_boxes(
                data,
                self.fig_dir / f"fig6_rolling_window{suffix}.png",
                x="_x",
                series="_series",
                x_order=windows,
                x_labels=labels,
                series_order=series,
                title=f"N-MSE per Young's modulus range ({_setting_text(part)})",
                xlabel="Young's modulus range of the subset (Pa)",
            )
            self.figures[f"fig6{suffix}"] = out
            self.blocks.append(
                Figure(
                    out,
                    "Fig. 6 — test N-MSE over seeds for the 7 rolling windows (three decades each, "
                    "undersampled to equal size). Boxes: quartiles and median; whiskers: 1.5 IQR; "
                    "dots: single runs.",
                    describe_runs(part),
                    label=f"fig6{suffix}",
                )
            )
            table = subset_summary_table(
                part,
                "window",
                "Fig. 6 numbers",
                "Test N-MSE per rolling window (best per column in **bold**).",
                f"fig6-numbers{suffix}",
                self.ddof,
            )
            if table is not None:
                self.add_table(f"fig6{suffix}", table)

    def fig7(self) -> None:
        self.blocks.append(Heading("Fig. 7: shape test (N-MSE per shape)", 2))
        done = self.done
        rows = done[(done["subset_kind"] == "shape") & ~done["is_shore"].astype(bool)]
        if rows.empty:
            self.note(
                "Fig. 7 skipped: no complete per-shape runs; produced by the "
                f"`{PRESET_HINTS['fig7']}` preset."
            )
            return
        for preset, part in rows.groupby("preset", sort=True):
            suffix = "" if rows["preset"].nunique() == 1 else f"_{_safe(str(preset))}"
            shapes = ordered(part["subset_value"], _SHAPE_ORDER)
            models = ordered(part["model"], MODEL_ORDER)
            data = part.assign(
                _x=part["subset_value"], _series=[model_label(m) for m in part["model"]]
            )
            out = plots.plot_nmse_boxes(
                data,
                self.fig_dir / f"fig7_shape{suffix}.png",
                x="_x",
                series="_series",
                x_order=shapes,
                x_labels=shapes,
                series_order=[model_label(m) for m in models],
                panel="inputs",
                panel_order=ordered(part["inputs"], InputStrategy.names()),
                title=f"N-MSE per object shape ({_setting_text(part)})",
                xlabel="Object shape",
            )
            self.figures[f"fig7{suffix}"] = out
            self.blocks.append(
                Figure(
                    out,
                    "Fig. 7 — test N-MSE over seeds for models trained and tested on one shape; "
                    "one panel per input strategy.",
                    describe_runs(part),
                    label=f"fig7{suffix}",
                )
            )
            table = subset_summary_table(
                part,
                "shape",
                "Fig. 7 numbers",
                "Test N-MSE per shape (best per column in **bold**).",
                f"fig7-numbers{suffix}",
                self.ddof,
            )
            if table is not None:
                self.add_table(f"fig7{suffix}", table)

    # ------------------------------------------------------------------ Table III
    def table3(self) -> None:
        self.blocks.append(Heading("Table III: new dataset (Shore hardness)", 2))
        paper = shore_table(self.frame, self.ddof)
        if paper is None:
            self.note(
                f"Table III and Fig. 8 skipped: no complete runs on a Shore-hardness store; "
                f"produced by the `{PRESET_HINTS['table3']}` preset."
            )
            return
        self.add_table("table3", paper)

    # ------------------------------------------------------------------ extras
    def extras(self) -> None:
        self.blocks.append(Heading("Extra analyses", 2))
        headline = self._headline()
        if headline is None:
            self.note(
                "Per-material tables and learning curves skipped: no complete runs on the "
                "whole dataset (presets `table1` / `table2`)."
            )
        else:
            rows, setting = headline
            built = group_metric_tables(rows, self.results_dir, setting, self.ddof)
            if built:
                self.blocks.append(Heading("Errors per material, shape and stiffness", 3))
                for paper in built:
                    self.add_table(paper.table.label, paper)
            else:
                self.note(
                    "Per-material tables skipped: no run of the headline setting has a "
                    "readable groups.csv."
                )
            self.learning_curves(rows, setting)
        softhard = softhard_subset_table(self.frame, self.ddof)
        if softhard is not None:
            self.blocks.append(Heading("Soft / hard training subsets", 3))
            self.add_table("softhard-subsets", softhard)

    def learning_curves(self, rows: pd.DataFrame, setting: str) -> None:
        frames = []
        for row in rows.itertuples(index=False):
            run_dir = resolve_run_dir(row.run_dir, self.results_dir)
            path = None if run_dir is None else run_dir / "logs" / "metrics.csv"
            if path is None or not path.is_file():
                continue
            try:
                log_frame = pd.read_csv(path)
            except (OSError, ValueError):
                continue
            if "epoch" not in log_frame.columns:
                continue
            # Lightning writes train and validation values on separate lines of one epoch.
            cols = [c for c in ("train_loss", "val_nmse") if c in log_frame.columns]
            if not cols:
                continue
            per_epoch = log_frame.groupby("epoch")[cols].first().reset_index()
            frames.append(per_epoch.assign(panel=row.model, series=row.inputs, seed=row.seed))
        if not frames:
            self.note("Learning curves skipped: no logs/metrics.csv found for the headline runs.")
            return
        curves = pd.concat(frames, ignore_index=True)
        for column in ("train_loss", "val_nmse"):
            if column not in curves.columns:
                curves[column] = np.nan
        models = ordered(curves["panel"], MODEL_ORDER)
        out = plots.plot_learning_curves(
            curves,
            self.fig_dir / "learning_curves.png",
            panel_order=models,
            panel_labels=[model_label(m) for m in models],
            series_order=ordered(curves["series"], InputStrategy.names()),
            title=f"Learning curves ({setting.replace('`', '')})",
        )
        self.figures["learning-curves"] = out
        self.blocks.append(Heading("Learning curves", 3))
        self.blocks.append(
            Figure(
                out,
                "Learning curves — validation N-MSE per epoch (solid: mean over seeds, "
                "shaded: min–max) and training loss (dashed) per input strategy.",
                describe_runs(rows, f"{setting}; from each run's logs/metrics.csv"),
                label="learning-curves",
            )
        )

    def failures(self) -> None:
        table = failed_table(self.frame)
        self.blocks.append(Heading("Failed runs", 2))
        if table is None:
            self.blocks.append(Paragraph("Every recorded run completed."))
            return
        self.blocks.append(table)
        self.latex_tables["failed-runs"] = table


# ============================================================================ helpers
def _safe(text: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in text) or "x"


def _model_key(models: pd.Series) -> pd.Series:
    order = {m: i for i, m in enumerate(MODEL_ORDER)}
    return models.map(lambda m: order.get(m, len(order)))


def _series_names(rows: pd.DataFrame) -> list[str]:
    """Model names, with the input strategy appended when several strategies are present."""
    several = rows["inputs"].nunique() > 1
    return [
        f"{model_label(m)} · {i}" if several else model_label(m)
        for m, i in zip(rows["model"], rows["inputs"], strict=True)
    ]


def _setting_text(rows: pd.DataFrame) -> str:
    def values(column: str) -> str:
        order = InputStrategy.names() if column == "inputs" else ("seen", "unseen")
        return "/".join(str(v) for v in ordered(rows[column], order))

    return f"{values('inputs')}, {values('condition')}, {values('sampling')} sampling"


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

    Args:
        results_dir: the results store (``RESULTS/rows/*.json``).
        out_dir: where to write; default ``RESULTS/report``.
        formats: any of ``md``, ``html``, ``tex`` (a list or ``"md,html"``).
        stores: extra GraspStore directories to draw in Fig. 1 (besides the runs' stores).
        ddof: delta degrees of freedom of the std over seeds (1: sample std).
        title: the document title.
        strict: re-raise errors inside a section instead of turning them into a note
            (tests use it; a user wants the rest of the report even if one part breaks).

    Returns:
        A :class:`ReportSummary` with the written files, the numbers of every table and
        the notes about skipped parts.

    Raises:
        FileNotFoundError: ``results_dir`` does not exist.
        ValueError: an unknown format.
    """
    wanted = _normalise_formats(formats)
    results = Path(results_dir)
    frame = load_results(results)
    out = Path(out_dir) if out_dir is not None else results / "report"
    out.mkdir(parents=True, exist_ok=True)
    builder = _Builder(frame, results, out, ddof, [Path(s) for s in stores], strict)

    builder.provenance(title)
    if builder.done.empty:
        builder.note(
            "No complete runs yet: every table and figure below is skipped. Run a grid preset "
            "(`table1`, `table2`, `rolling-window`, `shape-test`, `new-dataset`) first."
        )
    builder.section(
        "Table I", lambda: builder.paper_table_section("random", "I", PRESET_HINTS["table1"])
    )
    builder.section(
        "Table II", lambda: builder.paper_table_section("balanced", "II", PRESET_HINTS["table2"])
    )
    builder.section("Fig. 1", builder.fig1)
    builder.section("Fig. 5", builder.fig5)
    builder.section("Fig. 6", builder.fig6)
    builder.section("Fig. 7", builder.fig7)
    builder.section("Table III", builder.table3)
    builder.section("Fig. 8", builder.fig8)
    builder.section("Extras", builder.extras)
    builder.section("Failed runs", builder.failures)

    summary = ReportSummary(
        results_dir=results,
        out_dir=out,
        figures=dict(builder.figures),
        tables=dict(builder.tables),
        notes=list(builder.notes),
        n_rows=len(frame),
        n_complete=len(builder.done),
        n_failed=int((frame["status"] == STATUS_FAILED).sum()),
    )
    _write_tables(builder, out / "tables")
    if "md" in wanted:
        path = out / _DOC_NAMES["md"]
        path.write_text(render_markdown(builder.blocks, out), encoding="utf-8")
        summary.documents["md"] = path
    if "html" in wanted:
        path = out / _DOC_NAMES["html"]
        path.write_text(render_html(builder.blocks, title), encoding="utf-8")
        summary.documents["html"] = path
    if "tex" in wanted:
        path = out / _DOC_NAMES["tex"]
        path.write_text(render_latex(builder.blocks, out, title), encoding="utf-8")
        summary.documents["tex"] = path
    (out / "report.json").write_text(
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
        + "\n"
    )
    return summary


def _write_tables(builder: _Builder, table_dir: Path) -> None:
    """Each table as a standalone booktabs ``.tex`` and its tidy numbers as ``.csv``."""
    if not builder.latex_tables and not builder.tables:
        return
    table_dir.mkdir(parents=True, exist_ok=True)
    for label, table in builder.latex_tables.items():
        (table_dir / f"{_safe(label)}.tex").write_text(latex_table(table) + "\n", encoding="utf-8")
    for key, cells in builder.tables.items():
        cells.to_csv(table_dir / f"{_safe(key)}.csv", index=False)
