"""Tables of the report from the results frame, also as tidy numbers (``cells``): only
complete runs; a cell is ``mean ± std`` over its runs (one per seed, ``ddof=1``, the mean
alone for one run), never pooling presets or stores. See docs/reporting.md, "How the
numbers are made"."""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from tactile_compliance.data.inputs import InputStrategy
from tactile_compliance.data.splits import N_ROLLING_WINDOWS, rolling_windows
from tactile_compliance.evaluation.loading import (
    main_grid,
    read_groups,
    resolve_run_dir,
    store_header,
    subset_rows,
)
from tactile_compliance.evaluation.render import Cell, Table
from tactile_compliance.runs.metrics import REFERENCE_NAMES
from tactile_compliance.runs.results import (
    PROTOCOL_LABELS,
    PROTOCOLS,
    STATUS_COMPLETE,
    STATUS_FAILED,
)

__all__ = [
    "PRESET_HINTS",
    "SETTING_PREFERENCE",
    "SHAPE_ORDER",
    "STD_DDOF",
    "PaperTable",
    "describe_runs",
    "describe_weights",
    "failed_table",
    "group_metric_tables",
    "model_label",
    "model_order",
    "ordered",
    "paper_tables",
    "protocol_label",
    "shore_table",
    "softhard_subset_table",
    "subset_summary_table",
    "summarise",
    "window_label",
]

#: References that depend on the input strategy: one table row per strategy.
_PER_STRATEGY_REFERENCES = frozenset({"scalar_gbr"})
#: Row labels of the reference predictors (``ref_{name}_*`` columns of the results rows).
REFERENCE_LABELS: dict[str, str] = {
    "median": "Median",
    "analytical": "Analytical",
    "scalar_gbr": "Scalar GBR",
}
#: Paper order of the object shapes (Fig. 7 and its companion table).
SHAPE_ORDER: tuple[str, ...] = ("Sphere", "Cylinder", "Rectangular", "Irregular")
#: The (sampling, protocol) Fig. 5 and the extras prefer: the paper's Fig. 5 is balanced +
#: seen; of the two seen splits the grasp-grouped one comes first, because a scatter of a
#: per-sample split shows partly memorised grasps (the paper's protocol is next in line).
SETTING_PREFERENCE: tuple[tuple[str, str], ...] = (
    ("balanced", "seen_grasp"),
    ("random", "seen_grasp"),
    ("balanced", "seen_per_sample"),
    ("random", "seen_per_sample"),
    ("balanced", "unseen"),
    ("random", "unseen"),
)
#: Sample standard deviation over seeds (pandas' convention); numpy's default would be 0.
STD_DDOF = 1
#: Which grid preset produces which part (named in the "skipped" notes).
PRESET_HINTS: dict[str, str] = {
    "table1": "table1",
    "table2": "table2",
    "table3": "new-dataset",
    "fig1": "any preset (it reads the store of the recorded runs)",
    "fig5": "table2 (balanced, seen grasp-grouped; falls back to table1)",
    "fig6": "rolling-window",
    "fig7": "shape-test",
    "fig8": "new-dataset",
}
METRIC_LABELS: dict[str, str] = {
    "log10_accuracy": "log₁₀ accuracy",
    "nmse": "N-MSE",
    "r2": "R²",
    "mae_decades": "MAE (decades)",
    "within_half_decade": "within ½ decade",
}
_LATEX_METRIC = {
    "log10_accuracy": r"$\log_{10}$ accuracy",
    "nmse": "N-MSE",
    "r2": "$R^2$",
}
#: Metrics where larger is better (for bolding); the rest are errors.
HIGHER_IS_BETTER = frozenset({"log10_accuracy", "r2", "within_half_decade"})


# ============================================================================ helpers
def _display_names() -> dict[str, str]:
    # Imported on use: the registry loads torch and the networks, which the report's
    # modules otherwise never need (the names and order are the model classes' own).
    from tactile_compliance.models import model_display_names

    return model_display_names()


def model_order() -> tuple[str, ...]:
    """Registered model names in display order (the paper's: Top10NN, VGG-LSTM, Res-Tf)."""
    return tuple(_display_names())


