"""Check the paper's findings on a finished demo (or any results store of table1 quick).

Research script (issue 13): reads the results store and run directories that
``tactile-compliance demo`` wrote and prints, as markdown tables, the numbers that
``docs/results.md`` quotes:

1. **Convergence**: per model, how many runs ended by early stopping and, for runs that
   used their whole epoch budget, how much the best validation N-MSE so far still
   improved over the last 3 epochs, and the trend: the mean validation N-MSE of the last
   3 epochs against the 3 before them (from each run's ``logs/metrics.csv``; per-epoch
   values of the cached-feature heads scatter by +-20 % around their plateau, and the
   running best of a noisy plateau keeps creeping down, so the trend is the fairer test).
2. **The per-sample leak**: Seen with the paper's per-sample split next to Seen grouped by
   grasp, per model and input strategy.
3. **Learned models against the three references** (training median, analytical
   estimate, scalar GBR on the strategy's F/W/E): in how many runs of each condition the
   model's test N-MSE is lower.
4. **More inputs**: mean test N-MSE per input strategy and condition (over models).
5. **Seen against UnSeen**: mean test N-MSE per model and condition.
6. **Stiffness around the gel**: test N-MSE and log10 accuracy per label band around the
   gel's 0.275 MPa, pooled over the test predictions of every run of a condition.
7. **Table III**: N-MSE and R^2 per model on the Shore-hardness store.

Usage::

    tactile-compliance demo --out demo-output
    python benchmarks/demo_findings.py demo-output
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

CONDITIONS = {
    ("seen", "per_sample"): "Seen, per-sample (paper)",
    ("seen", "grasp"): "Seen, grasp-grouped",
    ("unseen", "grasp"): "UnSeen",
}
INPUTS = ("Image", "ImageF", "ImageFW", "ALL")
MODELS = ("top10nn", "vgg_lstm", "res_tf")

# Label bands [log10 Pa] around the gel's 0.275 MPa (log10 = 5.44): far below, just below,
# just above, rubbers and soft plastics, hard. Labels are normalised on [1e3, 1e12] Pa.
BANDS = ((3.0, 4.5), (4.5, 5.44), (5.44, 6.5), (6.5, 9.0), (9.0, 12.0))
LABEL_SPAN_DECADES = 9.0
LAST_EPOCHS = 3  # convergence: the window of the last epochs that must be flat


def load_rows(results: Path) -> pd.DataFrame:
    rows = [json.loads(p.read_text()) for p in sorted((results / "rows").glob("*.json"))]
    frame = pd.DataFrame(rows)
    return frame[frame["status"] == "complete"].copy()


def condition_name(row: pd.Series) -> str:
    grouping = (row.get("grouping") or "grasp") if row["condition"] == "seen" else "grasp"
    return CONDITIONS.get((row["condition"], grouping), "?")


def convergence(frame: pd.DataFrame) -> str:
    lines = [
        "| model | runs | ended by early stopping | used the whole budget | "
        "of those, best val N-MSE gain over the last 3 epochs (median, max) | "
        "of those, mean val N-MSE of the last 3 epochs vs the 3 before (median, max) |",
        "|---|---|---|---|---|---|",
    ]
    for model, part in frame.groupby("model", sort=False):
        early, full, falls, trends = 0, 0, [], []
        for _, row in part.iterrows():
            run = Path(row["run_dir"])
            cfg = yaml.safe_load((run / "config.yaml").read_text())
            max_epochs = int(cfg["training"]["max_epochs"])
            if int(row["epochs_trained"]) < max_epochs:
                early += 1
                continue
            full += 1
            log = pd.read_csv(run / "logs" / "metrics.csv")
            val = log["val_nmse"].dropna().to_numpy()
            best = np.minimum.accumulate(val)
            if len(best) > LAST_EPOCHS:
                falls.append((best[-LAST_EPOCHS - 1] - best[-1]) / best[-LAST_EPOCHS - 1])
            if len(val) >= 2 * LAST_EPOCHS:
                before = val[-2 * LAST_EPOCHS : -LAST_EPOCHS].mean()
                trends.append((val[-LAST_EPOCHS:].mean() - before) / before)
        spread = f"{100 * np.median(falls):.1f} %, {100 * np.max(falls):.1f} %" if falls else "-"
        trend = (
            f"{100 * np.median(trends):+.1f} %, {100 * np.max(trends):+.1f} %" if trends else "-"
        )
        lines.append(f"| {model} | {len(part)} | {early} | {full} | {spread} | {trend} |")
    return "\n".join(lines)


def leak(frame: pd.DataFrame) -> str:
    lines = [
        "| model | input | per-sample acc. | grasp-grouped acc. | per-sample N-MSE | "
        "grasp-grouped N-MSE | N-MSE ratio |",
        "|---|---|---|---|---|---|---|",
    ]
    for model in MODELS:
        for inputs in INPUTS:
            cell = frame[(frame["model"] == model) & (frame["inputs"] == inputs)]
            per = cell[cell["cond"] == CONDITIONS["seen", "per_sample"]]
            grp = cell[cell["cond"] == CONDITIONS["seen", "grasp"]]
            if per.empty or grp.empty:
                continue
            pa, ga = per["test_log10_accuracy"].mean(), grp["test_log10_accuracy"].mean()
            pn, gn = per["test_nmse"].mean(), grp["test_nmse"].mean()
            lines.append(
                f"| {model} | {inputs} | {pa:.3f} | {ga:.3f} | {pn:.4f} | {gn:.4f} | "
                f"{gn / pn:.1f}x |"
            )
    return "\n".join(lines)


def references(frame: pd.DataFrame) -> str:
    lines = [
        "| condition | runs | beat the median | beat the analytical estimate | "
        "beat the scalar GBR (runs with scalars) |",
        "|---|---|---|---|---|",
    ]
    for cond in CONDITIONS.values():
        part = frame[frame["cond"] == cond]
        if part.empty:
            continue
        median = int((part["test_nmse"] < part["ref_median_nmse"]).sum())
        analytical = int((part["test_nmse"] < part["ref_analytical_nmse"]).sum())
        with_gbr = part[part["ref_scalar_gbr_nmse"].notna()]
        gbr = int((with_gbr["test_nmse"] < with_gbr["ref_scalar_gbr_nmse"]).sum())
        lines.append(
            f"| {cond} | {len(part)} | {median} | {analytical} | {gbr} of {len(with_gbr)} |"
        )
    return "\n".join(lines)


def _mean_nmse_table(
    frame: pd.DataFrame, row_key: str, rows: list[str], col_key: str, cols: list[str]
) -> str:
    """Mean test N-MSE per (row, column) as a markdown table; rows without runs left out."""
    lines = [f"| {row_key} | " + " | ".join(cols) + " |", "|---|" + "---|" * len(cols)]
    for row in rows:
        part = frame[frame[row_key] == row]
        if part.empty:
            continue
        means = [part[part[col_key] == c]["test_nmse"].mean() for c in cols]
        lines.append(f"| {row} | " + " | ".join(f"{m:.4f}" for m in means) + " |")
    return "\n".join(lines)


def by_input(frame: pd.DataFrame) -> str:
    table = _mean_nmse_table(frame, "cond", list(CONDITIONS.values()), "inputs", list(INPUTS))
    return table.replace("| cond |", "| condition |", 1)


def seen_unseen(frame: pd.DataFrame) -> str:
    return _mean_nmse_table(frame, "model", list(MODELS), "cond", list(CONDITIONS.values()))


def stiffness(frame: pd.DataFrame) -> str:
    header = [f"{lo:g}-{hi:g}" for lo, hi in BANDS]
    lines = [
        "| condition | " + " | ".join(f"log10 E {h}" for h in header) + " |",
        "|---|" + "---|" * len(BANDS),
    ]
    for cond in CONDITIONS.values():
        part = frame[frame["cond"] == cond]
        if part.empty:
            continue
        preds = pd.concat(
            pd.read_csv(Path(d) / "predictions.csv").query("split == 'test'")
            for d in part["run_dir"]
        )
        true = np.log10(preds["modulus_pa"].to_numpy())
        pred = np.log10(preds["pred_pa"].to_numpy())
        cells = []
        for lo, hi in BANDS:
            inside = (true >= lo) & (true < hi) if hi < 12 else (true >= lo)
            if not inside.any():
                cells.append("-")
                continue
            err = (pred[inside] - true[inside]) / LABEL_SPAN_DECADES
            acc = np.mean(np.abs(pred[inside] - true[inside]) <= 1.0)
            cells.append(f"{np.mean(err**2):.4f} / {acc:.2f} (n {inside.sum()})")
        lines.append(f"| {cond} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def shore(frame: pd.DataFrame) -> str:
    lines = ["| model | N-MSE | R^2 | epochs (best) |", "|---|---|---|---|"]
    for _, row in frame.iterrows():
        lines.append(
            f"| {row['model']} | {row['test_nmse']:.4f} | {row['test_r2']:.3f} | "
            f"{row['epochs_trained']} ({row['best_epoch']}) |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("demo", type=Path, help="the demo's output directory")
    args = parser.parse_args()
    rows = load_rows(args.demo / "results")
    is_shore = rows["preset"].astype(str).str.startswith("new-dataset")
    table1 = rows[~is_shore].copy()
    table1["cond"] = table1.apply(condition_name, axis=1)
    sections = [
        ("Convergence (Table I and Table III runs)", convergence(rows)),
        ("The per-sample leak (Seen)", leak(table1)),
        ("Learned models against the references (test N-MSE)", references(table1)),
        ("More inputs: mean test N-MSE over the three models", by_input(table1)),
        ("Seen against UnSeen: mean test N-MSE over the four inputs", seen_unseen(table1)),
        (
            "Stiffness bands around the gel (0.275 MPa = 10^5.44 Pa): "
            "N-MSE / log10 accuracy, all test predictions of a condition",
            stiffness(table1),
        ),
        ("Table III (Shore-hardness videos)", shore(rows[is_shore])),
    ]
    for title, table in sections:
        print(f"### {title}\n\n{table}\n")


if __name__ == "__main__":
    main()
