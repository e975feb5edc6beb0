"""The analytical estimators by name, so data, checkpoints and live use agree on one.

Two estimators compute the same pair ``(E_elastic [Pa], E*_hertz [Pa])`` from a grasp's
force [N], width [m] and depth [mm] series:

* ``"dataset"``: :func:`~tactile_compliance.physics.dataset_estimates.dataset_estimates_pa`,
  the code that made the public dataset's ``elastic_estimate.pkl`` / ``hertz_estimate.pkl``
  (Burgess et al.), quirks included. Real data and the synthetic generator use it.
* ``"contact"``: :func:`~tactile_compliance.physics.contact.analytical_estimates_pa`, this
  project's physically cleaner variant (``docs/physics.md`` compares the two).

A model trained on one estimator's values must be fed the same estimator's values at
inference, or it sees inputs from another distribution (train/serve skew). Stores record
the name in their header, checkpoints copy it, and the streaming estimator looks it up
here.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import partial
from typing import Any, TypeAlias

import numpy.typing as npt

__all__ = [
    "ANALYTICAL_ESTIMATORS",
    "DEFAULT_ANALYTICAL_ESTIMATOR",
    "WEDGE_UNITS",
    "AnalyticalEstimator",
    "SensorUnits",
    "analytical_estimator",
]

AnalyticalEstimator: TypeAlias = Callable[
    [npt.ArrayLike, npt.ArrayLike, npt.ArrayLike], tuple[float, float]
]
"""``(forces_n (T,), widths_m (T,), depth_mm (T, H, W)) -> (E_elastic, E*_hertz)`` in Pa."""

ANALYTICAL_ESTIMATORS = ("dataset", "contact")
"""The estimator names, in the order docs list them."""

DEFAULT_ANALYTICAL_ESTIMATOR = "dataset"
"""What a checkpoint that records no estimator was most likely trained on: the public
dataset's stored values (the generator has written them too since it adopted the name)."""


@dataclass(frozen=True)
class SensorUnits:
    """How the depth maps under a grasp's analytical estimates were made.

    The estimates count contact pixels and read depths, so their values depend on the depth
    model and the pixel density: estimates of a Mini with its calibrated model at
    12.5 px/mm are not in the units of the public dataset's Wedge. Stores record this
    (``creation_parameters["sensor"]``), checkpoints copy it, and inference compares it
    with the calibration it runs on.

    Attributes:
        depth_model: ``"dataset"`` (the public dataset's heuristic) or ``"calibrated"``
            (a sensor's own, ``calibrate-depth``).
        px_per_mm: pixel density [px/mm] the estimator used; None: its own, the Wedge's.
    """

    depth_model: str = "dataset"
    px_per_mm: float | None = None

    def __post_init__(self) -> None:
        if self.depth_model not in ("dataset", "calibrated"):
            raise ValueError(f"unknown depth model {self.depth_model!r} in the sensor record")
        if self.px_per_mm is not None and not (
            isinstance(self.px_per_mm, (int, float))
            and math.isfinite(self.px_per_mm)
            and 0 < self.px_per_mm < 1000
        ):
            raise ValueError(f"px_per_mm {self.px_per_mm!r} in the sensor record is not valid")

    def to_dict(self) -> dict[str, Any]:
        return {"depth_model": self.depth_model, "px_per_mm": self.px_per_mm}

    @classmethod
    def from_dict(cls, data: Any) -> SensorUnits:
        """Read :meth:`to_dict`; None (nothing recorded) is the dataset's Wedge.

        Raises:
            ValueError: not a mapping, or invalid values.
        """
        if data is None:
            return WEDGE_UNITS
        if not isinstance(data, dict):
            raise ValueError(f"the sensor record must be a mapping, got {type(data).__name__}")
        px = data.get("px_per_mm")
        return cls(str(data.get("depth_model", "dataset")), None if px is None else px)

    def describe(self) -> str:
        """E.g. ``the dataset's depth heuristic at the Wedge's pixel density``."""
        model = (
            "the dataset's depth heuristic"
            if self.depth_model == "dataset"
            else ("a calibrated depth model")
        )
        pixels = (
            "the Wedge's pixel density"
            if self.px_per_mm is None
            else (f"{self.px_per_mm:.4g} px/mm")
        )
        return f"{model} at {pixels}"

    def check_same(self, other: SensorUnits, *, trained: str, used: str) -> None:
        """Raise when estimates made with ``other`` would not be in this one's units.

        Raises:
            ValueError: another depth model or pixel density, naming both.
        """
        same_px = (self.px_per_mm is None and other.px_per_mm is None) or (
            self.px_per_mm is not None
            and other.px_per_mm is not None
            and math.isclose(self.px_per_mm, other.px_per_mm, rel_tol=1e-6)
        )
        if self.depth_model != other.depth_model or not same_px:
            raise ValueError(
                f"{trained} has analytical estimates from {self.describe()}, {used} from "
                f"{other.describe()}: the estimates would be in other units; use a model "
                "trained on this sensor's recordings, or inputs without estimates"
            )


WEDGE_UNITS = SensorUnits()
"""The public dataset's units: its depth heuristic at the Wedge's pixel density."""


def analytical_estimator(name: str, px_per_mm: float | None = None) -> AnalyticalEstimator:
    """The estimator function called ``name`` (one of :data:`ANALYTICAL_ESTIMATORS`).

    Args:
        name: the estimator.
        px_per_mm: pixel density [px/mm] of the depth maps it will get (a calibrated
            sensor's); None keeps the estimator's own, the public dataset's Wedge value
            (16.40 px/mm for ``"dataset"``, 11.4 px/mm for ``"contact"``).

    Raises:
        ValueError: an unknown name or a pixel density that is not positive.
    """
    if px_per_mm is not None and not (math.isfinite(px_per_mm) and px_per_mm > 0):
        raise ValueError(f"px_per_mm must be a positive number of px/mm, got {px_per_mm}")
    if name == "dataset":
        from tactile_compliance.physics.dataset_estimates import (
            DATASET_CONSTANTS,
            dataset_estimates_pa,
        )

        if px_per_mm is None:
            return dataset_estimates_pa
        constants = replace(DATASET_CONSTANTS, px_per_mm=float(px_per_mm))
        return partial(dataset_estimates_pa, constants=constants)
    if name == "contact":
        from tactile_compliance.physics.contact import SensorConstants, analytical_estimates_pa

        if px_per_mm is None:
            return analytical_estimates_pa
        sensor = SensorConstants(pixel_size_m=1e-3 / float(px_per_mm))
        return partial(analytical_estimates_pa, constants=sensor)
    raise ValueError(
        f"unknown analytical estimator {name!r}; choose one of {', '.join(ANALYTICAL_ESTIMATORS)}"
    )