def model_label(name: Any) -> str:
    """The display name of a model (``VGG-LSTM`` for ``vgg_lstm``); unknown names as given."""
    return _display_names().get(str(name), str(name))


def inputs_label(inputs: Any) -> str:
    """An input strategy as a table shows it: the paper's four by name, the others marked
    ``FW (beyond the paper)``, so a reader comparing with Table I sees which rows it has."""
    try:
        strategy = InputStrategy.parse(str(inputs))
    except ValueError:
        return str(inputs)
    return strategy.value if strategy.in_paper else f"{strategy.value} (beyond the paper)"


def protocol_label(protocol: Any) -> str:
    """``Seen, grasp-grouped`` for ``seen_grasp``: which split a column or run used."""
    return PROTOCOL_LABELS.get(str(protocol), str(protocol))


def ordered(values: Iterable[Any], order: Sequence[Any]) -> list[Any]:
    """Distinct ``values``: those in ``order`` first (in that order), the rest sorted."""
    distinct = list(dict.fromkeys(v for v in values if v is not None))
    known = [v for v in order if v in distinct]
    return known + sorted((v for v in distinct if v not in order), key=str)


def _stats(values: Sequence[float], ddof: int) -> tuple[float, float, int]:
    """Mean, std and count of numbers without NaN."""
    arr = np.asarray(values, dtype=float)
    n = int(arr.size)
    if n == 0:
        return math.nan, math.nan, 0
    mean = float(arr.mean())
    std = float(arr.std(ddof=ddof)) if n > ddof else math.nan
    return mean, std, n


def summarise(
    frame: pd.DataFrame, by: Sequence[str], metrics: Sequence[str], ddof: int = STD_DDOF
) -> pd.DataFrame:
    """Tidy mean/std/n per group of ``by`` and metric column; ``seeds`` lists the seeds used."""
    out: list[dict[str, Any]] = []
    if frame.empty:
        return pd.DataFrame(columns=[*by, "metric", "mean", "std", "n", "seeds"])
    for keys, part in frame.groupby(list(by), sort=False, dropna=False):  # keys: a tuple
        for metric in metrics:
            if metric not in part.columns:
                continue
            values = pd.to_numeric(part[metric], errors="coerce")
            used = part.loc[values.notna()]
            mean, std, n = _stats(values.dropna().tolist(), ddof)
            out.append(
                {
                    **dict(zip(by, keys, strict=True)),
                    "metric": metric.removeprefix("test_"),
                    "mean": mean,
                    "std": std,
                    "n": n,
                    "seeds": sorted(int(s) for s in used["seed"].dropna().tolist()),
                }
            )
    return pd.DataFrame(out)


def _seed_text(seeds: Sequence[int]) -> str:
    seeds = sorted(set(seeds))
    if not seeds:
        return "none"
    if seeds == list(range(seeds[0], seeds[-1] + 1)) and len(seeds) > 2:
        return f"{seeds[0]}–{seeds[-1]}"
    return ", ".join(str(s) for s in seeds)


def describe_weights(frame: pd.DataFrame) -> str:
    """Backbone weights per model, e.g. "VGG-LSTM: random init (no ImageNet weights)"."""
    if "backbone_weights" not in frame.columns or frame.empty:
        return "not recorded"
    parts = []
    for model in ordered(frame["model"], model_order()):
        rows = frame[frame["model"] == model]
        weights = sorted({str(w) for w in rows["backbone_weights"].dropna()}) or ["not recorded"]
        text = "/".join(
            "random init (no ImageNet weights)" if w.lower() in ("none", "random") else w
            for w in weights
        )
        if (
            "freeze_backbone" in rows.columns
            and rows["freeze_backbone"].fillna(False).astype(bool).any()
        ):
            text += ", frozen backbone"
        parts.append(f"{model_label(model)}: {text}")
    return "; ".join(parts)


