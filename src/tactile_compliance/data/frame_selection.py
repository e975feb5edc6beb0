"""The dataset's frame-selection and time-shift augmentation rule: which frames of a grasp
recording become the three frames of each stored sample.

See docs/data.md, "How the three frames of a sample are chosen".
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from tactile_compliance.data.store import FRAMES_PER_SAMPLE

__all__ = [
    "AUGMENTATION_FORCE_FRACTION",
    "MAX_AUGMENTATIONS",
    "MIN_PEAK_FORCE_N",
    "ONSET_FORCE_N",
    "PEAK_FRACTION",
    "AugmentedSelection",
    "FrameSelection",
    "augment_selection",
    "check_window",
    "check_window_s",
    "select_frame_indices",
    "selection_window",
]

ONSET_FORCE_N = 5.0
"""Contact onset: first frame with F >= 5 N (the dataset's rule)."""

PEAK_FRACTION = 0.975
"""End of the selection: first frame with F >= 0.975 F_max (the dataset's rule)."""

MIN_PEAK_FORCE_N = 10.0
"""Grasps whose peak force stays below 10 N were skipped in the dataset."""

MAX_AUGMENTATIONS = 5
"""Augmentations per grasp at most (k = 0..4), as in the dataset."""

AUGMENTATION_FORCE_FRACTION = 0.95
"""Augmentation k exists while the force at the shifted last frame is >= 0.95 F_max."""

CONTACT_DEPTH_FRACTION = 0.075
"""A finger is in contact from the first frame with >= 7.5 % of its peak depth."""

HARD_OBJECT_PA = 5e5
"""Objects at least this stiff [Pa] stop augmenting once the first frame is nearly as deep
as the last (the published code's rule)."""

HARD_DEPTH_RATIO = 0.8
"""... 'nearly as deep': first frame's maximum depth >= 0.8 x the last frame's."""

#: Two frame times closer than this (s) to a target are equally near: the earlier frame
#: is taken, as the index rule's ``floor`` does. Far below any frame period (>= 1 ms) and
#: above the rounding of float64 timestamps on an epoch clock (~2e-7 s).
TIME_TOLERANCE_S = 1e-6


def check_window(window: int | None) -> int | None:
    """A window length (None: the whole trajectory); three frames need at least three."""
    if window is not None and (isinstance(window, bool) or int(window) < FRAMES_PER_SAMPLE):
        raise ValueError(
            f"window must be None or an integer >= {FRAMES_PER_SAMPLE}, got {window!r}"
        )
    return None if window is None else int(window)


def check_window_s(window_s: float | None) -> float | None:
    """A window length in seconds (None: the whole trajectory); must be positive."""
    if window_s is None:
        return None
    try:
        value = float(window_s)
    except (TypeError, ValueError) as err:
        raise ValueError(f"window_s must be None or a duration in s, got {window_s!r}") from err
    if not np.isfinite(value) or value <= 0 or isinstance(window_s, bool):
        raise ValueError(f"window_s must be None or a positive duration in s, got {window_s!r}")
    return value


def check_timestamps(times_s: Any, n_frames: int) -> np.ndarray:
    """(T,) finite, strictly increasing frame times in s, one per force reading."""
    times = np.asarray(times_s, dtype=np.float64).reshape(-1)
    if times.size != n_frames:
        raise ValueError(f"{n_frames} force readings but {times.size} timestamps")
    if not np.all(np.isfinite(times)):
        raise ValueError("timestamps_s must be finite (s)")
    steps = np.diff(times)
    if np.any(steps <= 0):
        bad = int(np.flatnonzero(steps <= 0)[0]) + 1
        raise ValueError(
            f"timestamps_s must increase: frame {bad} is at {times[bad]:.6f} s, frame "
            f"{bad - 1} at {times[bad - 1]:.6f} s"
        )
    return times


def _nearest_in_time(times_s: np.ndarray, start: int, stop: int, target_s: float) -> int:
    """Index in ``[start, stop]`` of the frame nearest to ``target_s``; a tie (within
    ``TIME_TOLERANCE_S``) goes to the earlier frame, like the index rule's ``floor``."""
    distance = np.abs(times_s[start : stop + 1] - target_s)
    return start + int(np.flatnonzero(distance <= distance.min() + TIME_TOLERANCE_S)[0])


@dataclass(frozen=True)
class FrameSelection:
    """The three frames chosen by the force rule (indices into the force sequence).

    Attributes:
        indices: the three frame indices, in time order.
        onset: ``i_start``, first frame with F >= the onset force.
        peak: ``i_peak``, first frame with F >= peak_fraction x F_max.
        window_start: first frame the three frames are spread over (``onset`` unless a
            window cuts it).
        times_s: timestamps (s) of the three frames when the selection was made in time,
            else None.
    """

    indices: tuple[int, int, int]
    onset: int
    peak: int
    window_start: int
    times_s: tuple[float, float, float] | None = None


def select_frame_indices(
    forces_n: Any,
    *,
    window: int | None = None,
    timestamps_s: Any = None,
    window_s: float | None = None,
    onset_force_n: float = ONSET_FORCE_N,
    peak_fraction: float = PEAK_FRACTION,
    min_peak_force_n: float = MIN_PEAK_FORCE_N,
) -> FrameSelection | None:
    """The dataset's three-frame selection on a force sequence (N), or None if not yet
    possible (docs/data.md), chosen in time with ``timestamps_s`` ((T,) s, increasing).

    ``window=n`` spreads the frames over the last ``n`` frames up to the peak (the
    streaming variant; see ``inference.streaming``), ``window_s`` (s, needs timestamps)
    over the last ``window_s`` seconds.

    None when no frame reaches ``onset_force_n``, the peak stays below
    ``min_peak_force_n``, or fewer than three frames lie between the start and the peak.
    In time, a tie goes to the earlier frame, so at a constant frame rate the timed
    selection is the index rule's.
    """
    f = np.asarray(forces_n, dtype=np.float64).reshape(-1)
    window = check_window(window)
    window_s = check_window_s(window_s)
    if window is not None and window_s is not None:
        raise ValueError("give window (frames) or window_s (seconds), not both")
    times = None if timestamps_s is None else check_timestamps(timestamps_s, f.size)
    if window_s is not None and times is None:
        raise ValueError("window_s (a window in seconds) needs the frames' timestamps_s")
    above = np.flatnonzero(f >= onset_force_n)
    if above.size == 0:
        return None
    onset = int(above[0])
    f_max = float(f[onset:].max())
    if f_max < min_peak_force_n:
        return None
    # Searching from the onset keeps i_peak >= i_start even for peaks just above 5 N.
    peak = onset + int(np.argmax(f[onset:] >= peak_fraction * f_max))
    start = onset if window is None else max(onset, peak - window + 1)
    if window_s is not None:
        assert times is not None
        inside = np.flatnonzero(times[: peak + 1] >= times[peak] - window_s - TIME_TOLERANCE_S)
        start = max(onset, int(inside[0]))
    if peak - start < FRAMES_PER_SAMPLE - 1:
        return None
    if times is None:
        # Same arithmetic as the published selection: offset + truncated linspace.
        offsets = np.linspace(0, peak - start, FRAMES_PER_SAMPLE, endpoint=True).astype(int)
        indices = tuple(int(start + o) for o in offsets)
        chosen_times = None
    else:
        # An interior frame is always nearer the middle moment than either end, so the
        # three indices are distinct whenever three frames exist.
        targets = np.linspace(times[start], times[peak], FRAMES_PER_SAMPLE, endpoint=True)
        indices = tuple(_nearest_in_time(times, start, peak, float(t)) for t in targets)
        chosen_times = tuple(float(times[i]) for i in indices)
    return FrameSelection(
        indices=indices,  # type: ignore[arg-type]
        onset=onset,
        peak=peak,
        window_start=start,
        times_s=chosen_times,  # type: ignore[arg-type]
    )


def selection_window(
    forces_n: Any, max_aug: int = MAX_AUGMENTATIONS
) -> tuple[int, int, int] | None:
    """``(i_start, i_peak + 1, i_end)``: the clip ``[i_start, i_end)`` of the recording the
    published code kept, ``i_end = min(i_peak + 1 + max_aug, T)``; None without a selection.

    The frames any augmentation can store lie in it, so a caller can compute what the
    augmentations need (e.g. depth maps) on the clip alone.
    """
    f = np.asarray(forces_n, dtype=np.float64).reshape(-1)
    selection = select_frame_indices(f)
    if selection is None:
        return None
    return selection.onset, selection.peak + 1, min(selection.peak + 1 + max_aug, f.size)


@dataclass(frozen=True)
class AugmentedSelection:
    """The frames a grasp's samples store (indices into the whole recording).

    Attributes:
        fingers: per finger (in the order of the depth maxima given; one entry, the
            unshifted selection, without depths), the three frame indices of
            augmentation 0.
        force: the three indices for forces / widths of augmentation 0.
        num_aug: number of augmentations; augmentation k adds k to every index.
        base: the three-frame selection before the contact shifts.
    """

    fingers: tuple[np.ndarray, ...]
    force: np.ndarray
    num_aug: int
    base: FrameSelection

    def augmentations(self, finger: int = 0) -> list[tuple[int, int, int]]:
        """One finger's three frame indices of each augmentation k = 0 .. num_aug - 1."""
        idx = self.fingers[finger]
        return [tuple(int(i) + k for i in idx) for k in range(self.num_aug)]  # type: ignore[misc]

    def frames_needed(self) -> np.ndarray:
        """All frame indices that some augmentation stores (any finger)."""
        shifts = np.arange(self.num_aug)
        return np.unique(np.concatenate([(v[:, None] + shifts).ravel() for v in self.fingers]))


def _contact_shift(depths_mm: np.ndarray, max_aug: int) -> int:
    """Frames from the clip's start to the first with >= 7.5 % of the clip's peak depth
    (at most ``max_aug - 1``; 0 when no such frame is that early)."""
    peak = depths_mm.max() if depths_mm.size else 0.0
    for i in range(min(max_aug, depths_mm.size)):
        if depths_mm[i] >= CONTACT_DEPTH_FRACTION * peak:
            return i
    return 0


def augment_selection(
    forces_n: Any,
    *,
    timestamps_s: Any = None,
    max_depth_mm: Sequence[Any] = (),
    modulus_pa: float | None = None,
    max_aug: int = MAX_AUGMENTATIONS,
    contact_shift: bool = True,
) -> AugmentedSelection | None:
    """The published frame selection and its time-shift augmentations (docs/data.md).

    Args:
        forces_n: (T,) measured force of the whole recording [N].
        timestamps_s: (T,) frame times [s]: augmentation 0 is then chosen in time
            (:func:`select_frame_indices`); None keeps the index rule.
        max_depth_mm: per finger, (T,) maximum depth of each frame [mm] (only the frames
            of the clip ``[i_start, i_peak + 1 + max_aug)`` are read). Without them there
            are no contact shifts and no hard-object rule.
        modulus_pa: the object's Young's modulus [Pa] (the label), for the hard-object
            rule; None: the rule does not apply.
        contact_shift: move each finger's first frame to its contact (the published
            code); False keeps the three frames of :func:`select_frame_indices` on every
            finger (one frame set per augmentation, as ``record`` writes).

    Returns:
        None when :func:`select_frame_indices` finds no selection.
    """
    f = np.asarray(forces_n, dtype=np.float64).reshape(-1)
    selection = select_frame_indices(f, timestamps_s=timestamps_s)
    window = selection_window(f, max_aug)
    if selection is None or window is None:
        return None
    onset, _, clip_end = window
    f_clip = f[onset:clip_end]
    depths = [np.asarray(d, dtype=np.float64).reshape(-1)[onset:clip_end] for d in max_depth_mm]
    base = np.asarray(selection.indices) - onset  # indices into the clip
    force_idx = base.copy()
    fingers = [base.copy() for _ in depths] or [base.copy()]
    num_aug = 1
    for k in range(1, max_aug):
        last = force_idx[-1] + k
        if last < f_clip.size and f_clip[last] >= AUGMENTATION_FORCE_FRACTION * f_clip.max():
            num_aug += 1
        else:
            break
    if depths and contact_shift:
        shifts = [_contact_shift(d, max_aug) for d in depths]
        force_idx[0] += min(shifts)
        for video, shift in zip(fingers, shifts, strict=True):
            video[0] += shift
    num_aug = min(num_aug, max(*(int(v[1] - v[0]) for v in fingers), 2))
    if min(int(v[-1] - v[0]) for v in fingers) < FRAMES_PER_SAMPLE:
        num_aug = 1
    hard = modulus_pa is not None and modulus_pa >= HARD_OBJECT_PA
    last_valid = f_clip.size - 1
    for k in range(1, num_aug):
        if max(*(int(v[-1]) for v in fingers), int(force_idx[-1])) + k > last_valid:
            num_aug = k
            break
        if (
            hard
            and depths
            and all(
                d[v[0] + k] >= HARD_DEPTH_RATIO * d[v[-1] + k]
                for d, v in zip(depths, fingers, strict=True)
            )
        ):
            num_aug = k
            break
    return AugmentedSelection(
        fingers=tuple(v + onset for v in fingers),
        force=force_idx + onset,
        num_aug=int(num_aug),
        base=selection,
    )
