"""The analytical estimators as objects, so data, checkpoints and live use agree on one.

See docs/physics.md, "Which estimator runs where".
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from tactile_compliance.physics.contact import (
    SensorConstants,
    analytical_estimates_pa,
    rig_corrected_widths_m,
)
from tactile_compliance.physics.dataset_estimates import (
    DATASET_CONSTANTS,
    DATASET_PRESS_FORCE_N,
    dataset_estimates_pa,
)

__all__ = [
    "DATASET_UNITS",
    "DEFAULT_ESTIMATOR",
    "WEDGE_UNITS",
    "AnalyticalEstimator",
    "GraspUnits",
    "SensorUnits",
]

ANALYTICAL_ESTIMATORS = ("dataset", "contact")
"""The estimator names, in the order docs list them."""


@dataclass(frozen=True)
class AnalyticalEstimator:
    """One analytical estimator at one pixel density.

    Attributes:
        name: ``"dataset"`` or ``"contact"`` (:data:`ANALYTICAL_ESTIMATORS`).
        px_per_mm: pixel density [px/mm] of the depth maps it gets (a calibrated
            sensor's); None keeps the estimator's own, the public dataset's Wedge value
            (16.40 px/mm for ``"dataset"``, 11.4 px/mm for ``"contact"``).
    """

    name: str = "dataset"
    px_per_mm: float | None = None

    def __post_init__(self) -> None:
        if self.name not in ANALYTICAL_ESTIMATORS:
            raise ValueError(
                f"unknown analytical estimator {self.name!r}; choose one of "
                f"{', '.join(ANALYTICAL_ESTIMATORS)}"
            )
        px = self.px_per_mm
        if px is not None and not (isinstance(px, (int, float)) and math.isfinite(px) and px > 0):
            raise ValueError(f"px_per_mm must be a positive number of px/mm, got {px}")

    def at(self, px_per_mm: float | None) -> AnalyticalEstimator:
        """The same estimator on depth maps of ``px_per_mm`` (None: its own density)."""
        return replace(self, px_per_mm=px_per_mm)

    def estimate(
        self,
        forces_n: npt.ArrayLike,
        widths_m: npt.ArrayLike,
        depth_mm: npt.ArrayLike,
        *,
        marker_depths_mm: npt.ArrayLike | None = None,
        rig_stiffness_n_per_m: float | None = None,
    ) -> tuple[float, float]:
        """``(E_elastic, E*_hertz)`` in Pa of a force (T,), width (T,) and depth (T, H, W)
        series (ValueError: malformed). ``marker_depths_mm``: the marker finger's depth
        maps, for the dataset estimator's depth-onset clip (the others ignore them).

        ``rig_stiffness_n_per_m`` [N/m]: the rig-corrected estimates, the rig's own
        closure ``F / k_rig`` taken out of the widths before the fits
        (``contact.rig_corrected_widths_m``; for the dataset estimator after its width
        interpolation). None (default): the estimates as they were, bit-exact."""
        if self.name == "dataset":
            constants = DATASET_CONSTANTS
            if self.px_per_mm is not None:
                constants = replace(constants, px_per_mm=float(self.px_per_mm))
            return dataset_estimates_pa(
                forces_n,
                widths_m,
                depth_mm,
                constants,
                marker_depths_mm=marker_depths_mm,
                rig_stiffness_n_per_m=rig_stiffness_n_per_m,
            )
        sensor = SensorConstants()
        if self.px_per_mm is not None:
            sensor = SensorConstants(pixel_size_m=1e-3 / float(self.px_per_mm))
        if rig_stiffness_n_per_m is not None:
            widths_m = rig_corrected_widths_m(widths_m, forces_n, rig_stiffness_n_per_m)
        return analytical_estimates_pa(forces_n, widths_m, depth_mm, sensor)

    def window_start(self, forces_n: npt.ArrayLike) -> int | None:
        """The frame of a recording this estimator's series starts at, or None.

        The dataset's estimator clips the whole recording itself: it is fed everything from
        one frame before the force first reaches 2.5 N, the recording after the peak too
        (None before that force). ``"contact"``: None, the selection's ``[start, peak]``.
        """
        if self.name != "dataset":
            return None
        pressed = np.flatnonzero(np.asarray(forces_n) >= DATASET_PRESS_FORCE_N)
        return max(int(pressed[0]) - 1, 0) if pressed.size else None


DEFAULT_ESTIMATOR = AnalyticalEstimator("dataset")
"""The public dataset's own estimator: what trees in the dataset's layout, the generator and
``record`` store, and what a store that names no estimator is taken to hold."""


@dataclass(frozen=True)
class SensorUnits:
    """How the depth maps under a grasp's analytical estimates were made.

    The estimates count contact pixels and read depths, so their values depend on the depth
    model and the pixel density: estimates of a Mini with its calibrated model at
    12.5 px/mm are not in the units of the public dataset's Wedge. Each grasp records it
    (:class:`GraspUnits`, in its raw directory and its store rows), checkpoints copy it, and
    inference compares it with the data it runs on (``RunInputs.check_sensor``).

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
        dataset = self.depth_model == "dataset"
        model = "the dataset's depth heuristic" if dataset else "a calibrated depth model"
        pixels = (
            "the Wedge's pixel density" if self.px_per_mm is None else f"{self.px_per_mm:.4g} px/mm"
        )
        return f"{model} at {pixels}"

    def same(self, other: SensorUnits) -> bool:
        """Whether ``other`` is the same depth model at the same pixel density (1e-6)."""
        same_px = (self.px_per_mm is None and other.px_per_mm is None) or (
            self.px_per_mm is not None
            and other.px_per_mm is not None
            and math.isclose(self.px_per_mm, other.px_per_mm, rel_tol=1e-6)
        )
        return self.depth_model == other.depth_model and same_px

    def check_same(self, other: SensorUnits, *, trained: str, used: str) -> None:
        """Raise when estimates made with ``other`` would not be in this one's units.

        Raises:
            ValueError: another depth model or pixel density, naming both.
        """
        if not self.same(other):
            raise ValueError(
                f"{trained} has analytical estimates from {self.describe()}, {used} from "
                f"{other.describe()}: the estimates would be in other units; use a model "
                "trained on this sensor's recordings, or inputs without estimates"
            )


WEDGE_UNITS = SensorUnits()
"""The public dataset's units: its depth heuristic at the Wedge's pixel density."""


@dataclass(frozen=True)
class GraspUnits:
    """What one grasp's analytical estimates were made with: the raw layout keeps it in
    each grasp directory (``data.raw_layout.UNITS_FILE``) and a store in each of its rows
    (``data.store.UNIT_COLUMNS``), so merging or deleting files cannot relabel a grasp.
    Checkpoints keep the two parts apart (``RunInputs.sensor``, ``RunInputs.estimator``).

    Attributes:
        sensor: depth model and pixel density (``physics.estimators.SensorUnits``).
        estimator: the analytical estimator's name (``physics.estimators``).
        rig_stiffness_n_per_m: the rig stiffness [N/m] the grasp's rig-corrected
            estimates were made with (``contact.rig_corrected_widths_m``); None: the grasp
            has no rig-corrected estimates.
    """

    sensor: SensorUnits = WEDGE_UNITS
    estimator: str = DEFAULT_ESTIMATOR.name
    rig_stiffness_n_per_m: float | None = None

    def __post_init__(self) -> None:
        AnalyticalEstimator(self.estimator)  # ValueError: unknown estimator
        k = self.rig_stiffness_n_per_m
        if k is not None:
            if not (isinstance(k, (int, float)) and math.isfinite(k) and k > 0):
                raise ValueError(f"rig_stiffness_n_per_m {k!r} in the units is not a stiffness")
            object.__setattr__(self, "rig_stiffness_n_per_m", float(k))

    def to_dict(self) -> dict[str, Any]:
        """The ``units.json`` fields; ``rig_stiffness_n_per_m`` only when set, so grasps
        without rig-corrected estimates keep the file they always had."""
        data = {**self.sensor.to_dict(), "analytical_estimator": self.estimator}
        if self.rig_stiffness_n_per_m is not None:
            data["rig_stiffness_n_per_m"] = self.rig_stiffness_n_per_m
        return data

    def to_row(self) -> tuple[str, str, float, float]:
        """(estimator, depth model, px/mm, rig stiffness N/m; NaN: the estimator's own
        density, no rig-corrected estimates), a store row's unit columns in their order
        (``data.store.UNIT_COLUMNS``)."""
        px, k = self.sensor.px_per_mm, self.rig_stiffness_n_per_m
        return (
            self.estimator,
            self.sensor.depth_model,
            math.nan if px is None else float(px),
            math.nan if k is None else k,
        )

    @classmethod
    def from_dict(cls, data: Any) -> GraspUnits:
        """Read :meth:`to_dict` (ValueError: not a mapping, a field missing or invalid)."""
        if not isinstance(data, dict) or not {"depth_model", "analytical_estimator"} <= set(data):
            raise ValueError("expected depth_model, px_per_mm and analytical_estimator")
        return cls(
            SensorUnits.from_dict(data),
            str(data["analytical_estimator"]),
            data.get("rig_stiffness_n_per_m"),
        )

    def describe(self) -> str:
        """E.g. ``the dataset estimator on a calibrated depth model at 11 px/mm``, plus
        ``, rig-corrected for a 3440 N/m rig`` when it has rig-corrected estimates."""
        text = f"the {self.estimator} estimator on {self.sensor.describe()}"
        if self.rig_stiffness_n_per_m is not None:
            text += f", rig-corrected for a {self.rig_stiffness_n_per_m:.4g} N/m rig"
        return text


DATASET_UNITS = GraspUnits()
"""The public dataset's grasps (which name no units): its estimator on :data:`WEDGE_UNITS`."""