def describe_runs(frame: pd.DataFrame, extra: str = "") -> str:
    """One sentence of provenance for a set of runs: preset(s), store(s), seeds, weights."""
    if frame.empty:
        return "no runs"
    presets = ", ".join(f"`{p}`" for p in sorted(set(frame["preset"])) if p) or "(no preset)"
    stores = [
        f"`{store}` (source {getattr(store_header(store), 'source', 'header not reachable')})"
        for store in dict.fromkeys(frame["store"].tolist())
    ]
    seeds = sorted(int(s) for s in frame["seed"].dropna().tolist())
    sizes = ""
    if "image_size" in frame.columns:
        values = {
            "x".join(str(int(v)) for v in s)
            for s in frame["image_size"].dropna().tolist()
            if isinstance(s, (list, tuple))
        }
        if values:
            sizes = f"; image size {', '.join(sorted(values))} px"
    text = (
        f"preset {presets}; store {', '.join(stores) or 'unknown'}; {len(frame)} complete runs, "
        f"seeds {_seed_text(seeds)}; backbone weights: {describe_weights(frame)}{sizes}"
    )
    return text + (f"; {extra}" if extra else "")


def _ddof_text(ddof: int) -> str:
    return (
        f"mean ± std over seeds (std with ddof={ddof}; one run shows the mean alone); "
        "metrics on each run's test split, best checkpoint"
    )


def _best_mask(values: Sequence[float], metric: str, digits: int) -> list[bool]:
    """Bold every value tied (at the printed precision) with the best one."""
    rounded = [None if math.isnan(v) else round(v, digits) for v in values]
    present = [v for v in rounded if v is not None]
    if not present:
        return [False] * len(values)
    best = max(present) if metric in HIGHER_IS_BETTER else min(present)
    return [v is not None and v == best for v in rounded]


def _label_for(text: str) -> str:
    return "".join(ch if ch.isalnum() else "-" for ch in text).strip("-").lower()


def _settings(stats: pd.DataFrame, keys: list[str]) -> list[dict[str, Any]]:
    """The distinct run settings (``keys`` of ``stats``) in table order: (preset,) model,
    inputs, object condition, sampling."""
    settings = stats[keys].drop_duplicates()
    models = ordered(settings["model"], model_order())
    settings = settings.assign(
        _m=[models.index(m) for m in settings["model"]],
        _p=[PROTOCOLS.index(p) if p in PROTOCOLS else len(PROTOCOLS) for p in settings["protocol"]],
    ).sort_values([*(["preset"] if "preset" in keys else []), "_m", "inputs", "_p", "sampling"])
    return [dict(zip(keys, s, strict=True)) for s in settings[keys].itertuples(index=False)]


def _model_inputs(frame: pd.DataFrame, inputs: Sequence[str]) -> list[tuple[Any, str]]:
    """The (model, input strategy) pairs with rows in ``frame``, models in display order."""
    return [
        (m, i)
        for m in ordered(frame["model"], model_order())
        for i in inputs
        if ((frame["model"] == m) & (frame["inputs"] == i)).any()
    ]


def _setting_cells(setting: Mapping[str, Any]) -> list[Cell]:
    """The Model, Input and Split cells of a row that stands for one run setting."""
    return [
        Cell(text=model_label(setting["model"])),
        Cell(text=inputs_label(setting["inputs"])),
        Cell(text=f"{protocol_label(setting['protocol'])}, {setting['sampling']}"),
    ]


@dataclass
class _Pivot:
    """A table body's number cells row by row, the runs behind each row, the tidy rows."""

    cells: list[list[Cell]]
    runs: list[list[int]]
    tidy: list[dict[str, Any]]


