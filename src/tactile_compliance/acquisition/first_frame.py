"""The checks of a recording's first frames, which ``record``, ``estimate`` and ``live``
share: the no-contact reference cut to the sensor frame (:func:`reference_frame`), whether
a calibration was taken from the very file a source replays (:func:`same_replay`), and the
warnings about the readings and the reference (:func:`check_recording`; the table in
docs/inference.md, "Real readings")."""

from __future__ import annotations

from typing import Any

import numpy as np

from tactile_compliance.acquisition.calibration import SensorCalibration
from tactile_compliance.acquisition.sensors import SPEC_KINDS, FrameSizeError, FrameSourceBase
from tactile_compliance.data.force_readings import BASELINE_WARN_N, ForceBaseline

__all__ = ["REFERENCE_MISMATCH_GREY", "check_recording", "reference_frame", "same_replay"]

# ---------------------------------------------------------------------- checks
# Mean |reference - first frame| in grey levels (0..255) beyond which the reference is of
# another session (docs/inference.md, "Real readings").
REFERENCE_MISMATCH_GREY = 8.0


def reference_frame(image: np.ndarray, geometry: Any, frame_shape: tuple[int, ...]) -> np.ndarray:
    """A no-contact image, a camera frame (``geometry``, a ``sensors.FrameGeometry``,
    applies) or a sensor frame, as a reference for frames of ``frame_shape`` (H, W, 3).

    Raises:
        FrameSizeError: it is neither.
    """
    image = np.asarray(image)
    if image.shape == tuple(frame_shape):
        return image
    try:
        frame = geometry.apply(image)
    except FrameSizeError:
        frame = None
    if frame is None or frame.shape != tuple(frame_shape):
        camera = getattr(geometry, "input_size", None)
        camera_text = "" if camera is None else f" of {camera[0]}x{camera[1]} px"
        raise FrameSizeError(
            f"the reference image is {image.shape[0]}x{image.shape[1]} px: give a camera "
            f"frame{camera_text} (the sensor geometry cuts it to "
            f"{frame_shape[0]}x{frame_shape[1]}) or a sensor frame of "
            f"{frame_shape[0]}x{frame_shape[1]} px"
        )
    return frame


def _frame_of_reading(readings: Any, index: int, frame_times: np.ndarray) -> int | None:
    """The captured frame nearest in time to reading ``index`` among those interpolated
    from it (None when no captured frame lies between its neighbouring readings)."""
    # A FollowedReadings holds the log read so far as a Readings.
    times = getattr(getattr(readings, "readings", readings), "timestamp_s", None)
    if times is None or frame_times.size == 0:
        return None
    lo = times[index - 1] if index > 0 else -np.inf
    hi = times[index + 1] if index + 1 < len(times) else np.inf
    inside = np.flatnonzero((frame_times > lo) & (frame_times < hi))
    if inside.size == 0:
        return None
    return int(inside[np.argmin(np.abs(frame_times[inside] - times[index]))])


def same_replay(calibration: SensorCalibration | None, source: FrameSourceBase) -> bool:
    """Whether ``calibration`` was recorded from the file ``source`` replays (so its
    reference is this recording's first frames)."""
    if calibration is None or source.live or not calibration.source:
        return False
    kind, sep, target = calibration.source.partition(":")
    if not (sep and kind in SPEC_KINDS):
        target = calibration.source
    return bool(target) and source.name.endswith(target)


def check_recording(
    readings: Any,
    frame_times_s: np.ndarray,
    force_n: np.ndarray,
    first_frame: np.ndarray,
    reference: np.ndarray,
    reference_kind: str,
    reference_from_start: bool = False,
    remedy: str = "--reference IMAGE, or a --calibration recorded before the grasp",
) -> tuple[list[str], dict[str, Any]]:
    """Warnings about a recording's readings and reference, and the numbers behind them
    (the table in docs/inference.md, "Real readings").

    Args:
        readings: a :class:`Readings` (or any callback; one without ``spikes`` and
            ``baseline`` is not checked).
        frame_times_s, force_n: (T,) the captured frames' times [s] and forces [N].
        first_frame, reference: (H, W, 3) uint8 BGR.
        reference_kind: where the reference came from: ``first frame``,
            ``calibration`` or ``--reference``.
        reference_from_start: the reference was taken from this recording's first
            frames (always so for ``first frame``).
        remedy: what to give instead, in the warning (``record``'s options by default).
    """
    warnings: list[str] = []
    checks: dict[str, Any] = {"reference": reference_kind, "spikes": []}
    frame_times = np.asarray(frame_times_s, dtype=np.float64)
    for spike in getattr(readings, "spikes", None) or []:
        frame = _frame_of_reading(readings, spike.index, frame_times)
        checks["spikes"].append({**spike.to_dict(), "frame": frame})
        warnings.append(spike.describe(frame))
    baseline: ForceBaseline | None = getattr(readings, "baseline", None)
    contact = None
    if baseline is not None:
        checks["baseline"] = baseline.to_dict()
        checks["baseline_text"] = baseline.describe()
        if baseline.baseline_n is not None and abs(baseline.baseline_n) > BASELINE_WARN_N:
            warnings.append(
                f"{baseline.describe()}: beyond +-{BASELINE_WARN_N:g} N it moves the 5 N "
                f"contact onset; zero the force sensor with the gripper empty"
            )
        contact = baseline.contact_n(float(force_n[0])) if len(force_n) else None
    checks["first_frame_contact_n"] = contact
    first = np.asarray(first_frame, dtype=np.float64)
    ref = np.asarray(reference, dtype=np.float64)
    difference = float(np.mean(np.abs(first - ref)))
    checks["reference_vs_first_frame_grey"] = difference
    if contact is not None and (reference_kind == "first frame" or reference_from_start):
        which = (
            "that frame is the reference"
            if reference_kind == "first frame"
            else "the calibration was taken from this recording's first frames"
        )
        warnings.append(
            f"the recording starts in contact: {float(force_n[0]):.2f} N at its first frame, "
            f"{contact:.2f} N above the no-contact level {baseline.level_n:+.2f} N; "  # type: ignore[union-attr]
            f"{which}, so the difference images and depth maps miss this "
            f"contact: give a frame with nothing touching the gel ({remedy})"
        )
    if difference > REFERENCE_MISMATCH_GREY:
        text = (
            f"the reference ({reference_kind}) differs from the first frame by "
            f"{difference:.1f} grey levels on average (frames of one session differ by a "
            f"few): is it from another session, lighting or sensor?"
        )
        swapped = float(np.mean(np.abs(first - ref[..., ::-1])))
        checks["reference_swapped_vs_first_frame_grey"] = swapped
        if swapped < 0.7 * difference:
            text += (
                f" With red and blue swapped it differs by {swapped:.1f}: it may be stored "
                f"as RGB (frames are BGR)"
            )
        warnings.append(text)
    return warnings, checks
