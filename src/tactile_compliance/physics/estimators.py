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
from dataclasses import replace
from functools import partial
from typing import TypeAlias

import numpy.typing as npt

__all__ = [
    "ANALYTICAL_ESTIMATORS",
    "DEFAULT_ANALYTICAL_ESTIMATOR",
    "AnalyticalEstimator",
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