def _pivot(
    stats: pd.DataFrame,
    rows: Sequence[Mapping[str, Any]],
    columns: Sequence[Mapping[str, Any]],
    *,
    head: Mapping[str, Any],
    digits: int,
    bold: bool,
) -> _Pivot:
    """Lay :func:`summarise` records out as rows x columns: the one layout of every table.

    A cell is the record matching its row's and column's fields (``–`` if none); a column
    may carry extra fields for the tidy rows only. ``bold``: each column's best is bold.
    """
    fields = [c for c in stats.columns if c not in ("mean", "std", "n", "seeds")]
    lookup = {tuple(getattr(r, f) for f in fields): r for r in stats.itertuples(index=False)}
    found = [
        [lookup.get(tuple({**row, **column}[f] for f in fields)) for column in columns]
        for row in rows
    ]
    best = [
        _best_mask(
            [math.nan if line[j] is None else line[j].mean for line in found],
            column["metric"],
            digits,
        )
        if bold
        else [False] * len(rows)
        for j, column in enumerate(columns)
    ]
    out = _Pivot([], [], [])
    for i, (row, line) in enumerate(zip(rows, found, strict=True)):
        cells: list[Cell] = []
        runs: list[int] = []
        for j, (column, rec) in enumerate(zip(columns, line, strict=True)):
            if rec is None:
                cells.append(Cell(text="–"))
                continue
            cells.append(Cell(rec.mean, rec.std, bold=best[j][i], digits=digits))
            runs.append(rec.n)
            flag = {"bold": best[j][i]} if bold else {}
            numbers = {"mean": rec.mean, "std": rec.std, "n": rec.n, "seeds": rec.seeds}
            out.tidy.append({**head, **row, **column, **numbers, **flag})
        out.cells.append(cells)
        out.runs.append(runs)
    return out


# ============================================================================ Tables I / II
@dataclass
class PaperTable:
    """A rendered table plus the tidy numbers behind it."""

    table: Table
    cells: pd.DataFrame


#: The metrics of Tables I and II (results columns ``test_NAME``, ``ref_REF_NAME``).
_PAPER_METRICS = ("log10_accuracy", "nmse")


def _reference_stats(
    lines: Sequence[tuple[str, str | None, pd.DataFrame]], protocols: Sequence[str], ddof: int
) -> pd.DataFrame:
    """:func:`summarise` records of the reference rows (``model`` ``ref_NAME``), averaged
    per seed first (docs/reporting.md, "How the numbers are made")."""
    records = []
    for name, inputs, rows in lines:
        for protocol in protocols:
            for metric in _PAPER_METRICS:
                column = f"ref_{name}_{metric}"
                if column not in rows.columns:
                    continue
                part = rows[rows["protocol"] == protocol]
                values = part.assign(_v=pd.to_numeric(part[column], errors="coerce"))
                per_seed = values.dropna(subset=["_v"]).groupby("seed")["_v"].mean()
                mean, std, n = _stats(per_seed.tolist(), ddof)
                if not n:
                    continue  # shown as "–"
                seeds = sorted(int(s) for s in per_seed.index)
                records.append((f"ref_{name}", inputs, protocol, metric, mean, std, n, seeds))
    columns = ["model", "inputs", "protocol", "metric", "mean", "std", "n", "seeds"]
    # dtype=object keeps a reference without inputs (median, analytical) as None, the key
    # its row is looked up by; pandas would turn it into NaN beside string inputs.
    return pd.DataFrame(records, columns=columns, dtype=object)


def _reference_lines(
    part: pd.DataFrame, inputs: Sequence[str]
) -> list[tuple[str, str | None, pd.DataFrame]]:
    """The reference rows of a paper table: (name, input strategy or None, its runs); only
    the scalar reference has one row per input strategy."""
    lines: list[tuple[str, str | None, pd.DataFrame]] = []
    for name in REFERENCE_NAMES:
        # Only references some run recorded (older runs have no scalar reference).
        columns = [c for c in part.columns if c.startswith(f"ref_{name}_")]
        if not columns or not part[columns].notna().any(axis=None):
            continue
        if name in _PER_STRATEGY_REFERENCES:
            lines += [(name, inp, part[part["inputs"] == inp]) for inp in inputs]
        else:
            lines.append((name, None, part))
    return lines


