"""Physically plausible values: one set of rules (``RULES``) for the importers, the store and
the estimator; NaN means "missing" and is left to each of them.

See docs/data.md, "Plausible values: one set of rules".
"""

from __future__ import annotations

import math
import numbers
import re
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = [
    "DEPTH",
    "ESTIMATE",
    "FORCE",
    "FRAME",
    "MAX_FRAME_SIDE_PX",
    "MODULUS",
    "RULES",
    "WIDTH",
    "PlausibleRange",
    "as_real_number",
    "check_size",
    "dtype_problem",
    "format_number",
    "parse_pascals",
]

#: numpy dtype kinds that hold numbers (signed, unsigned integers, floats); everything else
#: is refused, never cast (docs/data.md, "Plausible values").
NUMERIC_KINDS = "iuf"


_PREFIXES = {"": 1.0, "k": 1e3, "M": 1e6, "G": 1e9}
_PASCALS = re.compile(r"\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([kMG]?)(Pa)?\s*")


def parse_pascals(text: str) -> float:
    """A pressure or modulus as people write it -> Pa: ``2e5``, ``204kPa``, ``204 kPa``,
    ``1.2GPa``, ``3.5e4 Pa``; a number without a unit is Pa. Only k, M and G prefixes
    (``mPa`` would be a typo for ``MPa``); the value is not range-checked here.

    Raises:
        ValueError: anything else, with the forms it takes.
    """
    match = _PASCALS.fullmatch(str(text))
    if match is None or (match.group(2) and not match.group(3)):
        raise ValueError(
            f"{text!r} is no modulus: give Pa as a number (2.5e4) or with kPa, MPa or GPa "
            f"(25kPa, 1.2 GPa)"
        )
    return float(match.group(1)) * _PREFIXES[match.group(2)]


def format_number(value: float) -> str:
    """A number as short text: ``1000``, ``0.2``, ``1e13``, ``inf``, ``-50``."""
    if math.isinf(value):
        return "inf" if value > 0 else "-inf"
    text = f"{value:.4g}"
    if "e" in text:
        mantissa, exponent = text.split("e")
        text = f"{mantissa}e{int(exponent)}"
    return text


