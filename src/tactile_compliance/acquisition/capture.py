"""Capture one grasp from a frame source and its robot readings, and check its first frame.

What ``record`` and ``estimate`` share before either computes anything (docs/inference.md,
"Record and train on your own objects").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tactile_compliance.acquisition.calibration import SensorCalibration
from tactile_compliance.acquisition.first_frame import check_recording, reference_frame, same_replay
from tactile_compliance.acquisition.readings import (
    ReadingError,
    ReadingsCallback,
    checked_reading,
    milliseconds_check,
)
from tactile_compliance.acquisition.sensors import FrameError, FrameSourceBase, iter_frames
from tactile_compliance.data.frame_selection import MIN_PEAK_FORCE_N

__all__ = ["CapturedGrasp", "capture_checked", "capture_grasp"]


@dataclass
class CapturedGrasp:
    """Every good frame of one grasp with its readings.

    Attributes:
        timestamp_s: (T,) frame times in s.
        frames: (T, H, W, 3) uint8 BGR sensor frames.
        force_n: (T,) N; width_m: (T,) m, interpolated to the frame times.
        markers_frames: (T, H', W', 3) uint8 BGR of a second (marker) sensor, or None.
        skipped: one line per frame left out (bad frame, no reading).
        interrupted: the capture was stopped with Ctrl-C (what came before is kept).
    """

    timestamp_s: np.ndarray
    frames: np.ndarray
    force_n: np.ndarray
    width_m: np.ndarray
    markers_frames: np.ndarray | None = None
    skipped: list[str] = field(default_factory=list)
    interrupted: bool = False

    def __len__(self) -> int:
        return int(self.timestamp_s.size)


def capture_grasp(
    source: FrameSourceBase,
    readings: ReadingsCallback,
    *,
    markers_source: FrameSourceBase | None = None,
    max_frames: int | None = None,
    stop_on_release: bool = True,
    release_fraction: float = 0.5,
    min_peak_force_n: float = MIN_PEAK_FORCE_N,
) -> CapturedGrasp:
    """Read frames and readings until the source ends, the grasp is released (the
    streaming estimator's rule), ``max_frames`` good frames are in, or Ctrl-C. Bad frames
    and frames without a reading are skipped and listed.

    Args:
        markers_source: a second sensor (the marker finger), read in lockstep: its i-th
            frame pairs with the first sensor's i-th.
    """
    kept: list[tuple[float, np.ndarray, float, float, np.ndarray | None]] = []
    skipped: list[str] = []
    interrupted = False
    f_max = -math.inf

    units_decided = False
    try:
        for timestamp_s, frame in iter_frames(source, lambda err: skipped.append(str(err))):
            if not units_decided:  # milliseconds for seconds: every force would be wrong
                problem, units_decided = milliseconds_check(readings, timestamp_s)
                if problem:
                    raise ValueError(problem)
            marker = None
            if markers_source is not None:
                try:
                    item = markers_source.read()
                except FrameError as err:
                    skipped.append(f"markers sensor: {err}")
                    continue
                if item is None:
                    break
                marker = item[1]
            try:
                force, width = checked_reading(readings, timestamp_s)
            except ReadingError as err:
                skipped.append(f"frame at {timestamp_s:.4f} s: {err}")
                continue
            kept.append((timestamp_s, frame, force, width, marker))
            f_max = max(f_max, force)
            if stop_on_release and f_max >= min_peak_force_n and force < release_fraction * f_max:
                break
            if max_frames is not None and len(kept) >= max_frames:
                break
    except KeyboardInterrupt:
        interrupted = True
    if not kept:
        why = f" ({len(skipped)} skipped; first: {skipped[0]})" if skipped else ""
        raise ValueError(f"{source.name}: no usable frame was recorded{why}")
    times, frames, forces, widths, markers = zip(*kept, strict=True)
    return CapturedGrasp(
        timestamp_s=np.asarray(times),
        frames=np.stack(frames),
        force_n=np.asarray(forces),
        width_m=np.asarray(widths),
        markers_frames=None if markers_source is None else np.stack(markers),
        skipped=skipped,
        interrupted=interrupted,
    )


def capture_checked(
    source: FrameSourceBase,
    readings: ReadingsCallback,
    *,
    calibration: SensorCalibration | None = None,
    reference: np.ndarray | None = None,
    markers_source: FrameSourceBase | None = None,
    max_frames: int | None = None,
    stop_on_release: bool = True,
    remedy: str = "--reference IMAGE, or a --calibration recorded before the grasp",
) -> tuple[CapturedGrasp, np.ndarray, list[str], dict[str, Any]]:
    """Capture one grasp (:func:`capture_grasp`), pick its no-contact reference
    (``reference``, else the calibration's, else the first frame) and check the readings
    and the reference (:func:`check_recording`): what ``record`` and ``estimate`` share.

    Returns:
        (the capture, the reference used (H, W, 3) uint8, warnings, the numbers behind them).

    Raises:
        FrameSizeError: ``reference`` fits neither the camera nor the sensor frames.
        ValueError: no usable frame.
    """
    if reference is not None and calibration is not None:  # a bad size: fail before capturing
        reference = reference_frame(reference, source.geometry, (*calibration.frame_size, 3))
    captured = capture_grasp(
        source,
        readings,
        markers_source=markers_source,
        max_frames=max_frames,
        stop_on_release=stop_on_release,
    )
    if reference is not None:
        kind = "--reference"
        used = reference_frame(reference, source.geometry, captured.frames.shape[1:])
    elif calibration is not None:
        used, kind = calibration.reference, "calibration"
    else:
        used, kind = captured.frames[0], "first frame"
    if used.shape != captured.frames.shape[1:]:  # write_grasp refuses it with the sizes
        warnings, checks = [], {"reference": kind}
    else:
        warnings, checks = check_recording(
            readings,
            captured.timestamp_s,
            captured.force_n,
            captured.frames[0],
            used,
            kind,
            reference_from_start=kind == "calibration" and same_replay(calibration, source),
            remedy=remedy,
        )
    return captured, used, warnings, checks