def paper_tables(
    frame: pd.DataFrame, sampling: str, number: str, ddof: int = STD_DDOF, digits: int = 4
) -> list[PaperTable]:
    """Table I (``sampling="random"``) or II (``"balanced"``): one table per (preset, store).

    Layout: docs/reporting.md, "Tables I and II". The tidy cells carry ``protocol`` (the
    column group) and the ``condition`` / ``grouping`` it stands for.
    """
    rows = main_grid(frame)
    rows = rows[rows["sampling"] == sampling]
    out: list[PaperTable] = []
    if rows.empty:
        return out
    groups = list(rows.groupby(["preset", "store"], sort=True, dropna=False))
    for (preset, store), part in groups:
        metrics = [f"test_{m}" for m in _PAPER_METRICS]
        stats = summarise(part, ["model", "inputs", "protocol"], metrics, ddof)
        protocols = ordered(part["protocol"], PROTOCOLS)
        # The split settings each column group stands for (in the tidy cells).
        split_fields = {
            p: {"protocol": p, "condition": r.condition, "grouping": r.grouping}
            for p, r in part.drop_duplicates("protocol").set_index("protocol").iterrows()
        }
        models = ordered(part["model"], model_order())
        inputs = ordered(part["inputs"], InputStrategy.names())
        body_keys = [(m, i) for m in models for i in inputs]
        columns_fields = [
            {**split_fields[protocol], "metric": metric}
            for protocol in protocols
            for metric in _PAPER_METRICS
        ]
        head = {"table": number, "preset": preset, "store": store}
        pivot = _pivot(
            stats,
            [{"model": m, "inputs": i} for m, i in body_keys],
            columns_fields,
            head=head,
            digits=digits,
            bold=True,
        )
        # References are never bold (they are floors, not contenders), yet their tidy
        # rows carry ``bold`` like the models'.
        references = _reference_lines(part, inputs)
        ref_pivot = _pivot(
            _reference_stats(references, protocols, ddof),
            [{"model": f"ref_{name}", "inputs": inp} for name, inp, _ in references],
            columns_fields,
            head=head,
            digits=digits,
            bold=False,
        )
        metric_columns = [m for _ in protocols for m in _PAPER_METRICS]
        columns = ["Model", "Input", *[METRIC_LABELS[m] for m in metric_columns], "runs"]
        latex_columns = ["Model", "Input", *[_LATEX_METRIC[m] for m in metric_columns], "runs"]
        group_header = [("", 2), *[(protocol_label(p), 2) for p in protocols], ("", 1)]
        labels = [(model_label(m), inputs_label(i)) for m, i in body_keys] + [
            (f"{REFERENCE_LABELS[name]} (reference)", inp or "–") for name, inp, _ in references
        ]
        body = [
            [Cell(text=label), Cell(text=inp), *cells, Cell(text=_runs_text(runs))]
            for (label, inp), cells, runs in zip(
                labels, pivot.cells + ref_pivot.cells, pivot.runs + ref_pivot.runs, strict=True
            )
        ]
        # A rule after each model, and between the models and the references (if any).
        rules = {i for i in range(len(body_keys) - 1) if body_keys[i][0] != body_keys[i + 1][0]}
        rules.add(len(body_keys) - 1)
        tidy = pivot.tidy + [{**row, "bold": False} for row in ref_pivot.tidy]
        title = f"Table {number} — preset {preset or '(none)'}"
        if len(groups) > 1 and len({p for (p, _), _ in groups}) < len(groups):
            title += f", store {Path(str(store)).name}"
        caption = (
            f"Overall performance of all models with {sampling} sampling"
            f"{' and the Balanced strategy' if sampling == 'balanced' else ''}: "
            "log₁₀ accuracy (higher is better) and N-MSE (lower is better) per input strategy; "
            "best model per column in **bold**. "
            + _protocol_caption(protocols)
            + _reference_caption({name for name, _, _ in references})
        )
        has_refs = bool(references)
        provenance = describe_runs(
            part, _ddof_text(ddof) + ("; references: one value per seed" if has_refs else "")
        )
        table = Table(
            title=title,
            columns=columns,
            rows=body,
            groups=group_header,
            rules_after=rules,
            caption=caption,
            provenance=provenance,
            label=_label_for(f"table{number}-{preset}-{Path(str(store)).name}"),
            latex_columns=latex_columns,
        )
        out.append(PaperTable(table, pd.DataFrame(tidy)))
    return out


