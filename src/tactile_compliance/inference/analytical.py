"""The analytical estimates streamed without a model (``live SOURCE`` with no checkpoint):
:class:`StreamingEstimator`'s frame selection, window and release rule, and the
estimates of ``acquisition.recording.grasp_estimates`` instead of a prediction. See
docs/inference.md, "A model-free estimate".
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from tactile_compliance.data.frame_selection import FrameSelection
from tactile_compliance.inference.streaming import StreamingEstimator
from tactile_compliance.physics.estimators import AnalyticalEstimator

__all__ = ["AnalyticalEstimate", "AnalyticalStream"]


@dataclass(frozen=True)
class AnalyticalEstimate:
    """One estimate of an :class:`AnalyticalStream` (the fields of ``StreamEstimate``,
    with the two analytical estimates in place of a model's one).

    Attributes:
        estimates_pa: (elastic E, Hertz E*) in Pa, in the units of the stream's estimator.
        rig_corrected_pa: the same with the rig's own closure taken out of the widths (NaN
            where not estimable), from the same frames; None for a stream without a rig.
        frame_indices, onset_frame, peak_frame, frames_seen, final, force_n, width_m,
        window, frame_times_s, window_s: as ``streaming.StreamEstimate``'s.
    """

    estimates_pa: tuple[float, float]
    frame_indices: tuple[int, int, int]
    onset_frame: int
    peak_frame: int
    frames_seen: int
    final: bool
    force_n: tuple[float, float, float]
    width_m: tuple[float, float, float] | None
    window: int | None
    frame_times_s: tuple[float, float, float] | None = None
    window_s: float | None = None
    rig_corrected_pa: tuple[float, float] | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly dict (lists for tuples), with ``elastic_pa`` and ``hertz_pa``; a
        rig-corrected estimate that could not be made is None."""
        data = {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}
        data["elastic_pa"], data["hertz_pa"] = self.estimates_pa
        if self.rig_corrected_pa is not None:
            data["rig_corrected_pa"] = [None if math.isnan(v) else v for v in self.rig_corrected_pa]
        return data


class _NoModel:
    """The model of a stream without one: it takes the force, the width and the estimates
    (so the stream asks for widths and computes the estimates from the depth maps)."""

    required_inputs = ("force", "width", "estimates")


class AnalyticalStream(StreamingEstimator):
    """Frames, readings and depth maps one at a time; the analytical estimates as soon as
    the dataset's frame rule allows, refined while the peak moves, final on release.

    The final estimate is the one ``estimate`` (and ``record``) computes for the same
    frames: the dataset's estimator gets everything since the press began.

    Args:
        analytical_estimator: the estimator (``recording.recording_estimator(calibration)``).
        rig_stiffness_n_per_m: the rig's stiffness [N/m] (``calibrate-rig``): each estimate
            also carries the rig-corrected pair, as ``estimate --rig`` computes it.
        options: ``StreamingEstimator``'s (window, window_s, frame_kind, release_fraction,
            ...); ``depth_mm`` must come with every update.
    """

    def __init__(
        self,
        analytical_estimator: AnalyticalEstimator,
        rig_stiffness_n_per_m: float | None = None,
        **options: Any,
    ) -> None:
        super().__init__(_NoModel(), analytical_estimator=analytical_estimator, **options)  # type: ignore[arg-type]
        self.rig_stiffness_n_per_m = rig_stiffness_n_per_m

    def _takes_missing_estimates(self) -> bool:
        return False  # the estimates are the result: it waits until they can be made

    def _rig_corrected(self, selection: FrameSelection, final: bool) -> tuple[float, float]:
        forces, widths, depths = self._estimation_series(selection, final)
        try:
            values = self.analytical_estimator.estimate(
                forces, widths, depths, rig_stiffness_n_per_m=self.rig_stiffness_n_per_m
            )
        except ValueError:
            return (math.nan, math.nan)  # as recording.grasp_estimates: no estimate
        return (float(values[0]), float(values[1]))

    def _predict(
        self, selection: FrameSelection, analytical: dict[str, np.ndarray], final: bool
    ) -> AnalyticalEstimate:  # type: ignore[override]
        estimates = analytical["estimates"]  # _estimate waits until both are finite
        idx, buf = selection.indices, self._buffer
        widths = tuple(float(buf.widths[i]) for i in idx)
        return AnalyticalEstimate(
            estimates_pa=(float(estimates[0]), float(estimates[1])),
            frame_indices=idx,
            onset_frame=selection.onset,
            peak_frame=selection.peak,
            frames_seen=self.frames_seen,
            final=final,
            force_n=tuple(float(buf.forces[i]) for i in idx),  # type: ignore[arg-type]
            width_m=None if any(math.isnan(w) for w in widths) else widths,  # type: ignore[arg-type]
            window=self.window,
            frame_times_s=selection.times_s,
            window_s=self.window_s,
            rig_corrected_pa=None
            if self.rig_stiffness_n_per_m is None
            else self._rig_corrected(selection, final),
        )
