"""An output calibration: a model's log10 prediction mapped onto a rig's reference objects.

``adapt`` (``inference.adapt``) fits it on grasps of reference objects of known modulus
and records it in the checkpoint under :data:`CALIBRATION_KEY`; the estimators that load
the checkpoint (``ComplianceEstimator``: ``predict``, ``live``) apply it to every
prediction. See docs/inference.md, "Adapt a model to your rig".
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tactile_compliance.data.normalisation import NormalisationConstants

__all__ = [
    "CALIBRATION_KEY",
    "DEFAULT_RIDGE",
    "OutputCalibration",
    "fit_output_calibration",
]

CALIBRATION_KEY = "output_calibration"
"""The checkpoint key that holds :meth:`OutputCalibration.to_dict`."""

DEFAULT_RIDGE = 1.0
"""Ridge weight [-] that pulls the slope towards 1 (a pure shift of the model's log10
prediction): the penalty is ``ridge x (b - 1)^2`` against the mean squared error in
decades^2 times the variance of the model's predictions, so it counts as much as the
predictions' own spread. With a handful of reference objects the slope is poorly
determined; the shift is what transfers a simulation-trained model's scale."""


@dataclass(frozen=True)
class OutputCalibration:
    """``log10 E' = intercept + slope x log10 E`` (E in Pa, the model's prediction E).

    Attributes:
        intercept: [log10 Pa].
        slope: [-], >= 0 (monotone: the calibration never reverses the model's ranking).
        fitted_on: what it was fitted on (objects, grasps, store, scores); informative.
    """

    intercept: float
    slope: float
    fitted_on: dict[str, Any] = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.intercept) and math.isfinite(self.slope)):
            raise ValueError(
                f"output calibration must be finite, got {self.intercept}, {self.slope}"
            )
        if self.slope < 0:
            raise ValueError(f"output calibration slope must be >= 0, got {self.slope}")

    def apply_log10(self, log10_pa: Any) -> Any:
        """The calibrated log10 E [log10 Pa] of the model's log10 E."""
        return self.intercept + self.slope * np.asarray(log10_pa, dtype=np.float64)

    def apply_normalised(self, y: np.ndarray, constants: NormalisationConstants) -> np.ndarray:
        """The same on normalised outputs ``y = (log10 E - lo) / span`` (the estimators'
        outputs), in the dtype of ``y``."""
        lo, span = constants.label_log10_min, constants.label_log10_span
        log10 = self.apply_log10(np.asarray(y, dtype=np.float64) * span + lo)
        return ((log10 - lo) / span).astype(np.asarray(y).dtype)

    def to_dict(self) -> dict[str, Any]:
        return {
            "kind": "affine-log10",
            "intercept": float(self.intercept),
            "slope": float(self.slope),
            "fitted_on": self.fitted_on,
        }

    @classmethod
    def from_dict(cls, data: Any, source: str = "checkpoint") -> OutputCalibration:
        """Read :meth:`to_dict` (ValueError naming ``source`` when invalid)."""
        if not isinstance(data, dict) or data.get("kind") != "affine-log10":
            raise ValueError(f"{source}: the output calibration is not an affine-log10 map")
        try:
            return cls(
                float(data["intercept"]), float(data["slope"]), dict(data.get("fitted_on", {}))
            )
        except (KeyError, TypeError, ValueError) as err:
            raise ValueError(f"{source}: invalid output calibration ({err})") from err


def fit_output_calibration(
    predicted_log10: Any, true_log10: Any, *, ridge: float = DEFAULT_RIDGE
) -> OutputCalibration:
    """The ridge-regularised affine map of ``predicted_log10`` onto ``true_log10`` (log10 Pa,
    one value per grasp or sample): minimises ``mean((t - a - b p)^2) + ridge var(p)
    (b - 1)^2``, with ``b`` clipped at 0 (monotone). ``ridge=inf`` fits the shift alone.

    Raises:
        ValueError: fewer than one finite pair, or a negative ridge.
    """
    p = np.asarray(predicted_log10, dtype=np.float64).reshape(-1)
    t = np.asarray(true_log10, dtype=np.float64).reshape(-1)
    ok = np.isfinite(p) & np.isfinite(t)
    if not ok.any():
        raise ValueError("no finite (prediction, truth) pair to fit an output calibration on")
    if not ridge >= 0:
        raise ValueError(f"ridge must be >= 0, got {ridge}")
    p, t = p[ok], t[ok]
    pc, tc = p - p.mean(), t - t.mean()
    var = float(np.mean(pc**2))
    if math.isinf(ridge) or var == 0.0:
        slope = 1.0
    else:
        # d/db [mean((tc - b pc)^2) + ridge var (b - 1)^2] = 0
        slope = (float(np.mean(pc * tc)) + ridge * var) / (var + ridge * var)
    slope = max(slope, 0.0)
    intercept = float(t.mean() - slope * p.mean())
    return OutputCalibration(intercept, slope)