@dataclass(frozen=True)
class PlausibleRange:
    """The physically plausible range of one quantity.

    Attributes:
        quantity: what is measured, e.g. ``"force"``.
        unit: its unit, e.g. ``"N"``.
        low, high: the bounds in ``unit``; ``high`` may be ``inf`` (then values must be
            finite).
        low_inclusive, high_inclusive: whether a value equal to the bound is plausible.
        reason: why these bounds (short, shown in reports and docs).
        tolerance: accepted beyond either bound (round-off), in ``unit``; 0 for most.
        saturated_share: the share of one sample's values that may lie outside the range
            (beyond the tolerance) without making it implausible; 0 for most. Frames: the
            few saturated pixels of a real difference image, which the store's encoding
            saturates to the range.
        limits: ``(low, high)`` that no value may cross whatever ``saturated_share``
            (inclusive; the physical limits); None: the range itself.
    """

    quantity: str
    unit: str
    low: float
    high: float
    reason: str
    low_inclusive: bool = True
    high_inclusive: bool = True
    tolerance: float = 0.0
    saturated_share: float = 0.0
    limits: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if not self.unit:
            raise ValueError(f"rule {self.quantity!r} needs a unit")
        if not self.low < self.high:
            raise ValueError(f"rule {self.quantity!r}: low {self.low} must be < high {self.high}")
        if not (self.tolerance >= 0 and math.isfinite(self.tolerance)):
            raise ValueError(f"rule {self.quantity!r}: tolerance must be finite and >= 0")
        if not 0 <= self.saturated_share < 1:
            raise ValueError(f"rule {self.quantity!r}: saturated_share must be in [0, 1)")
        if self.limits is not None and not (
            self.limits[0] <= self.low - self.tolerance
            and self.high + self.tolerance <= self.limits[1]
        ):
            raise ValueError(f"rule {self.quantity!r}: limits must contain the range")

    # ------------------------------------------------------------------ text
    def interval(self) -> str:
        """The range as text with its unit, e.g. ``[0, 1000] N`` or ``(0, inf) Pa``."""
        left = "[" if self.low_inclusive else "("
        right = "]" if self.high_inclusive and math.isfinite(self.high) else ")"
        text = f"{left}{format_number(self.low)}, {format_number(self.high)}{right} {self.unit}"
        if self.tolerance:
            text += f" ± {format_number(self.tolerance)}"
        return text

    def allowance(self) -> str | None:
        """What may lie outside the range, e.g. ``at most 1% of a sample's values may lie
        outside, none beyond [-0.5, 1.5] full scale``; None when nothing may."""
        if not self.saturated_share:
            return None
        share = format_number(100 * self.saturated_share)
        text = f"at most {share}% of a sample's values may lie outside"
        if self.limits is not None:
            low, high = (format_number(v) for v in self.limits)
            text += f", none beyond [{low}, {high}] {self.unit}"
        return text

    def lower_bound(self) -> str:
        """The lower bound as a condition, e.g. ``>= 0 N`` or ``> 0 Pa``."""
        op = ">=" if self.low_inclusive else ">"
        return f"{op} {format_number(self.low)} {self.unit}"

    def upper_bound(self) -> str | None:
        """The upper bound as a condition, e.g. ``<= 1000 N``; None when it is ``inf``."""
        if not math.isfinite(self.high):
            return None
        op = "<=" if self.high_inclusive else "<"
        return f"{op} {format_number(self.high)} {self.unit}"

    def requirement(self) -> str:
        """What a value must be, e.g. ``a finite number >= 0 N and <= 1000 N``."""
        upper = self.upper_bound()
        text = f"a finite number {self.lower_bound()}"
        return f"{text} and {upper}" if upper else text

    # ------------------------------------------------------------------ checks
    def below(self, values: Any) -> np.ndarray:
        """Element-wise: the value is under the lower bound (NaN: False)."""
        x = np.asarray(values, dtype=np.float64)
        low = self.low - self.tolerance
        with np.errstate(invalid="ignore"):
            return x < low if self.low_inclusive else x <= low

    def above(self, values: Any) -> np.ndarray:
        """Element-wise: the value is over the upper bound, or ``inf`` when the upper
        bound is ``inf`` (NaN: False)."""
        x = np.asarray(values, dtype=np.float64)
        high = self.high + self.tolerance
        with np.errstate(invalid="ignore"):
            if self.high_inclusive and math.isfinite(high):
                return x > high
            return x >= high

    def outside(self, values: Any) -> np.ndarray:
        """Element-wise: the value is outside the range (beyond the tolerance). NaN is not
        (it means missing). Without ``saturated_share`` such a value is implausible."""
        return self.below(values) | self.above(values)

    def contains(self, values: Any) -> np.ndarray:
        """Element-wise: the value is plausible. NaN is not (it is no value)."""
        x = np.asarray(values, dtype=np.float64)
        return ~np.isnan(x) & ~self.outside(x)

    def violation(self, values: Any, *, reason: bool = True) -> str | None:
        """None when the values of one sample (NaN aside) are plausible, else a message
        with the first implausible value, its unit, how many there are and the range, e.g.
        ``force -50 N is outside the plausible range [0, 1000] N (1 of 3 values): ...``.

        Plausible: every value within the range (and its tolerance), or, with
        ``saturated_share``, at most that share of the values outside it and none beyond
        :attr:`limits`. ``reason=False`` leaves the rule's reason out of the message.
        """
        array = np.asarray(values)
        if array.size == 0:
            return None
        with np.errstate(invalid="ignore"):  # fast path (large frames): the extremes only
            low, high = float(np.min(array)), float(np.max(array))
        if not (math.isnan(low) or math.isnan(high) or self.below(low) or self.above(high)):
            return None
        x = np.asarray(array, dtype=np.float64).ravel()
        outside = self.outside(x)
        beyond = outside  # values crossing the limits, which no saturated share allows
        if self.limits is not None:
            with np.errstate(invalid="ignore"):
                beyond = (x < self.limits[0]) | (x > self.limits[1])
        bad = np.flatnonzero(beyond)
        allowance = self.allowance()
        if bad.size == 0:
            if outside.sum() <= self.saturated_share * x.size:
                return None
            bad = np.flatnonzero(outside)
        first = format_number(float(x[bad[0]]))
        notes = [f"{bad.size} of {x.size} values"] if x.size > 1 else []
        notes += [allowance] if allowance else []
        shown = f" ({'; '.join(notes)})" if notes else ""
        why = f": {self.reason}" if reason else ""
        return (
            f"{self.quantity} {first} {self.unit} is outside the plausible range "
            f"{self.interval()}{shown}{why}"
        )