#: What each column group's split is, for the captions of Tables I and II.
_PROTOCOL_TEXT = {
    "seen_per_sample": (
        "Seen, per-sample (paper) = the paper's protocol: samples split at random, so the "
        "other finger and the time-shifted copies of most test grasps are in training"
    ),
    "seen_grasp": (
        "Seen, grasp-grouped = the same objects, each grasp's samples in one split "
        "(no grasp shared between train and test)"
    ),
    "unseen": "UnSeen = split by object (test objects never in training)",
}


def _protocol_caption(protocols: Sequence[str]) -> str:
    """The column groups in words, and the object conditions this table has no runs of."""
    present = [_PROTOCOL_TEXT.get(p, protocol_label(p)) for p in protocols]
    text = "Columns: " + "; ".join(present) + "."
    absent = [protocol_label(p) for p in PROTOCOLS if p not in protocols]
    if absent:
        text += f" No runs of {', '.join(absent)} in this preset (column group left out)."
    return text


def _reference_caption(names: set[str]) -> str:
    if not names:
        return ""
    parts = {
        "median": "the training median",
        "analytical": "the sample's analytical estimate",
        "scalar_gbr": (
            "Scalar GBR: gradient-boosted trees on the strategy's scalar inputs only (F; F, W; "
            "F, W, log₁₀ E) fitted on the training split, which shows what the images add "
            "(none for Image: no scalar inputs)"
        ),
    }
    listed = "; ".join(parts[name] for name in REFERENCE_NAMES if name in names)
    return f" Reference predictors on the same test splits: {listed}."


def _runs_text(runs: Sequence[int]) -> str:
    if not runs:
        return "0"
    lo, hi = min(runs), max(runs)
    return str(lo) if lo == hi else f"{lo}–{hi}"


# ============================================================================ Table III
def shore_table(frame: pd.DataFrame, ddof: int = STD_DDOF, digits: int = 4) -> PaperTable | None:
    """Table III: N-MSE and R² per model on the Shore-hardness data (mean ± std over seeds)."""
    rows = subset_rows(frame, "none", shore=True)
    if rows.empty:
        return None
    metrics = ("test_nmse", "test_r2")
    keys = ["preset", "store", "model", "inputs", "protocol", "sampling"]
    stats = summarise(rows, keys, metrics, ddof)
    setting_rows = _settings(stats, keys)
    show_preset = stats["preset"].nunique() > 1 or stats["store"].nunique() > 1
    preset_column = ["Preset"] if show_preset else []
    columns = [*preset_column, "Model", "Input", "Split", "N-MSE", "R²", "runs"]
    latex_columns = [*preset_column, "Model", "Input", "Split", "N-MSE", "$R^2$", "runs"]
    pivot = _pivot(
        stats,
        setting_rows,
        [{"metric": "nmse"}, {"metric": "r2"}],
        head={"table": "III"},
        digits=digits,
        bold=True,
    )
    body = [
        [*_setting_cells(s), *cells, Cell(text=_runs_text(runs))]
        for s, cells, runs in zip(setting_rows, pivot.cells, pivot.runs, strict=True)
    ]
    if show_preset:
        presets = [Cell(text=str(s["preset"])) for s in setting_rows]
        body = [[preset, *line] for preset, line in zip(presets, body, strict=True)]
    table = Table(
        title="Table III — Shore-hardness data",
        columns=columns,
        rows=body,
        caption="N-MSE and R² of all models on the Shore-hardness (new) dataset; best in **bold**.",
        provenance=describe_runs(
            rows, _ddof_text(ddof) + "; N-MSE on this data's own label range (config)"
        ),
        label="table3",
        latex_columns=latex_columns,
    )
    return PaperTable(table, pd.DataFrame(pivot.tidy))


# ============================================================================ subsets
def window_label(k: int) -> str:
    """``1e3–1e6`` for rolling window 0 (the decades it spans, in Pa)."""
    lo, hi = rolling_windows()[int(k)]
    return f"1e{round(math.log10(lo))}–1e{round(math.log10(hi))}"


