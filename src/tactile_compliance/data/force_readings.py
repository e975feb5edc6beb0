"""Real force readings as a robot logs them: single-frame spikes, the no-contact baseline,
and whether a recording starts in contact (pure functions, applied by
``acquisition.readings.Readings`` for ``record`` and ``live``).

See docs/inference.md, "Real readings: spikes, baselines, a start in contact".
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

__all__ = [
    "BASELINE_WARN_N",
    "CONTACT_MARGIN_N",
    "ForceBaseline",
    "ForceSpike",
    "find_force_spikes",
    "force_baseline",
]

SPIKE_MIN_N = 2.0
"""A spike deviates from both neighbours by at least this much [N] ... """

SPIKE_PEAK_FRACTION = 0.05
"""... and by at least this share of the recording's (spike-free) peak force. On the 15
real grasps the largest same-sign deviation of a reading from both neighbours is 0.61 N
(at a 19 N peak), so 2 N leaves a margin of 3x; a 60 N grasp needs 3 N."""

QUIET_RANGE_N = 0.25
"""An end of the recording is flat (no contact change) if its readings span at most this
[N]: the real rig's readings of an empty gripper vary by 0.01-0.06 N over 4 frames, the
generator's noise (sd 0.05 N) spans about 0.1 N."""

BASELINE_SEGMENT = 4
"""Readings at each end that the baseline is taken from (0.13 s at 30 fps)."""

MAX_BASELINE_N = 2.5
"""A flat end above this [N] is a hold in contact, not an offset (the dataset's estimator
starts the press at 2.5 N)."""

CONTACT_MARGIN_N = 0.1
"""A reading this far [N] above the baseline (or 5 noise sd, if more) is in contact. On the
real grasps the first reading of the 7 recordings that start without contact lies
0.00-0.03 N above the baseline; of the 8 that start in contact, 0.11-1.10 N."""

BASELINE_WARN_N = 0.5
"""A baseline beyond +-0.5 N (10 % of the 5 N onset force) is reported as a warning."""


@dataclass(frozen=True)
class ForceSpike:
    """One reading replaced as a single-frame spike.

    Attributes:
        index: the reading's index (for a CSV with one reading per frame, the frame's).
        timestamp_s: its time [s] (None when the series has no times).
        force_n: the value read [N].
        replaced_n: the value used instead [N]: the median of its neighbours.
    """

    index: int
    timestamp_s: float | None
    force_n: float
    replaced_n: float

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly dict."""
        return asdict(self)

    def describe(self, frame: int | None = None) -> str:
        """One line: where, what was read and what is used instead."""
        when = "" if self.timestamp_s is None else f" at {self.timestamp_s:.4f} s"
        at_frame = "" if frame is None else f", frame {frame}"
        return (
            f"force spike in reading {self.index}{when}{at_frame}: {self.force_n:.2f} N "
            f"replaced by {self.replaced_n:.2f} N (the median of its neighbours)"
        )


@dataclass(frozen=True)
class ForceBaseline:
    """The no-contact level of a force series, from its flat ends.

    Attributes:
        start_n, end_n: median of the first / last :data:`BASELINE_SEGMENT` readings when
            that end is flat and below :data:`MAX_BASELINE_N`, else None.
        baseline_n: the lower of the two (contact only adds compressive force, so the
            higher end is the one in contact or the one the zero drifted from); None when
            neither end is flat.
        noise_n: robust sd [N] of the flat ends' readings around their medians (0 if none).
        lowest_n: the lowest reading [N]; no reading of an empty gripper lies much below
            the baseline, so contact is judged against it when neither end is flat.
    """

    start_n: float | None
    end_n: float | None
    baseline_n: float | None
    noise_n: float
    lowest_n: float

    @property
    def margin_n(self) -> float:
        """How far above the baseline a reading counts as contact [N]."""
        return max(CONTACT_MARGIN_N, 5.0 * self.noise_n)

    @property
    def level_n(self) -> float:
        """The no-contact level contact is judged against [N]: the baseline, or the
        lowest reading when the baseline is unknown."""
        return self.lowest_n if self.baseline_n is None else self.baseline_n

    def contact_n(self, force_n: float) -> float | None:
        """How far ``force_n`` lies above :attr:`level_n` when that means contact, else
        None."""
        above = float(force_n) - self.level_n
        return above if above > self.margin_n else None

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly dict."""
        return {
            "baseline_n": self.baseline_n,
            "start_n": self.start_n,
            "end_n": self.end_n,
            "noise_n": self.noise_n,
            "lowest_n": self.lowest_n,
            "subtracted": False,
        }

    def describe(self) -> str:
        """One line for reports."""
        if self.baseline_n is None:
            return (
                "no-contact force baseline unknown (neither end of the readings is flat; "
                f"lowest reading {self.lowest_n:+.2f} N)"
            )
        ends = ", ".join(
            f"{name} {value:+.2f} N"
            for name, value in (("start", self.start_n), ("end", self.end_n))
            if value is not None
        )
        return f"no-contact force baseline {self.baseline_n:+.2f} N ({ends}; not subtracted)"


