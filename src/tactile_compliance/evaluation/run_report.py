"""``build_run_report``: the report of one run directory (``report RUN``).

A run directory (what ``train`` writes: ``metrics.json``, ``predictions.csv``,
``config.yaml``) is reported on its own: its metrics table (test, validation and the
reference predictors) and its predicted-against-true figure. See docs/reporting.md,
"A single run".
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pandas as pd

from tactile_compliance import __version__
from tactile_compliance.data.normalisation import NormalisationConstants
from tactile_compliance.evaluation import plots
from tactile_compliance.evaluation.loading import read_label_span, read_test_predictions
from tactile_compliance.evaluation.parts import ReportParts
from tactile_compliance.evaluation.render import Cell, Heading, Paragraph, Table
from tactile_compliance.runs.layout import RESULT_FILE
from tactile_compliance.runs.metrics import METRIC_NAMES

__all__ = ["is_run_dir", "run_report_parts"]


def is_run_dir(path: Path) -> bool:
    """True when ``path`` is a run directory (it holds ``metrics.json``), not a results store."""
    return (path / RESULT_FILE).is_file()


def _metric_rows(result: dict[str, Any]) -> list[tuple[str, dict[str, Any]]]:
    """(label, metrics) of the test split, the validation split and each reference."""
    rows = [(name, result[name]) for name in ("test", "val") if isinstance(result.get(name), dict)]
    for name, metrics in (result.get("reference") or {}).items():
        if isinstance(metrics, dict):
            rows.append((f"reference: {name} (test)", metrics))
    return rows


def run_report_parts(run_dir: Path, fig_dir: Path) -> tuple[ReportParts, dict[str, Any]]:
    """The blocks, table and figure of one run's report, and its ``metrics.json``.

    The table ``run-metrics`` has one row per split and reference predictor with the
    metrics of ``runs.metrics.METRIC_NAMES`` (log10 accuracy and within half a decade as
    fractions, N-MSE on the run's normalised scale, MAE in decades) and ``n``. The figure
    ``run-scatter`` (``fig_dir/run_scatter.png``) is the run's test predictions against the
    true modulus, from ``predictions.csv``; without a readable one it is a note.

    Raises:
        ValueError: ``metrics.json`` is not a JSON object (a damaged run).
    """
    try:
        result = json.loads((run_dir / RESULT_FILE).read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ValueError(f"{run_dir / RESULT_FILE}: not a run's metrics file ({err})") from err
    if not isinstance(result, dict):
        raise ValueError(f"{run_dir / RESULT_FILE}: not a run's metrics file (not an object)")
    parts = ReportParts()
    name = str(result.get("run_name") or run_dir.name)
    setting = ", ".join(
        f"{key} {result[key]}"
        for key in ("model", "inputs", "condition", "sampling", "seed")
        if result.get(key) is not None
    )
    lines = [
        f"- Run directory: `{run_dir}`",
        f"- Setting: {setting or 'not recorded'}",
        f"- Samples: {result.get('n_train', '?')} train, {result.get('n_val', '?')} validation, "
        f"{result.get('n_test', '?')} test; best epoch {result.get('best_epoch', '?')}",
        f"- Report: tactile-compliance {__version__}; metrics of the best checkpoint",
    ]
    parts.blocks += [
        Heading(f"Run {name}", 1),
        Paragraph("\n".join(lines)),
        Heading("Metrics", 2),
    ]
    body, tidy = [], []
    for label, metrics in _metric_rows(result):
        values = {m: metrics.get(m) for m in METRIC_NAMES}
        body.append(
            [
                Cell(text=label),
                *(Cell(None if v is None else float(v)) for v in values.values()),
                Cell(text=str(metrics.get("n", ""))),
            ]
        )
        tidy.append({"row": label, **values, "n": metrics.get("n")})
    if body:
        table = Table(
            title="Run metrics",
            columns=["", *METRIC_NAMES, "n"],
            rows=body,
            caption="The run's metrics as `metrics.json` holds them (best checkpoint).",
            label="run-metrics",
        )
        parts.blocks.append(table)
        parts.latex_tables["run-metrics"] = table
        parts.tables["run-metrics"] = pd.DataFrame(tidy)
    else:
        parts.note(f"{run_dir / RESULT_FILE} holds no test metrics (the run did not finish).")
    parts.blocks.append(Heading("Predicted against true modulus", 2))
    predictions = read_test_predictions(run_dir)
    test = result.get("test") if isinstance(result.get("test"), dict) else {}
    nmse = test.get("nmse")
    if predictions is None or nmse is None:
        parts.note(
            f"Figure skipped: {run_dir / 'predictions.csv'} has no test predictions"
            if predictions is None
            else "Figure skipped: metrics.json has no test N-MSE"
        )
        return parts, result
    panel = plots.ScatterPanel(
        title=name if len(name) <= 40 else setting or name[:40],
        true_pa=predictions["modulus_pa"].to_numpy(dtype=float),
        pred_pa=predictions["pred_pa"].to_numpy(dtype=float),
        material=predictions.get("material", pd.Series(["?"] * len(predictions)))
        .astype(str)
        .to_numpy(),
        nmse=float(nmse),
        span_decades=read_label_span(run_dir) or NormalisationConstants().label_log10_span,
    )
    out = plots.plot_prediction_panels([panel], fig_dir / "run_scatter.png", ncols=1)
    parts.add_figure(
        "run-scatter",
        out,
        "Predicted against true Young's modulus of the run's test samples, per material. "
        "Red: y = x; blue: the gel's 0.275 MPa; grey: the N-MSE band.",
        f"one point per test sample of `{run_dir / 'predictions.csv'}`",
    )
    return parts, result
