"""The robot's force and width readings of a grasp: a CSV read once (:class:`Readings`), or
followed while the robot writes it (:class:`FollowedReadings`), and which of the two a
source takes (:func:`source_readings`). ``record``, ``estimate`` and ``live`` read them
(docs/inference.md, "Real readings")."""

from __future__ import annotations

import csv
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from tactile_compliance.data.force_readings import (
    ForceBaseline,
    ForceSpike,
    find_force_spikes,
    force_baseline,
)
from tactile_compliance.outputs import atomic_file

__all__ = [
    "READINGS_COLUMNS",
    "FollowedReadings",
    "ReadingError",
    "Readings",
    "ReadingsCallback",
    "checked_reading",
    "milliseconds_check",
    "recorded_readings",
    "source_readings",
    "write_readings_csv",
]

READINGS_COLUMNS = ["timestamp_s", "force_n", "width_m"]  # s, N, m

ReadingsCallback = Callable[[float], tuple[float, float]]
"""``timestamp_s -> (force_n, width_m)``; raise :class:`ReadingError` for no reading."""


class ReadingError(ValueError):
    """No force/width reading for a frame (outside the readings' time range)."""


# ---------------------------------------------------------------------- readings
@dataclass
class Readings:
    """Timestamped force and width readings from the robot, interpolated to frame times;
    spikes replaced, the baseline estimated (docs/inference.md, "Real readings").

    Attributes:
        timestamp_s: (N,) reading times in s, strictly increasing, on the frames' clock.
        force_n: (N,) normal force in N (spikes replaced).
        width_m: (N,) gripper width in m.
        tolerance_s: how far outside ``[timestamp_s[0], timestamp_s[-1]]`` a frame may lie
            and still take the nearest reading (default 0: none).
        raw_force_n: (N,) the force as given, spikes included.
        spikes: the readings replaced as single-frame spikes.
        baseline: the no-contact force level and its noise.
    """

    timestamp_s: np.ndarray
    force_n: np.ndarray
    width_m: np.ndarray
    tolerance_s: float = 0.0
    raw_force_n: np.ndarray = field(init=False, repr=False)
    spikes: list[ForceSpike] = field(init=False)
    baseline: ForceBaseline = field(init=False)

    def __post_init__(self) -> None:
        self.timestamp_s = np.asarray(self.timestamp_s, dtype=np.float64).reshape(-1)
        self.force_n = np.asarray(self.force_n, dtype=np.float64).reshape(-1)
        self.width_m = np.asarray(self.width_m, dtype=np.float64).reshape(-1)
        n = self.timestamp_s.size
        if n == 0 or self.force_n.size != n or self.width_m.size != n:
            raise ValueError(
                f"readings need as many times, forces and widths (>= 1), got {n}, "
                f"{self.force_n.size}, {self.width_m.size}"
            )
        for name in ("timestamp_s", "force_n", "width_m"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise ValueError(f"readings: {name} holds NaN or infinite values")
        if n > 1 and np.any(np.diff(self.timestamp_s) <= 0):
            i = int(np.flatnonzero(np.diff(self.timestamp_s) <= 0)[0]) + 1
            raise ValueError(
                f"readings: timestamps must increase; reading {i} at "
                f"{self.timestamp_s[i]:.4f} s follows {self.timestamp_s[i - 1]:.4f} s"
            )
        self.raw_force_n = self.force_n
        self.force_n, self.spikes = find_force_spikes(self.raw_force_n, self.timestamp_s)
        # Reported, not subtracted: why in docs/inference.md, "Real readings".
        self.baseline = force_baseline(self.force_n)

    @classmethod
    def from_csv(cls, path: str | Path, tolerance_s: float = 0.0) -> Readings:
        """Read a CSV with columns ``timestamp_s,force_n,width_m`` (s, N, m).

        Raises:
            ValueError: not such a CSV, or bad values. OSError: the file cannot be read.
        """
        path = Path(path)
        table = _readings_table(path)
        if table is None:
            raise ValueError(f"{path}: not a readings CSV (the file is empty)")
        try:
            values = table.astype(np.float64)
            return cls(*(values[c].to_numpy() for c in READINGS_COLUMNS), tolerance_s=tolerance_s)
        except ValueError as err:
            raise ValueError(f"{path}: {err}") from err

    def __call__(self, timestamp_s: float) -> tuple[float, float]:
        """(force_n, width_m) at ``timestamp_s``, linearly interpolated.

        Raises:
            ReadingError: the time lies outside the readings (beyond ``tolerance_s``).
        """
        t = float(timestamp_s)
        lo, hi = self.timestamp_s[0], self.timestamp_s[-1]
        if not (lo - self.tolerance_s <= t <= hi + self.tolerance_s):
            raise ReadingError(
                f"no force/width reading at {t:.4f} s (readings cover {lo:.4f}..{hi:.4f} s)"
            )
        return (
            float(np.interp(t, self.timestamp_s, self.force_n)),
            float(np.interp(t, self.timestamp_s, self.width_m)),
        )


def _readings_table(path: Path) -> pd.DataFrame | None:
    """The :data:`READINGS_COLUMNS` of a readings CSV as read (None: the file is empty)."""
    try:
        table = pd.read_csv(path)
    except pd.errors.EmptyDataError:
        return None
    except (pd.errors.ParserError, UnicodeDecodeError) as err:
        raise ValueError(f"{path}: not a readings CSV ({err})") from err
    table.columns = [str(c).strip() for c in table.columns]
    missing = [c for c in READINGS_COLUMNS if c not in table.columns]
    if missing:
        expected = ",".join(READINGS_COLUMNS)
        header = str(table.columns[0]) if len(table.columns) == 1 else ""
        separator = next((sep for sep in (";", "\t", "|") if sep in header), None)
        if separator is not None:  # one column holding the whole header: another separator
            shown = {";": "';'", "\t": "tabs", "|": "'|'"}[separator]
            raise ValueError(
                f"{path}: its columns are separated by {shown}, not commas; write it as "
                f"{expected} (comma-separated, '.' decimals)"
            )
        raise ValueError(f"{path}: missing column(s) {missing}; expected {expected}")
    return table[READINGS_COLUMNS]


class FollowedReadings:
    """Readings from a CSV that the robot is still writing: a frame waits up to ``wait_s``
    s for a reading at or after its time (docs/inference.md, "``live``"). The file may not
    exist yet when the capture starts.

    An incomplete last line (the robot mid-write) is ignored until it is complete; a
    non-number in any other row is a ``ValueError``. A frame with no reading at or after
    its time within ``wait_s`` is a :class:`ReadingError` for that frame only.
    """

    def __init__(self, path: str | Path, wait_s: float = 1.0, tolerance_s: float = 0.0) -> None:
        self.path = Path(path)
        self.wait_s = float(wait_s)
        self.tolerance_s = float(tolerance_s)
        self.readings: Readings | None = None
        self._stamp: tuple[int, int] | None = None
        self._load()

    def _load(self) -> None:
        try:
            stat = self.path.stat()
        except FileNotFoundError:
            return
        stamp = (stat.st_mtime_ns, stat.st_size)
        if stamp == self._stamp:
            return
        table = _readings_table(self.path)
        if table is None:
            return
        values = table.apply(pd.to_numeric, errors="coerce")
        complete = values.notna().all(axis=1).to_numpy()
        n = len(complete)
        if not complete.all():
            first = int(np.argmin(complete))
            # Only the last line may be incomplete (the robot mid-write); others are errors.
            if first < n - 1:
                raise ValueError(f"{self.path}: row {first + 1} holds a value that is not a number")
            n -= 1
        self._stamp = stamp
        if n:
            arrays = (values[c].to_numpy()[:n] for c in READINGS_COLUMNS)
            self.readings = Readings(*arrays, tolerance_s=self.tolerance_s)

    @property
    def spikes(self) -> list[ForceSpike]:
        """Spikes replaced in the log so far (the newest reading is judged once the next
        one is there)."""
        return [] if self.readings is None else self.readings.spikes

    @property
    def baseline(self) -> ForceBaseline | None:
        """The no-contact baseline of the log so far (None before the first reading)."""
        return None if self.readings is None else self.readings.baseline

    def __call__(self, timestamp_s: float) -> tuple[float, float]:
        """(force_n, width_m) at ``timestamp_s``, waiting for the robot's log to reach it."""
        deadline = time.monotonic() + self.wait_s
        while True:
            readings = self.readings
            if readings is not None and timestamp_s <= readings.timestamp_s[-1] + self.tolerance_s:
                return readings(timestamp_s)
            if time.monotonic() >= deadline:
                last = "none yet" if readings is None else f"{readings.timestamp_s[-1]:.4f} s"
                raise ReadingError(
                    f"no force/width reading at {timestamp_s:.4f} s in {self.path} after "
                    f"waiting {self.wait_s:g} s (last reading: {last})"
                )
            time.sleep(0.005)
            self._load()


#: Readings at least this far apart (median, s) over at least ``_MS_MIN_READINGS`` readings,
#: whose times divided by 1000 cover the frames' times, are stamped in milliseconds: a
#: force log runs at 10 Hz or more, so 1 s between readings is 1 kHz in milliseconds.
_MS_MIN_STEP_S = 1.0
_MS_MIN_READINGS = 5


def milliseconds_check(readings: Any, frame_time_s: float) -> tuple[str | None, bool]:
    """``(problem, decided)``: whether the readings' timestamps look like milliseconds next
    to a frame stamped ``frame_time_s`` seconds (None: they do not), and whether that is
    decided (False while a followed log holds too few readings to tell)."""
    if isinstance(readings, FollowedReadings):
        inner = readings.readings
        times = None if inner is None else inner.timestamp_s
        if times is None or times.size < _MS_MIN_READINGS:
            return None, False
    else:
        times = getattr(readings, "timestamp_s", None)
        if times is None:
            return None, True  # a callback: nothing to look at
    times = np.asarray(times, dtype=np.float64)
    if times.size < _MS_MIN_READINGS:
        return None, True
    step = float(np.median(np.diff(times)))
    lo, hi = float(times[0]), float(times[-1])
    slack = (hi - lo) / 1000.0
    t = float(frame_time_s)
    if step >= _MS_MIN_STEP_S and lo / 1000.0 - slack <= t <= hi / 1000.0 + slack:
        return (
            f"--readings: timestamps look like milliseconds; give seconds (the readings lie "
            f"{step:g} apart and cover {lo:.6g}..{hi:.6g}, about 1000 times the frames' "
            f"time {t:.4g} s)"
        ), True
    return None, True


def checked_reading(readings: ReadingsCallback, timestamp_s: float) -> tuple[float, float]:
    """A callback's reading, checked: two finite numbers (N, m)."""
    force, width = readings(timestamp_s)
    force, width = float(force), float(width)
    if not (math.isfinite(force) and math.isfinite(width)):
        raise ReadingError(f"reading at {timestamp_s:.4f} s is not finite ({force}, {width})")
    return force, width


def write_readings_csv(path: str | Path, timestamp_s: Any, force_n: Any, width_m: Any) -> Path:
    """Write readings as ``timestamp_s,force_n,width_m`` (the CSV ``record`` reads)."""
    path = Path(path)
    with atomic_file(path, "w") as handle:
        writer = csv.writer(handle)
        writer.writerow(READINGS_COLUMNS)
        for row in zip(timestamp_s, force_n, width_m, strict=True):
            writer.writerow([repr(float(v)) for v in row])
    return path


def source_readings(path: Path | None, source: Any) -> Readings | FollowedReadings:
    """The readings of a grasp that ``source`` (an open frame source) streams: the
    ``--readings`` CSV at ``path`` read once for a replay, followed while the robot writes
    it for a live device (each frame waits up to 1 s for its reading), or the bag's own
    readings when the source is a ``rosbag:`` (which carries them).

    Raises:
        ValueError: no ``path`` (except for a bag), a ``path`` as well as a bag's readings,
            a live device's ``path`` whose folder does not exist, or a bad CSV (see
            :func:`recorded_readings`).
    """
    bag_readings = getattr(source, "readings_arrays", None)  # a rosbag: source
    if bag_readings is not None:
        if path is not None:
            raise ValueError(
                f"--readings {path}: the source {source.name} carries its own force and "
                "width topics; give one or the other"
            )
        try:
            return Readings(*bag_readings)
        except ValueError as err:
            raise ValueError(f"{source.name}: {err}") from err
    if path is None:
        raise ValueError(
            "--readings CSV is required (timestamp_s,force_n,width_m), except for a "
            "rosbag: source, which carries them"
        )
    if source.live:  # the robot may create the file after the start; its folder must exist
        if not path.parent.is_dir():
            raise ValueError(f"--readings {path}: no such folder: {path.parent}")
        return FollowedReadings(path)
    return recorded_readings(path)


def recorded_readings(path: Path | None) -> Readings:
    """The recorded readings CSV at ``path``, read once (``live none``: no frame source).

    Raises:
        ValueError: no ``path``, no such file, or not a readings CSV (the message starts
            with ``--readings``).
    """
    if path is None:
        raise ValueError("--readings CSV is required (timestamp_s,force_n,width_m)")
    if not path.is_file():
        raise ValueError(f"--readings {path}: no such file")
    try:
        return Readings.from_csv(path)
    except (OSError, ValueError) as err:
        raise ValueError(f"--readings: {err}") from err
