"""``adapt``: a simulation-trained model adapted to a rig from grasps of reference objects.

The model predicts every grasp of a reference store (``record`` + ``import burgess`` of
objects whose moduli the lab knows); an output calibration in log10 space
(``runs.output_calibration``: ``log10 E' = a + b log10 E``, the slope ridge-pulled towards
1 and kept >= 0) is fitted on them and recorded in ``DIR/best.pt``, which ``predict`` and
``live`` load as any checkpoint (``ComplianceEstimator`` applies the map). Leave-one-
OBJECT-out scores say what to expect on objects the calibration has not seen. See
docs/inference.md, "Adapt a model to your rig".
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from tactile_compliance.data.safe_pickle import load_torch_file
from tactile_compliance.devices import DEFAULT_DEVICE
from tactile_compliance.outputs import atomic_file, claim_output_dir
from tactile_compliance.runs.checkpoint import torch_write_errors
from tactile_compliance.runs.output_calibration import (
    CALIBRATION_KEY,
    DEFAULT_RIDGE,
    OutputCalibration,
    fit_output_calibration,
)

__all__ = ["AdaptSummary", "GraspPrediction", "adapt_model", "score_grasps"]

OUTPUT_KIND = "adapt"
"""The marker ``claim_output_dir`` writes into ``DIR``."""


@dataclass(frozen=True)
class GraspPrediction:
    """One reference grasp: its object, true E [Pa] and the model's log10 E [log10 Pa]
    (augmentation 0, the frames ``live`` uses; the markerless finger when a store has
    both)."""

    object: str
    grasp: int
    true_pa: float
    pred_log10: float


def score_grasps(
    true_log10: Sequence[float], pred_log10: Sequence[float], objects: Sequence[str]
) -> dict[str, Any]:
    """``within_one_decade`` (share of grasps with |error| <= 1 decade), ``median_abs_decades``,
    ``spearman_objects`` (of the objects' mean log10 predictions against their log10 E;
    None with fewer than 3 objects or a constant) and ``n_grasps``."""
    from scipy.stats import spearmanr

    from tactile_compliance.runs.metrics import log10_accuracy

    t, p = np.asarray(true_log10, dtype=float), np.asarray(pred_log10, dtype=float)
    names = sorted(set(objects))
    per_true = [float(np.mean(t[[o == n for o in objects]])) for n in names]
    per_pred = [float(np.mean(p[[o == n for o in objects]])) for n in names]
    rho = None
    if len(names) >= 3 and np.ptp(per_true) > 0 and np.ptp(per_pred) > 0:
        rho = float(spearmanr(per_true, per_pred).statistic)
    return {
        "n_grasps": int(t.size),
        "within_one_decade": log10_accuracy(10**t, 10**p),
        "median_abs_decades": float(np.median(np.abs(p - t))),
        "spearman_objects": rho,
    }


def leave_one_object_out(grasps: Sequence[GraspPrediction], ridge: float) -> list[float]:
    """Each grasp's calibrated log10 E from a calibration fitted on the other objects'
    grasps (NaN when no other object is left)."""
    out = []
    for g in grasps:
        rest = [h for h in grasps if h.object != g.object]
        if not rest:
            out.append(math.nan)
            continue
        cal = fit_output_calibration(
            [h.pred_log10 for h in rest], [math.log10(h.true_pa) for h in rest], ridge=ridge
        )
        out.append(float(cal.apply_log10(g.pred_log10)))
    return out


@dataclass
class AdaptSummary:
    """What ``adapt`` wrote and its scores on the reference grasps."""

    out_dir: Path
    checkpoint: Path
    calibration: OutputCalibration
    scores: dict[str, dict[str, Any]]
    per_object: list[dict[str, Any]] = field(default_factory=list)
    per_grasp: list[dict[str, Any]] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {
            "out_dir": str(self.out_dir),
            "checkpoint": str(self.checkpoint),
            "calibration": self.calibration.to_dict(),
            "scores": self.scores,
            "per_object": self.per_object,
            "per_grasp": self.per_grasp,
        }

    def format(self) -> str:
        cal = self.calibration
        lines = [
            f"Output calibration: log10 E = {cal.intercept:+.3f} + {cal.slope:.3f} x log10 "
            f"E_model, fitted on {cal.fitted_on['grasps']} grasps of "
            f"{len(cal.fitted_on['objects'])} reference objects.",
            f"{'':36s} {'within 1 decade':>16s} {'Spearman (objects)':>19s} "
            f"{'median |err| [dec]':>19s}",
        ]
        names = {
            "model": "the model as it was",
            "adapted_in_sample": "adapted (on the grasps it was fitted on)",
            "adapted_leave_one_object_out": "adapted, leave-one-object-out",
        }
        for key, label in names.items():
            s = self.scores[key]
            rho = "-" if s["spearman_objects"] is None else f"{s['spearman_objects']:.2f}"
            lines.append(
                f"{label:36s} {s['within_one_decade']:>15.0%} {rho:>19s} "
                f"{s['median_abs_decades']:>19.2f}"
            )
        lines.append(
            "Leave-one-object-out is what to expect on objects not among the references "
            f"({self.scores['model']['n_grasps']} grasps: few objects, a rough guide)."
        )
        lines.append(f"Model: {self.checkpoint} (predict and live apply the calibration).")
        return "\n".join(lines)


def reference_predictions(
    model: str | Path, store: str | Path, *, device: str = DEFAULT_DEVICE
) -> tuple[Path, list[GraspPrediction]]:
    """The checkpoint file and the model's own (uncalibrated) prediction of every grasp of
    ``store`` (augmentation 0; the markerless finger where a store has both).

    Raises:
        ValueError: an exported directory instead of a checkpoint, or a store without a
            labelled grasp the model can predict.
    """
    from tactile_compliance.inference.estimator import ComplianceEstimator, resolve_checkpoint
    from tactile_compliance.inference.predict import predict_path
    from tactile_compliance.inference.pretrained import WEIGHTS_FILE

    if (Path(model) / WEIGHTS_FILE).is_file():
        raise ValueError(
            f"{model}: adapt needs a checkpoint (best.pt or a run directory), not an "
            "exported directory"
        )
    checkpoint = resolve_checkpoint(model)
    estimator = ComplianceEstimator.from_checkpoint(checkpoint, device=device)
    estimator.calibration = None  # re-adapting fits on the model's own predictions
    report = predict_path(estimator, store, device=device)
    rows = [p for p in report["predictions"] if int(p["augmentation"]) == 0 and "true_pa" in p]
    fingers = {p["finger"] for p in rows}
    if len(fingers) > 1:
        rows = [p for p in rows if p["finger"] == "markerless"]
    grasps = [
        GraspPrediction(str(p["object"]), int(p["grasp"]), float(p["true_pa"]), p["pred_log10_pa"])
        for p in rows
        if math.isfinite(p["pred_log10_pa"])
    ]
    if not grasps:
        raise ValueError(f"{store}: no labelled grasp that {checkpoint} can predict")
    return checkpoint, grasps


def adapt_model(
    model: str | Path,
    reference_store: str | Path,
    out_dir: str | Path,
    *,
    ridge: float = DEFAULT_RIDGE,
    device: str = DEFAULT_DEVICE,
) -> AdaptSummary:
    """Fit the output calibration of ``model`` on ``reference_store`` and write
    ``out_dir/best.pt`` (the checkpoint with the calibration recorded under
    ``output_calibration``) and ``out_dir/adapt.json`` (the scores, and per object and
    per grasp [Pa] the model's own and the leave-one-object-out prediction, ``per_object``
    and ``per_grasp``).

    Deterministic: the same model and store give the same calibration.

    Raises:
        OutputExistsError: ``out_dir`` holds something ``adapt`` did not write.
        ValueError: see :func:`reference_predictions`; a negative ridge.
    """
    out = claim_output_dir(out_dir, OUTPUT_KIND, create=False)
    checkpoint, grasps = reference_predictions(model, reference_store, device=device)
    true = [math.log10(g.true_pa) for g in grasps]
    pred = [g.pred_log10 for g in grasps]
    objects = [g.object for g in grasps]
    calibration = fit_output_calibration(pred, true, ridge=ridge)
    loo = leave_one_object_out(grasps, ridge)
    in_sample = [float(calibration.apply_log10(p)) for p in pred]
    scores = {
        "model": score_grasps(true, pred, objects),
        "adapted_in_sample": score_grasps(true, in_sample, objects),
        "adapted_leave_one_object_out": score_grasps(true, loo, objects),
    }
    per_object = []
    for name in sorted(
        set(objects), key=lambda n: next(g.true_pa for g in grasps if g.object == n)
    ):
        idx = [i for i, o in enumerate(objects) if o == name]
        per_object.append(
            {
                "object": name,
                "true_pa": grasps[idx[0]].true_pa,
                "grasps": len(idx),
                "model_pa": float(10 ** np.mean([pred[i] for i in idx])),
                "adapted_loo_pa": float(10 ** np.mean([loo[i] for i in idx])),
            }
        )
    calibration = OutputCalibration(
        calibration.intercept,
        calibration.slope,
        {
            "base_checkpoint": str(checkpoint),
            "reference_store": str(reference_store),
            "objects": sorted(set(objects)),
            "grasps": len(grasps),
            "ridge": ridge,
            "leave_one_object_out": scores["adapted_leave_one_object_out"],
        },
    )
    out = claim_output_dir(out, OUTPUT_KIND)
    payload = load_torch_file(checkpoint, "tactile-compliance checkpoint", map_location="cpu")
    payload[CALIBRATION_KEY] = calibration.to_dict()
    target = out / "best.pt"
    with atomic_file(target, "wb") as handle, torch_write_errors(target):
        torch.save(payload, handle)
    per_grasp = [
        {
            "object": g.object,
            "grasp": g.grasp,
            "true_pa": g.true_pa,
            "model_pa": float(10**p),
            "adapted_loo_pa": None if not math.isfinite(q) else float(10**q),
        }
        for g, p, q in zip(grasps, pred, loo, strict=True)
    ]
    summary = AdaptSummary(out, target, calibration, scores, per_object, per_grasp)
    with atomic_file(out / "adapt.json", "w") as handle:
        handle.write(json.dumps(summary.to_dict(), indent=2) + "\n")
    return summary