def _flat_level(segment: np.ndarray) -> tuple[float | None, np.ndarray]:
    if segment.size < 2 or np.ptp(segment) > QUIET_RANGE_N:
        return None, segment[:0]
    level = float(np.median(segment))
    if abs(level) > MAX_BASELINE_N:
        return None, segment[:0]
    return level, segment - level


def force_baseline(force_n: Any) -> ForceBaseline:
    """The no-contact force level of a whole recording (see :class:`ForceBaseline`).

    Both ends are candidates: the gripper is empty before it closes and after it opens,
    and real recordings often start already in contact (then only the end is flat).
    """
    f = np.asarray(force_n, dtype=np.float64).reshape(-1)
    n = min(BASELINE_SEGMENT, f.size // 2)
    start, start_res = _flat_level(f[:n])
    end, end_res = _flat_level(f[f.size - n :] if n else f[:0])
    levels = [v for v in (start, end) if v is not None]
    residuals = np.concatenate([start_res, end_res])
    noise = float(1.4826 * np.median(np.abs(residuals))) if residuals.size else 0.0
    return ForceBaseline(
        start_n=start,
        end_n=end,
        baseline_n=min(levels) if levels else None,
        noise_n=noise,
        lowest_n=float(f.min()) if f.size else 0.0,
    )


def find_force_spikes(force_n: Any, timestamp_s: Any = None) -> tuple[np.ndarray, list[ForceSpike]]:
    """Replace single-frame spikes: ``(cleaned force [N], the spikes replaced)``.

    Reading ``i`` is a spike when it deviates from both neighbours in the same direction
    by at least ``max(SPIKE_MIN_N, SPIKE_PEAK_FRACTION x peak)`` and the neighbours agree
    with each other within half that deviation. So a step (a fast release: 24, 24, 0, 0)
    and a steep ramp are never spikes, and a reading that is off by a lot for exactly one
    frame is. It is replaced by the median of readings ``i-2, i-1, i+1, i+2`` (those that
    exist): on a straight ramp that is the linear interpolation. The first and last
    reading have only one neighbour, so a spike there cannot be told from a step and is
    left as read; so is a spike that lasts two frames or more.
    """
    f = np.asarray(force_n, dtype=np.float64).reshape(-1)
    times = None if timestamp_s is None else np.asarray(timestamp_s, dtype=np.float64).reshape(-1)
    if f.size < 3:
        return f.copy(), []
    left, right = f[1:-1] - f[:-2], f[1:-1] - f[2:]
    smallest = np.minimum(np.abs(left), np.abs(right))
    # The peak without spikes: the running median of three ignores any single reading.
    running = np.median(np.stack([f[:-2], f[1:-1], f[2:]]), axis=0)
    threshold = max(SPIKE_MIN_N, SPIKE_PEAK_FRACTION * float(np.max(np.abs(running))))
    agree = np.abs(f[2:] - f[:-2]) <= 0.5 * smallest
    spike = (np.sign(left) == np.sign(right)) & (smallest >= threshold) & agree
    cleaned = f.copy()
    spikes = []
    for i in (np.flatnonzero(spike) + 1).tolist():
        cleaned[i] = np.median([f[j] for j in (i - 2, i - 1, i + 1, i + 2) if 0 <= j < f.size])
        when = None if times is None else float(times[i])
        spikes.append(ForceSpike(i, when, float(f[i]), float(cleaned[i])))
    return cleaned, spikes