#: Normal force at the three frames of a grasp.
FORCE = PlausibleRange(
    quantity="force",
    unit="N",
    low=0.0,
    high=1000.0,
    reason="a grasp pushes, so never < 0 N; the dataset's grasps reach ~60 N, the "
    "synthetic ones ~90 N; 1000 N catches unit mix-ups",
)
#: Gripper width (opening) at the three frames of a grasp.
WIDTH = PlausibleRange(
    quantity="width",
    unit="m",
    low=-0.005,
    high=0.2,
    reason="a reading dips below 0 m only by the encoder's offset (~0.5 mm); the gripper "
    "opens to 0.08 m, so 0.2 m catches millimetres",
)
#: Analytical estimates (elastic E, Hertz E*) of a grasp.
ESTIMATE = PlausibleRange(
    quantity="estimate",
    unit="Pa",
    low=0.0,
    high=math.inf,
    low_inclusive=False,
    high_inclusive=False,
    reason="a modulus is > 0 and finite, a failed fit is NaN (missing); large finite "
    "values are fine, the model clamps estimates to [1e2, 1e14] Pa",
)
#: The label: the object's Young's modulus.
MODULUS = PlausibleRange(
    quantity="modulus",
    unit="Pa",
    low=0.0,
    high=1e13,
    low_inclusive=False,
    reason="log10 needs > 0 Pa; nothing is stiffer than diamond (~1.2e12 Pa); the "
    "default label range [1e3, 1e12] Pa does not clip, so values outside it are kept",
)
#: Float difference images, ``(frame - blurred reference) / 255 + 0.5``; 1 = 255 grey
#: levels. The limits are (0 - 255) / 255 + 0.5 and (255 - 0) / 255 + 0.5.
FRAME = PlausibleRange(
    quantity="frame value",
    unit="full scale",
    low=0.0,
    high=1.0,
    reason="difference images lie in [0, 1] but for a few saturated pixels, which the "
    "store's uint8 encoding saturates; more is no difference image (0..255 or normalised "
    "frames)",
    tolerance=1.0 / 255.0,
    saturated_share=0.01,
    limits=(-0.5, 1.5),
)
#: Gel depth maps (indentation into the gel); NaN marks a pixel without depth.
DEPTH = PlausibleRange(
    quantity="depth",
    unit="mm",
    low=-100.0,
    high=100.0,
    reason="a gel is a few mm thick (the Wedge's 5.5 mm), so |depth| beyond 100 mm is no "
    "depth map (metres or pixels)",
)

#: Every rule, by quantity: what ``docs/data.md`` tabulates.
RULES: dict[str, PlausibleRange] = {
    rule.quantity: rule for rule in (FORCE, WIDTH, ESTIMATE, MODULUS, FRAME, DEPTH)
}


def dtype_problem(dtype: Any) -> str | None:
    """None for a numeric dtype (:data:`NUMERIC_KINDS`), else what it is instead, e.g.
    ``datetime64[D]`` (bool, complex, datetime, timedelta, text, structured, object)."""
    try:
        kind = np.dtype(dtype).kind
    except TypeError:  # a pandas extension dtype
        kind = getattr(dtype, "kind", "O")
    return None if kind in NUMERIC_KINDS else str(dtype)


def as_real_number(value: Any) -> float:
    """``value`` as a float when it is a real number (int, float, numpy integer or float,
    a one-element numeric array); None becomes NaN (missing).

    Raises:
        ValueError: bool, complex, datetime, text or anything else that is no number;
            nothing is cast silently.
    """
    if value is None:
        return math.nan
    if isinstance(value, np.ndarray) and value.size == 1:
        if dtype_problem(value.dtype):
            raise ValueError(f"expected a number, got an array of dtype {value.dtype}")
        return float(value.reshape(()))
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise ValueError(f"expected a number, got {type(value).__name__} {value!r}")
    return float(value)


#: The largest frame side (px) any command resizes, warps, crops to or reads from a file.
#: The dataset's frames are 250 x 350 px and a GelSight Mini camera gives 3280 x 2464; a
#: 4096 x 4096 frame is 50 MB as uint8, 200 MB as float32. Larger sizes are typos (or
#: attacks) that would allocate tens of GB before failing, so they are refused first.
MAX_FRAME_SIDE_PX = 4096


def check_size(size: object, what: str = "size") -> tuple[int, int]:
    """``size`` as (height, width) px: two integers in ``[1, MAX_FRAME_SIDE_PX]`` (not
    floats, booleans or text), checked before anything is allocated.

    Raises:
        ValueError: naming ``what`` and the value.
    """
    if (
        isinstance(size, (str, bytes))
        or not hasattr(size, "__len__")
        or len(size) != 2  # type: ignore[arg-type]
        or not all(
            isinstance(n, (int, np.integer)) and not isinstance(n, bool)
            for n in size  # type: ignore[union-attr]
        )
    ):
        raise ValueError(f"{what} must be [height, width] in whole pixels, got {size!r}")
    height, width = (int(n) for n in size)  # type: ignore[union-attr]
    if not (1 <= height <= MAX_FRAME_SIDE_PX and 1 <= width <= MAX_FRAME_SIDE_PX):
        raise ValueError(
            f"{what} {height}x{width} px is out of range: each side must lie in "
            f"[1, {MAX_FRAME_SIDE_PX}] px"
        )
    return height, width