def subset_summary_table(
    rows: pd.DataFrame,
    kind: str,
    title: str,
    caption: str,
    label: str,
    ddof: int = STD_DDOF,
    digits: int = 4,
) -> PaperTable | None:
    """N-MSE per subset (columns) and model x inputs (rows): the numbers behind Fig. 6 / 7."""
    rows = rows[rows["subset_kind"] == kind]
    if rows.empty:
        return None
    rows = rows.assign(subset_key=rows["subset_value"].astype(object))
    stats = summarise(rows, ["model", "inputs", "subset_key"], ["test_nmse"], ddof)
    stats = stats.rename(columns={"subset_key": "subset"})
    if kind == "window":
        subsets = [k for k in range(N_ROLLING_WINDOWS) if k in set(rows["subset_key"])]
    else:
        subsets = ordered(rows["subset_key"], SHAPE_ORDER)
    keys = _model_inputs(rows, ordered(rows["inputs"], InputStrategy.names()))
    pivot = _pivot(
        stats,
        [{"model": m, "inputs": i} for m, i in keys],
        [{"subset": s, "metric": "nmse"} for s in subsets],
        head={"table": label},
        digits=digits,
        bold=True,
    )
    # Bold in the cells only: these tidy rows never carried a ``bold`` column.
    tidy = [{k: v for k, v in row.items() if k != "bold"} for row in pivot.tidy]
    body = [
        [Cell(text=model_label(model)), Cell(text=inputs_label(inp)), *cells]
        for (model, inp), cells in zip(keys, pivot.cells, strict=True)
    ]
    columns = ["Model", "Input"]
    columns += [f"{window_label(int(s))} Pa" if kind == "window" else str(s) for s in subsets]
    table = Table(
        title=title,
        columns=columns,
        rows=body,
        caption=caption,
        provenance=describe_runs(rows, _ddof_text(ddof)),
        label=label,
    )
    return PaperTable(table, pd.DataFrame(tidy))


def softhard_subset_table(
    frame: pd.DataFrame, ddof: int = STD_DDOF, digits: int = 4
) -> PaperTable | None:
    """Runs trained and tested on the soft (< 0.275 MPa) or hard subset only."""
    rows = subset_rows(frame, "softhard")
    if rows.empty:
        return None
    rows = rows.assign(subset_key=rows["subset_value"].astype(object))
    metrics = ("test_log10_accuracy", "test_nmse")
    stats = summarise(
        rows, ["model", "inputs", "protocol", "sampling", "subset_key"], metrics, ddof
    ).rename(columns={"subset_key": "subset"})
    setting_rows = _settings(stats, ["model", "inputs", "protocol", "sampling"])
    pivot = _pivot(
        stats,
        setting_rows,
        [{"subset": s, "metric": m} for s in ("soft", "hard") for m in ("log10_accuracy", "nmse")],
        head={"table": "softhard-subsets"},
        digits=digits,
        bold=False,
    )
    body = [
        [*_setting_cells(s), *cells] for s, cells in zip(setting_rows, pivot.cells, strict=True)
    ]
    table = Table(
        title="Soft / hard training subsets",
        columns=["Model", "Input", "Split", "log₁₀ accuracy", "N-MSE", "log₁₀ accuracy", "N-MSE"],
        groups=[("", 3), ("soft (< 0.275 MPa)", 2), ("hard (≥ 0.275 MPa)", 2)],
        rows=body,
        caption="Models trained and tested only on objects softer / harder than the gel.",
        provenance=describe_runs(rows, _ddof_text(ddof)),
        label="softhard-subsets",
    )
    return PaperTable(table, pd.DataFrame(pivot.tidy))


