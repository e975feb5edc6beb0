"""The model-free estimate of a recorded grasp (``tactile-compliance estimate``): the
analytical estimates ``record`` stores, without writing anything, with how far such
estimates were from the truth on real grasps. See docs/inference.md, "A model-free
estimate".
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tactile_compliance.acquisition.calibration import SensorCalibration
from tactile_compliance.acquisition.capture import capture_checked
from tactile_compliance.acquisition.readings import ReadingsCallback
from tactile_compliance.acquisition.recording import (
    capture_notes,
    checked_selection,
    grasp_estimates,
)
from tactile_compliance.acquisition.sensors import FrameSourceBase
from tactile_compliance.physics.estimators import WEDGE_UNITS, SensorUnits

__all__ = ["REAL_WEDGE_ACCURACY", "RecordingEstimate", "accuracy_statement", "estimate_recording"]

REAL_WEDGE_ACCURACY: dict[str, Any] = {
    "sensor": "GelSight Wedge, the public dataset's rig (Franka Panda gripper)",
    "units": WEDGE_UNITS.to_dict(),
    "grasps": 15,
    "objects": 5,
    "true_range_pa": [3.19e4, 8.50e8],
    "elastic": {"within_one_decade": 9, "mae_decades": 1.33, "spearman_objects": 0.10},
    "hertz": {"within_one_decade": 8, "mae_decades": 1.63, "spearman_objects": 0.40},
    # With the rig's own closure taken out (``--rig``), the packaged rig of these grasps.
    "rig": "wedge-2023",
    "elastic_rig": {"within_one_decade": 6, "mae_decades": 1.38, "spearman_objects": 0.60},
    "hertz_rig": {"within_one_decade": 9, "mae_decades": 1.37, "spearman_objects": 0.40},
    "command": "python benchmarks/real_estimates.py",
    "docs": 'docs/results.md, "Real grasps"',
}
"""How far the analytical estimates were from the true moduli on real grasps, measured by
``benchmarks/real_estimates.py`` on the 15 Wedge grasps of
``../shared/reference-data/real/wedge-grasps`` (5 objects, 3.19e4-8.50e8 Pa; calibration
from each video's first 3 frames). ``tests/test_estimate.py`` runs the benchmark when the
data is present and fails when these numbers no longer hold. Counts are grasps; MAE is the
mean |log10 estimate - log10 true E|; Spearman ranks the objects' mean log10 estimates.
``elastic_rig`` / ``hertz_rig``: the rig-corrected estimates of the same grasps with the
``rig`` (``estimate --rig wedge-2023``), whose stiffness was fitted on the golf ball's
grasps, one of these 5 objects."""


def accuracy_statement(units: SensorUnits = WEDGE_UNITS, rig_corrected: bool = False) -> str:
    """One sentence: how good the analytical estimates were on real grasps (with
    ``rig_corrected``, the rig-corrected ones too), and whether that measurement covers
    estimates in ``units``."""
    a = REAL_WEDGE_ACCURACY
    n = a["grasps"]
    text = (
        f"on {n} real Wedge grasps of only {a['objects']} objects (true E "
        f"{a['true_range_pa'][0]:.3g}-{a['true_range_pa'][1]:.3g} Pa) the elastic estimate "
        f"was within one decade of the true E for {a['elastic']['within_one_decade']}/{n} "
        f"(mean error {a['elastic']['mae_decades']:.2f} decades), the Hertz estimate for "
        f"{a['hertz']['within_one_decade']}/{n} ({a['hertz']['mae_decades']:.2f} decades); "
        f"neither ranked the objects (a golf ball read 3-4 decades low): a rough reference, "
        f"not a measurement ({a['docs']})"
    )
    if rig_corrected:
        er, hr = a["elastic_rig"], a["hertz_rig"]
        text += (
            f"; rig-corrected with the {a['rig']} rig, the elastic estimate was within one "
            f"decade for {er['within_one_decade']}/{n} ({er['mae_decades']:.2f} decades), "
            f"the Hertz estimate for {hr['within_one_decade']}/{n} "
            f"({hr['mae_decades']:.2f} decades)"
        )
    if SensorUnits.from_dict(a["units"]) != units:
        text += (
            f". Not measured in this sensor's units ({units.describe()}): these "
            f"estimates are not comparable with the Wedge's"
        )
    return text


@dataclass
class RecordingEstimate:
    """What :func:`estimate_recording` found.

    Attributes:
        estimates_pa: (elastic E, Hertz E*) in Pa, NaN where not estimable.
        rig_corrected_pa: the same with the rig's own closure taken out of the widths
            (``estimate_recording``'s ``rig_stiffness_n_per_m``); None without a rig.
        units: the depth model and pixel density they were made with (a calibration's,
            else the public dataset's Wedge).
        frame_indices: the dataset's three frames (augmentation 0, into the capture).
        peak_force_n: the highest force of the capture [N].
        n_frames: frames captured; skipped: frames left out, with the reason.
        source: what was read (a path, device, bag).
        warnings: what looked wrong in the readings or the reference.
        checks: the numbers behind them (``first_frame.check_recording``).
    """

    estimates_pa: tuple[float, float]
    units: SensorUnits
    frame_indices: tuple[int, int, int]
    peak_force_n: float
    n_frames: int
    source: str
    skipped: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    checks: dict[str, Any] = field(default_factory=dict)
    rig_corrected_pa: tuple[float, float] | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly dict (None for an estimate that could not be made);
        ``rig_corrected_pa`` is ``[elastic, hertz]``, or None without a rig."""
        elastic, hertz = (None if math.isnan(v) else v for v in self.estimates_pa)
        rig = self.rig_corrected_pa
        return {
            "source": self.source,
            "elastic_pa": elastic,
            "hertz_pa": hertz,
            "estimates_pa": [elastic, hertz],
            "rig_corrected_pa": None
            if rig is None
            else [None if math.isnan(v) else v for v in rig],
            "units": self.units.to_dict(),
            "units_text": self.units.describe(),
            "frame_indices": list(self.frame_indices),
            "peak_force_n": self.peak_force_n,
            "n_frames": self.n_frames,
            "skipped": self.skipped,
            "accuracy": {
                **REAL_WEDGE_ACCURACY,
                "statement": accuracy_statement(self.units, rig is not None),
            },
            "warnings": self.warnings,
            "checks": self.checks,
        }

    def format(self) -> str:
        """Human-readable summary (what ``estimate`` prints)."""

        def pa(value: float) -> str:
            return "not estimable" if math.isnan(value) else f"{value:.4g} Pa"

        elastic, hertz = self.estimates_pa
        lines = [f"Estimates   elastic E {pa(elastic)}, Hertz E* {pa(hertz)}"]
        if self.rig_corrected_pa is not None:
            rig_elastic, rig_hertz = self.rig_corrected_pa
            lines.append(
                f"Rig-corrected elastic E {pa(rig_elastic)}, Hertz E* {pa(rig_hertz)} "
                "(the rig's own closure taken out)"
            )
        lines += [
            f"Units       {self.units.describe()}",
            f"Frames      {', '.join(map(str, self.frame_indices))} of {self.n_frames} "
            f"(peak force {self.peak_force_n:.1f} N)",
            f"Accuracy    {accuracy_statement(self.units, self.rig_corrected_pa is not None)}",
        ]
        lines += capture_notes(self.skipped, self.checks, self.warnings)
        return "\n".join(lines)


def estimate_recording(
    source: FrameSourceBase,
    readings: ReadingsCallback,
    *,
    calibration: SensorCalibration | None = None,
    reference: np.ndarray | None = None,
    max_frames: int | None = None,
    rig_stiffness_n_per_m: float | None = None,
) -> RecordingEstimate:
    """Capture one grasp and compute its analytical estimates, exactly as ``record``
    computes the ones it stores (``capture.capture_checked`` then
    ``recording.grasp_estimates``); nothing is written.

    Args:
        source: an open frame source (with a calibration: ``calibration.open(spec)``).
        readings: ``timestamp_s -> (force_n, width_m)``, e.g. ``Readings.from_csv(path)``
            or a bag's readings.
        calibration: the no-contact reference, depth model and px/mm (default: the first
            frame, the dataset's heuristic at the Wedge's pixel density).
        reference: a no-contact uint8 BGR camera or sensor frame; replaces the
            calibration's reference.
        rig_stiffness_n_per_m: the rig's stiffness [N/m] (``calibrate-rig``): also the
            rig-corrected estimates, as ``record --rig`` reports them.

    Raises:
        ValueError: no usable frame, no frame selection, or implausible readings.
    """
    captured, used, warnings, checks = capture_checked(
        source,
        readings,
        calibration=calibration,
        reference=reference,
        max_frames=max_frames,
    )
    selection = checked_selection(captured)
    computed = grasp_estimates(
        captured, reference=used, sensor=calibration, rig_stiffness_n_per_m=rig_stiffness_n_per_m
    )
    missing = [
        name
        for name, value in zip(("elastic", "Hertz"), computed.estimates_pa, strict=True)
        if not math.isfinite(value)
    ]
    if missing:
        warnings.append(
            f"no {' or '.join(missing)} estimate for this grasp: too little contact area or "
            "depth at this frame size and pixel density (calibrate the sensor's px/mm, "
            "docs/sensors.md)"
        )
    return RecordingEstimate(
        estimates_pa=computed.estimates_pa,
        units=computed.units,
        frame_indices=tuple(int(i) for i in selection[0]),  # type: ignore[arg-type]
        peak_force_n=float(np.max(captured.force_n)),
        n_frames=len(captured),
        source=source.name,
        skipped=list(captured.skipped),
        warnings=warnings,
        checks=checks,
        rig_corrected_pa=computed.rig_corrected_pa,
    )
