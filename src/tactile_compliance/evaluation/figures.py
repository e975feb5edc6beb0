"""The report's figures: which runs each draws, and its PNG, caption and numbers table.

One function per figure; drawing is :mod:`plots`' job, reading run files :mod:`loading`'s.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from tactile_compliance.data.inputs import InputStrategy
from tactile_compliance.data.normalisation import NormalisationConstants
from tactile_compliance.evaluation import plots
from tactile_compliance.evaluation.loading import (
    complete_rows,
    main_grid,
    read_epoch_metrics,
    read_label_span,
    read_store_samples,
    read_test_predictions,
    resolve_run_dir,
    subset_rows,
)
from tactile_compliance.evaluation.parts import ReportParts, safe_name
from tactile_compliance.evaluation.render import Cell, Heading, Table
from tactile_compliance.evaluation.tables import (
    PRESET_HINTS,
    SETTING_PREFERENCE,
    SHAPE_ORDER,
    describe_runs,
    inputs_label,
    model_label,
    model_order,
    ordered,
    protocol_label,
    subset_summary_table,
    window_label,
)
from tactile_compliance.runs.results import PROTOCOLS

__all__ = ["fig1", "fig5", "fig6", "fig7", "fig8", "headline_runs", "learning_curves"]

#: Fig. 1 draws at most this many stores (a results store normally uses one or two).
MAX_STORES = 4
_FIG5_INPUTS = ("Image", "ALL")


# ============================================================================ Fig. 1
def fig1(
    parts: ReportParts, frame: pd.DataFrame, extra_stores: Sequence[Path], fig_dir: Path
) -> None:
    """Fig. 1: the modulus distribution by shape of every store the runs used (and extras)."""
    parts.blocks.append(Heading("Fig. 1: dataset distribution", 2))
    unique: dict[str, str] = {}  # resolved path -> the first spelling of it
    for store in [
        *complete_rows(frame)["store"].dropna().astype(str),
        *frame["store"].dropna().astype(str),
        *map(str, extra_stores),
    ]:
        unique.setdefault(str(Path(store).expanduser().resolve()), store)
    stores = list(unique.values())
    if not stores:
        parts.note(
            f"Fig. 1 skipped: no store recorded; produced from the store of {PRESET_HINTS['fig1']}."
        )
        return
    for store in stores[:MAX_STORES]:
        loaded = read_store_samples(store)
        if loaded is None:
            parts.note(f"Fig. 1 skipped for `{store}`: the store is not reachable from here.")
            continue
        samples, source = loaded
        constants = (
            NormalisationConstants.for_shore_data()
            if source == "yuan"
            else NormalisationConstants()
        )
        name = Path(store).name or "store"
        out = fig_dir / f"fig1_dataset_{safe_name(name)}.png"
        plots.plot_dataset_distribution(
            samples, out, constants, title=f"Dataset distribution: {name} ({source})"
        )
        lo, hi = constants.label_range_pa
        parts.add_figure(
            f"fig1-{safe_name(name)}",
            out,
            f"Fig. 1 — normalised Young's modulus of `{name}` split by object shape.",
            f"all {len(samples)} samples of store `{store}` (source {source}, before "
            f"the training filters); modulus normalised as log10 min-max over "
            f"[1e{math.log10(lo):.0f}, 1e{math.log10(hi):.0f}] Pa; blue dashed line: "
            "the gel's 0.275 MPa.",
        )
    if len(stores) > MAX_STORES:
        parts.note(f"Fig. 1 drawn for the first {MAX_STORES} of {len(stores)} stores.")


# ============================================================================ Fig. 5 / 8
def headline_runs(frame: pd.DataFrame) -> tuple[pd.DataFrame, str] | None:
    """The runs of the preferred setting and its name; within it, the preset with the most
    runs (ties: the first by name), so a quick preset never decides what Fig. 5 shows."""
    rows = main_grid(frame)
    for sampling, protocol in SETTING_PREFERENCE:
        part = rows[(rows["sampling"] == sampling) & (rows["protocol"] == protocol)]
        if part.empty:
            continue
        counts = part["preset"].value_counts()
        preset = sorted(counts[counts == counts.max()].index)[0]
        part = part[part["preset"] == preset]
        return (
            part,
            f"preset `{preset}`, {sampling} sampling, {protocol_label(protocol)}",
        )
    return None


def _label_span(run_dir: Path | None, shore: bool) -> float:
    """Label span in decades for the N-MSE band: the run's config, else the data's default."""
    span = read_label_span(run_dir)
    if span is not None:
        return span
    constants = NormalisationConstants.for_shore_data() if shore else NormalisationConstants()
    return constants.label_log10_span


def _setting_rank(row: Any) -> int:
    key = (row.sampling, row.protocol)
    return SETTING_PREFERENCE.index(key) if key in SETTING_PREFERENCE else len(SETTING_PREFERENCE)


def _best_panels(
    rows: pd.DataFrame,
    inputs: Sequence[str],
    preferred: pd.DataFrame | None,
    shore: bool,
    results_dir: Path,
) -> tuple[list[plots.ScatterPanel | str], list[list[Cell]], pd.DataFrame]:
    """Per input x model, the lowest-N-MSE run that has predictions: panel, table row, numbers.

    Ranked: runs in ``preferred`` first, then by setting preference, then by N-MSE.
    """
    panels: list[plots.ScatterPanel | str] = []
    body: list[list[Cell]] = []
    tidy: list[dict[str, Any]] = []
    models = ordered(rows["model"], model_order())
    for inp in inputs:
        for model in models:
            cand = rows[(rows["model"] == model) & (rows["inputs"] == inp)]
            cand = cand.assign(
                sel_pref=[
                    0 if preferred is not None and key in set(preferred["key"]) else 1
                    for key in cand["key"]
                ],
                sel_rank=[_setting_rank(r) for r in cand.itertuples(index=False)],
                sel_nmse=pd.to_numeric(
                    cand["test_nmse"] if "test_nmse" in cand.columns else np.nan,
                    errors="coerce",
                ),
            ).dropna(subset=["sel_nmse"])
            cand = cand.sort_values(
                ["sel_pref", "sel_rank", "preset", "sampling", "protocol", "sel_nmse"]
            )
            chosen = None
            for row in cand.itertuples(index=False):
                predictions = read_test_predictions(resolve_run_dir(row.run_dir, results_dir))
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
                & (cand["protocol"] == row.protocol)
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
                span_decades=_label_span(resolve_run_dir(row.run_dir, results_dir), shore),
                subtitle=f"{row.sampling}, {protocol_label(row.protocol)}, seed {row.seed}",
            )
            panels.append(panel)
            inside = panel.inside
            body.append(
                [
                    Cell(text=model_label(model)),
                    Cell(text=inputs_label(inp)),
                    Cell(text=f"{row.preset}: {row.sampling}, {protocol_label(row.protocol)}"),
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
                    "protocol": row.protocol,
                    "seed": row.seed,
                    "nmse": float(row.sel_nmse),
                    "inside_band": inside,
                    "n": int(panel.true_pa.size),
                    "run_dir": row.run_dir,
                }
            )
    return panels, body, pd.DataFrame(tidy)


def _add_runs_table(
    parts: ReportParts,
    key: str,
    body: list[list[Cell]],
    tidy: pd.DataFrame,
    caption: str,
    rows: pd.DataFrame,
) -> None:
    """The table under Fig. 5 / 8 (``key``): which run each panel shows and how it ranks."""
    parts.tables[key] = tidy
    table = Table(
        title=f"Fig. {key.removeprefix('fig')} runs",
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
        label=f"{key}-runs",
    )
    parts.blocks.append(table)


def fig5(parts: ReportParts, frame: pd.DataFrame, results_dir: Path, fig_dir: Path) -> None:
    """Fig. 5: predicted vs true modulus per material, Image and ALL of each model."""
    parts.blocks.append(Heading("Fig. 5: material test (predicted vs true modulus)", 2))
    rows = main_grid(frame)
    rows = rows[rows["inputs"].isin(_FIG5_INPUTS)]
    if rows.empty:
        parts.note(
            "Fig. 5 skipped: no complete Image/ALL runs on the whole dataset; produced by "
            f"{PRESET_HINTS['fig5']}."
        )
        return
    headline = headline_runs(frame)
    panels, body, tidy = _best_panels(
        rows,
        [i for i in _FIG5_INPUTS if i in set(rows["inputs"])],
        headline[0] if headline else None,
        False,
        results_dir,
    )
    if tidy.empty:
        parts.note(
            "Fig. 5 skipped: none of the candidate runs has a readable predictions.csv "
            "(run directories missing or moved)."
        )
        return
    out = plots.plot_prediction_panels(
        panels,
        fig_dir / "fig5_material_scatter.png",
        ncols=len(ordered(rows["model"], model_order())),
        suptitle="Predicted vs true Young's modulus per material (lowest-N-MSE seed)",
    )
    used = rows[rows["run_dir"].isin(tidy["run_dir"])]
    parts.add_figure(
        "fig5",
        out,
        "Fig. 5 — predicted vs true Young's modulus per material, Image (top) and ALL "
        "(bottom) for each model. Red: y = x; blue: the gel's 0.275 MPa; grey: the "
        "N-MSE band y = x·f^±1 with f = 10^(9·√N-MSE); a point is inside when its squared "
        "normalised error is at most the run's N-MSE.",
        describe_runs(
            used,
            "the seed with the lowest test N-MSE of the preferred setting "
            "(balanced + seen grasp-grouped, else random + seen grasp-grouped, then the "
            "per-sample and unseen splits); see the table below",
        ),
    )
    caption = "The run behind each panel and the share of points in its band."
    _add_runs_table(parts, "fig5", body, tidy, caption, used)


def fig8(parts: ReportParts, frame: pd.DataFrame, results_dir: Path, fig_dir: Path) -> None:
    """Fig. 8: predicted vs true modulus on the Shore-hardness data (Image input)."""
    rows = subset_rows(frame, "none", shore=True)
    if rows.empty:
        return  # Table III's note already says what is missing
    inputs = (
        ["Image"]
        if "Image" in set(rows["inputs"])
        else ordered(rows["inputs"], InputStrategy.names())[:1]
    )
    panels, body, tidy = _best_panels(rows, inputs, None, True, results_dir)
    if tidy.empty:
        parts.note("Fig. 8 skipped: no Shore-hardness run has a readable predictions.csv.")
        return
    out = plots.plot_prediction_panels(
        panels,
        fig_dir / "fig8_new_dataset_scatter.png",
        ncols=len(panels),
        suptitle="Shore-hardness data: predicted vs true Young's modulus (lowest-N-MSE seed)",
    )
    used = rows[rows["run_dir"].isin(tidy["run_dir"])]
    parts.add_figure(
        "fig8",
        out,
        f"Fig. 8 — Shore-hardness data, {inputs[0]} input: predicted vs true modulus per "
        "material; band as in Fig. 5 on this data's label range.",
        describe_runs(used, "seed with the lowest test N-MSE per model"),
    )
    _add_runs_table(parts, "fig8", body, tidy, "The run behind each panel.", used)


# ============================================================================ Fig. 6 / 7
@dataclass(frozen=True)
class _BoxLayout:
    """How one subset figure lays out its boxes: ``data`` has the ``_x`` and ``_series``."""

    data: pd.DataFrame
    x_order: list[Any]
    x_labels: list[str]
    series_order: list[str]
    panel: str | None = None
    panel_order: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class _SubsetFigure:
    """What tells Fig. 6 (rolling window) and Fig. 7 (shape) apart; the rest is shared."""

    key: str  # figure id, PRESET_HINTS key, stem of the table ids
    name: str
    heading: str
    kind: str  # the rows' subset_kind
    missing: str  # what the "skipped" note says there is none of
    file_stem: str
    title: str
    xlabel: str
    caption: str
    table_caption: str
    layout: Callable[[pd.DataFrame], _BoxLayout]


def _model_key(models: pd.Series) -> pd.Series:
    order = {m: i for i, m in enumerate(model_order())}
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
        if column == "protocol":
            return "/".join(protocol_label(v) for v in ordered(rows[column], PROTOCOLS))
        order = InputStrategy.names() if column == "inputs" else ()
        return "/".join(str(v) for v in ordered(rows[column], order))

    return f"{values('inputs')}, {values('protocol')}, {values('sampling')} sampling"


def _window_layout(part: pd.DataFrame) -> _BoxLayout:
    """Windows along x in modulus order; one series per model (and input, if several)."""
    data = part.assign(_x=part["subset_value"].astype(int), _series=_series_names(part))
    windows = sorted(set(data["_x"]))
    series = list(dict.fromkeys(_series_names(part.sort_values("model", key=_model_key))))
    return _BoxLayout(data, windows, [window_label(k) for k in windows], series)


def _shape_layout(part: pd.DataFrame) -> _BoxLayout:
    """Shapes along x in paper order; one series per model; one panel per input strategy."""
    shapes = ordered(part["subset_value"], SHAPE_ORDER)
    models = ordered(part["model"], model_order())
    data = part.assign(_x=part["subset_value"], _series=[model_label(m) for m in part["model"]])
    return _BoxLayout(
        data,
        shapes,
        shapes,
        [model_label(m) for m in models],
        panel="inputs",
        panel_order=ordered(part["inputs"], InputStrategy.names()),
    )


_FIG6 = _SubsetFigure(
    key="fig6",
    name="Fig. 6",
    heading="Fig. 6: rolling window (N-MSE per modulus range)",
    kind="window",
    missing="no complete rolling-window runs (subset 0-6)",
    file_stem="fig6_rolling_window",
    title="N-MSE per Young's modulus range",
    xlabel="Young's modulus range of the subset (Pa)",
    caption="Fig. 6 — test N-MSE over seeds for the 7 rolling windows (three decades each, "
    "undersampled to equal size). Boxes: quartiles and median; whiskers: 1.5 IQR; "
    "dots: single runs.",
    table_caption="Test N-MSE per rolling window (best per column in **bold**).",
    layout=_window_layout,
)
_FIG7 = _SubsetFigure(
    key="fig7",
    name="Fig. 7",
    heading="Fig. 7: shape test (N-MSE per shape)",
    kind="shape",
    missing="no complete per-shape runs",
    file_stem="fig7_shape",
    title="N-MSE per object shape",
    xlabel="Object shape",
    caption="Fig. 7 — test N-MSE over seeds for models trained and tested on one shape; "
    "one panel per input strategy.",
    table_caption="Test N-MSE per shape (best per column in **bold**).",
    layout=_shape_layout,
)


def _subset_figure(
    parts: ReportParts, frame: pd.DataFrame, spec: _SubsetFigure, fig_dir: Path, ddof: int
) -> None:
    """N-MSE boxes over seeds per subset, one figure and numbers table per preset."""
    parts.blocks.append(Heading(spec.heading, 2))
    rows = subset_rows(frame, spec.kind)
    if rows.empty:
        parts.note(
            f"{spec.name} skipped: {spec.missing}; produced by the "
            f"`{PRESET_HINTS[spec.key]}` preset."
        )
        return
    for preset, part in rows.groupby("preset", sort=True):
        # Presets are never pooled; the suffix appears only when there is more than one.
        suffix = "" if rows["preset"].nunique() == 1 else f"_{safe_name(str(preset))}"
        layout = spec.layout(part)
        out = plots.plot_nmse_boxes(
            layout.data,
            fig_dir / f"{spec.file_stem}{suffix}.png",
            x="_x",
            series="_series",
            x_order=layout.x_order,
            x_labels=layout.x_labels,
            series_order=layout.series_order,
            panel=layout.panel,
            panel_order=layout.panel_order,
            title=f"{spec.title} ({_setting_text(part)})",
            xlabel=spec.xlabel,
        )
        parts.add_figure(f"{spec.key}{suffix}", out, spec.caption, describe_runs(part))
        table = subset_summary_table(
            part,
            spec.kind,
            f"{spec.name} numbers",
            spec.table_caption,
            f"{spec.key}-numbers{suffix}",
            ddof,
        )
        if table is not None:
            parts.add_table(f"{spec.key}{suffix}", table)


def fig6(parts: ReportParts, frame: pd.DataFrame, fig_dir: Path, ddof: int) -> None:
    """Fig. 6: N-MSE over seeds per rolling window of the modulus range."""
    _subset_figure(parts, frame, _FIG6, fig_dir, ddof)


def fig7(parts: ReportParts, frame: pd.DataFrame, fig_dir: Path, ddof: int) -> None:
    """Fig. 7: N-MSE over seeds per object shape, one panel per input strategy."""
    _subset_figure(parts, frame, _FIG7, fig_dir, ddof)


# ============================================================================ extras
def learning_curves(
    parts: ReportParts, rows: pd.DataFrame, setting: str, results_dir: Path, fig_dir: Path
) -> None:
    """Validation N-MSE and training loss per epoch of ``rows`` (one panel per model)."""
    frames = []
    for row in rows.itertuples(index=False):
        per_epoch = read_epoch_metrics(resolve_run_dir(row.run_dir, results_dir))
        if per_epoch is not None:
            frames.append(per_epoch.assign(panel=row.model, series=row.inputs, seed=row.seed))
    if not frames:
        parts.note("Learning curves skipped: no logs/metrics.csv found for the headline runs.")
        return
    curves = pd.concat(frames, ignore_index=True)
    for column in ("train_loss", "val_nmse"):
        if column not in curves.columns:
            curves[column] = np.nan
    models = ordered(curves["panel"], model_order())
    out = plots.plot_learning_curves(
        curves,
        fig_dir / "learning_curves.png",
        panel_order=models,
        panel_labels=[model_label(m) for m in models],
        series_order=ordered(curves["series"], InputStrategy.names()),
        title=f"Learning curves ({setting.replace('`', '')})",
    )
    parts.blocks.append(Heading("Learning curves", 3))
    parts.add_figure(
        "learning-curves",
        out,
        "Learning curves — validation N-MSE per epoch (solid: mean over seeds, "
        "shaded: min–max) and training loss (dashed) per input strategy.",
        describe_runs(rows, f"{setting}; from each run's logs/metrics.csv"),
    )
