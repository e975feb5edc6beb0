"""The ``predict`` command's library side: read a source, run a checkpoint, report.
See docs/inference.md, "Command line".
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from tactile_compliance.data.inputs import scalar_inputs
from tactile_compliance.data.raw_layout import FingerChoice
from tactile_compliance.devices import DEFAULT_DEVICE
from tactile_compliance.inference.sources import ROW_COLUMNS, GraspBatch, read_source
from tactile_compliance.models import InputStrategy
from tactile_compliance.runs.metrics import compute_metrics

if TYPE_CHECKING:
    from tactile_compliance.inference.estimator import ComplianceEstimator

__all__ = ["format_predictions", "predict_path", "skip_reasons"]


def predict_path(
    checkpoint: str | Path | ComplianceEstimator,
    path: str | Path,
    *,
    device: str = DEFAULT_DEVICE,
    fingers: FingerChoice = "both",
    batch_size: int = 64,
    backbone_weights: str | Path | None = None,
) -> dict[str, Any]:
    """Predict every grasp under ``path`` with ``checkpoint`` (as
    :meth:`ComplianceEstimator.load` takes it, or an estimator already loaded); samples
    missing an input the checkpoint needs are skipped with the reason.

    Returns:
        The JSON report shown in docs/inference.md, "Command line": ``checkpoint`` (what
        the model is), ``source`` (``path``, ``kind``, ``frame_kind``, ``samples``),
        ``predictions`` (per sample: its identification, ``pred_pa``, ``pred_log10_pa``,
        and ``true_pa`` / ``error_decades`` when the truth is known), ``skipped`` and
        ``summary`` (counts, geometric mean, and ``metrics`` when every predicted sample
        has a known modulus).
    """
    from tactile_compliance.inference.estimator import ComplianceEstimator

    if isinstance(checkpoint, ComplianceEstimator):
        estimator = checkpoint
    else:
        estimator = ComplianceEstimator.load(
            checkpoint, device=device, backbone_weights=backbone_weights
        )
    source = read_source(path, fingers=fingers, image_size=estimator.run_inputs.store_image_size)
    needed = estimator.required_inputs
    scalar_names = estimator.inputs.scalar_names
    if source.kind == "video" and scalar_names:
        raise ValueError(
            f"{path}: a video carries no force, width or estimates, but checkpoint "
            f"{estimator.source} (inputs={estimator.inputs.value}) needs "
            f"{', '.join(scalar_names)}; use an Image checkpoint"
        )
    if "depth" in needed and source.depth_mm is None:
        raise ValueError(
            f"{path}: checkpoint {estimator.source} (inputs={estimator.inputs.value}) reads "
            f"depth maps, but this {source.kind.replace('_', ' ')} holds none; predict from "
            f"a store imported with its depth maps (`import burgess SRC --out STORE`), or "
            f"run `live` with the sensor's --calibration"
        )
    run_inputs = estimator.run_inputs
    run_inputs.check_sensor(
        source.sensor_units, trained=f"checkpoint {estimator.source}", used=str(path)
    )
    mismatch = run_inputs.source_mismatch(
        source.source_image_size, source.sensor_units, used=str(path)
    ) + run_inputs.rig_mismatch(source.rig_stiffness_n_per_m, used=str(path))
    scalars = source.inputs(scalar_names)
    usable = np.ones(len(source), dtype=bool)
    reasons: list[str] = [""] * len(source)
    # A model trained with estimate dropout estimates grasps whose fits failed.
    may_miss = set(run_inputs.analytical_inputs) if run_inputs.missing_estimates else set()
    for name in scalar_names:
        if name in may_miss:
            continue
        missing = ~np.all(np.isfinite(scalars[name]), axis=1)
        for i in np.flatnonzero(missing & usable):
            reasons[i] = f"missing {name} (NaN)"
        usable &= ~missing
    if len(source) and not usable.any():
        _refuse_when_nothing_is_usable(path, estimator.source, estimator.inputs, reasons, source)
    ids = np.flatnonzero(usable)
    pred_pa = np.full(len(source), np.nan)
    pred_log10 = np.full(len(source), np.nan)
    chunk = max(1, int(batch_size)) * 4  # bound memory on large stores
    for start in range(0, ids.size, chunk):
        part = ids[start : start + chunk]
        prediction = estimator.predict(**source.inputs(needed, part), batch_size=batch_size)
        pred_pa[part] = prediction.modulus_pa
        pred_log10[part] = prediction.log10_modulus_pa

    records: list[dict[str, Any]] = []
    skipped = [{**dict.fromkeys(ROW_COLUMNS), **bad} for bad in source.unreadable]
    truth = source.rows["modulus_pa"].to_numpy(np.float64)
    for i, row in enumerate(source.rows.to_dict(orient="records")):
        ident = {
            k: row[k].item() if isinstance(row[k], np.generic) else row[k] for k in ROW_COLUMNS
        }
        if not usable[i]:
            skipped.append({**ident, "reason": reasons[i]})
            continue
        record = {**ident, "pred_pa": float(pred_pa[i]), "pred_log10_pa": float(pred_log10[i])}
        if np.isfinite(truth[i]) and truth[i] > 0:
            record["true_pa"] = float(truth[i])
            record["error_decades"] = float(pred_log10[i] - np.log10(truth[i]))
        records.append(record)

    summary: dict[str, Any] = {"n_predicted": int(ids.size), "n_skipped": len(skipped)}
    if ids.size:
        mean_log10 = float(np.mean(pred_log10[ids]))
        summary["mean_log10_pa"] = mean_log10
        summary["geometric_mean_pa"] = float(10.0**mean_log10)
        known = truth[ids]
        if np.all(np.isfinite(known) & (known > 0)):
            summary["metrics"] = compute_metrics(known, pred_pa[ids], estimator.constants)
    return {
        "checkpoint": estimator.describe(),
        "source": {
            "path": str(path),
            "kind": source.kind,
            "frame_kind": source.frame_kind,
            "samples": len(source),
        },
        "predictions": records,
        "skipped": skipped,
        "summary": summary,
        # Where the source differs from the training data (RunInputs.source_mismatch).
        "warnings": mismatch,
    }


def _refuse_when_nothing_is_usable(
    path: str | Path,
    checkpoint: str,
    inputs: InputStrategy,
    reasons: list[str],
    source: GraspBatch,
) -> None:
    """A ValueError naming why no sample of ``path`` can be predicted, and which input
    strategies could: those whose scalar inputs ``source`` holds for some sample (its
    image inputs are not judged)."""
    names = {spec.name for spec in scalar_inputs()}
    held = source.inputs(sorted(names))
    lacking = {n for n in names if not np.all(np.isfinite(held[n]), axis=1).any()}
    could = [s.value for s in InputStrategy if not lacking & set(s.input_names)]
    raise ValueError(
        f"{path}: none of its {len(reasons)} samples can be predicted by {checkpoint} "
        f"(inputs={inputs.value}): {skip_reasons([{'reason': r} for r in reasons])}; "
        f"a checkpoint of {' or '.join(could)} inputs can"
    )


def skip_reasons(skipped: list[dict[str, Any]]) -> str:
    """Why samples were skipped, most common first: ``"missing estimates (NaN): 4"``."""
    counts = Counter(str(row.get("reason")) for row in skipped)
    return ", ".join(f"{reason}: {n}" for reason, n in counts.most_common())


def format_predictions(report: dict[str, Any], max_rows: int = 20) -> str:
    """Human-readable text of a :func:`predict_path` report (what the CLI prints)."""
    ckpt, source, summary = report["checkpoint"], report["source"], report["summary"]
    size = "x".join(map(str, ckpt["image_size"])) if ckpt["image_size"] else "none"
    lines = [
        f"Checkpoint  {ckpt['checkpoint']}  ({ckpt['model']}, inputs {ckpt['inputs']}, "
        f"images {size})",
        f"Source      {source['path']}  ({source['kind']}, {source['samples']} samples)",
        *(f"Warning     {warning}" for warning in report.get("warnings", [])),
    ]
    predictions = report["predictions"]
    if predictions:
        has_truth = all("true_pa" in p for p in predictions)
        header = f"{'object':<24} {'grasp':>5} {'aug':>3} {'finger':<10} {'E_pred [Pa]':>12}"
        if has_truth:
            header += f" {'E_true [Pa]':>12} {'err [dec]':>9}"
        lines += ["", header]
        for p in predictions[:max_rows]:
            line = (
                f"{str(p['object'])[:24]:<24} {p['grasp']:>5} {p['augmentation']:>3} "
                f"{p['finger']:<10} {p['pred_pa']:>12.3g}"
            )
            if has_truth:
                line += f" {p['true_pa']:>12.3g} {p['error_decades']:>+9.2f}"
            lines.append(line)
        if len(predictions) > max_rows:
            lines.append(f"... {len(predictions) - max_rows} more (use --json for all)")
    lines.append("")
    if summary["n_predicted"]:
        lines.append(
            f"Estimate    {summary['geometric_mean_pa']:.4g} Pa (geometric mean of "
            f"{summary['n_predicted']}; log10 {summary['mean_log10_pa']:.3f})"
        )
    if "metrics" in summary:
        m = summary["metrics"]
        lines.append(
            f"Metrics     log10 accuracy {m['log10_accuracy']:.3f}, N-MSE {m['nmse']:.4f}, "
            f"MAE {m['mae_decades']:.3f} decades"
        )
    if report["skipped"]:
        lines.append(
            f"Skipped     {len(report['skipped'])} samples ({skip_reasons(report['skipped'])}; "
            "see --json)"
        )
    return "\n".join(lines)