# ============================================================================ per-group
def group_metric_tables(
    rows: pd.DataFrame,
    results_dir: str | Path,
    setting_text: str,
    ddof: int = STD_DDOF,
    digits: int = 4,
) -> list[PaperTable]:
    """Per-material / per-shape / soft-hard test errors from each run's ``groups.csv``.

    ``rows``: the runs of one setting; one table per metric, columns model x input
    strategy (Image and ALL when both exist, else all inputs).
    """
    frames = []
    for row in rows.itertuples(index=False):
        groups = read_groups(resolve_run_dir(row.run_dir, results_dir))
        if groups is None or groups.empty:
            continue
        frames.append(groups.assign(model=row.model, inputs=row.inputs, seed=row.seed))
    if not frames:
        return []
    data = pd.concat(frames, ignore_index=True)
    data = data[data["grouping"].isin(["material", "shape", "soft_hard"])]
    inputs = ordered(data["inputs"], InputStrategy.names())
    if {"Image", "ALL"} <= set(inputs):
        inputs = ["Image", "ALL"]
    keys = _model_inputs(data, inputs)
    group_order = []
    for grouping in ("soft_hard", "material", "shape"):
        names = data.loc[data["grouping"] == grouping, "group"].astype(str)
        preferred = ("soft", "hard") if grouping == "soft_hard" else ()
        group_order += [(grouping, g) for g in ordered(names, preferred)]
    used_rows = rows[rows["run_dir"].notna() & rows.set_index(["model", "inputs"]).index.isin(keys)]
    n_test = data.groupby(["grouping", "group"])["n"].mean()
    # A rule between the groupings (stiffness, material, shape).
    rules = {i for i in range(len(group_order) - 1) if group_order[i][0] != group_order[i + 1][0]}
    out: list[PaperTable] = []
    for metric in ("nmse", "log10_accuracy"):
        if metric not in data.columns:
            continue
        stats = summarise(data, ["grouping", "group", "model", "inputs"], [metric], ddof)
        # Group names as the row labels spell them (groups.csv may read them as numbers).
        stats = stats.assign(group=stats["group"].astype(str))
        pivot = _pivot(
            stats,
            [{"grouping": grouping, "group": group} for grouping, group in group_order],
            [{"model": m, "inputs": i, "metric": metric} for m, i in keys],
            head={"table": f"groups-{metric}"},
            digits=digits,
            bold=False,
        )
        body = [
            [
                Cell(text=f"{'stiffness' if grouping == 'soft_hard' else grouping}: {group}"),
                Cell(text=f"{n_test[(grouping, group)]:.0f}"),
                *cells,
            ]
            for (grouping, group), cells in zip(group_order, pivot.cells, strict=True)
        ]
        name = METRIC_LABELS[metric]
        table = Table(
            title=f"{name} per material, shape and stiffness",
            columns=["Group", "test samples / run"] + [f"{model_label(m)} {i}" for m, i in keys],
            rows=body,
            rules_after=rules,
            caption=(
                f"Test {name} broken down by the true object's material, shape and stiffness "
                f"(soft: E < 0.275 MPa, the gel's modulus); {setting_text}."
            ),
            provenance=describe_runs(used_rows, _ddof_text(ddof) + "; from each run's groups.csv"),
            label=f"groups-{_label_for(metric)}",
        )
        out.append(PaperTable(table, pd.DataFrame(pivot.tidy)))
    return out


# ============================================================================ failures
def failed_table(frame: pd.DataFrame, max_error_chars: int = 160) -> Table | None:
    """Every row that did not complete (failed, or any other status), with its error."""
    bad = frame[frame["status"] != STATUS_COMPLETE]
    if bad.empty:
        return None
    body = []
    for row in bad.itertuples(index=False):
        error = str(getattr(row, "error", "") or "").strip().splitlines()
        message = error[-1] if error else ""
        if len(message) > max_error_chars:
            message = message[: max_error_chars - 1] + "…"
        subset = "" if row.subset_kind == "none" else str(row.subset_value)
        body.append(
            [
                Cell(text=str(row.preset or "")),
                *_setting_cells(row._asdict()),
                Cell(text=str(row.seed)),
                Cell(text=subset),
                Cell(text=str(row.status)),
                Cell(text=str(getattr(row, "attempts", "") or "")),
                Cell(text=message),
            ]
        )
    n_failed = int((bad["status"] == STATUS_FAILED).sum())
    columns = ["Preset", "Model", "Input", "Split", "Seed", "Subset", "Status", "Attempts", "Error"]
    return Table(
        title="Runs that did not complete",
        columns=columns,
        rows=body,
        caption=(
            f"{len(bad)} row(s) ({n_failed} failed) are excluded from every table and figure; "
            "re-running the grid retries them."
        ),
        label="failed-runs",
    )
