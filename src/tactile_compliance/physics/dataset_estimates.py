"""The analytical estimates exactly as the public dataset stored them, quirks included.

An independent re-implementation of the authors' generator. See docs/physics.md, "The
dataset's estimator and ours" and "The dataset's estimator, step by step".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from tactile_compliance.physics.contact import (
    _check_fields,
    _validate_sequence,
    rig_corrected_widths_m,
)

__all__ = [
    "DATASET_CONSTANTS",
    "DATASET_GEL_MODULUS_PA",
    "DATASET_PRESS_FORCE_N",
    "DATASET_PX_PER_MM",
    "DatasetEstimatorConstants",
    "dataset_estimates_pa",
    "dataset_force_press",
    "dataset_press_window",
    "interpolate_repeated_widths",
]

FloatArray = npt.NDArray[np.float64]

DATASET_PX_PER_MM: float = math.sqrt((400 / 35) ** 2 + (300 / 25.5) ** 2)
"""Pixel density [px/mm] of the original code, 16.40: the norm of the warp's two axis
densities (400 px / 35 mm and 300 px / 25.5 mm), a quirk; one axis would be ~11.4."""

DATASET_GEL_MODULUS_PA: float = 1.5e5
"""Gel Young's modulus [Pa] of the final published code."""

DATASET_PRESS_FORCE_N: float = 2.5
"""Force [N] that starts the press clip (half the 5 N of the frame selection)."""

# The original worked in metres (``0.001 * depth``); doing the same keeps the floating
# point comparisons with the thresholds identical to it.
_M_PER_MM = 0.001


@dataclass(frozen=True)
class DatasetEstimatorConstants:
    """The constants of the dataset's estimator, with units; defaults are the dataset's.

    Change them only to study the estimator or to run it on rescaled depth maps
    (docs/physics.md): any other value no longer reproduces the stored estimates.

    Attributes:
        px_per_mm: pixel density [px/mm] assumed for the depth maps (16.40, a quirk).
        gel_modulus_pa: gel Young's modulus [Pa].
        gel_poisson: gel Poisson ratio [-].
        contact_threshold_mm: depth [mm] from which a pixel is in contact (and first contact).
        min_contact_area_m2: smallest contact area [m^2] of a fitted frame (2690 px).
        depth_percentile: percentile [%] of the whole frame's depth, the elastic indentation.
        patch_radius_px: half side k [px] of the Hertz patch ``[r-k:r+k, c-k:c+k]``.
        min_depth_fraction: frames-kept and depth-onset fraction [-] of the peak depth.
        fit_tolerance: depth/force consistency tolerance [-] on the normalised values.
        l0_fallback_factor: ``L0 = W[0]`` below this many contact thresholds of depth [-].
        min_approach_m: smallest per-finger approach ``(L0 - W)/2`` of a Hertz frame [m].
        press_force_n: force [N] that starts the press clip.
        press_peak_fraction: the press ends before the force drops below this fraction [-]
            of its peak.
    """

    px_per_mm: float = DATASET_PX_PER_MM
    gel_modulus_pa: float = DATASET_GEL_MODULUS_PA
    gel_poisson: float = 0.485
    contact_threshold_mm: float = 0.1
    min_contact_area_m2: float = 1e-5
    depth_percentile: float = 97.0
    patch_radius_px: int = 5
    min_depth_fraction: float = 0.075
    fit_tolerance: float = 0.25
    l0_fallback_factor: float = 5.0
    min_approach_m: float = 1e-4
    press_force_n: float = DATASET_PRESS_FORCE_N
    press_peak_fraction: float = 0.9

    def __post_init__(self) -> None:
        _check_fields(
            self,
            {
                "finite and > 0": ("px_per_mm", "gel_modulus_pa"),
                "finite and >= 0": (
                    "contact_threshold_mm",
                    "min_contact_area_m2",
                    "fit_tolerance",
                    "l0_fallback_factor",
                    "min_approach_m",
                    "press_force_n",
                ),
                "in (-1, 0.5]": ("gel_poisson",),
                "in [0, 100]": ("depth_percentile",),
                "in [0, 1]": ("min_depth_fraction", "press_peak_fraction"),
            },
        )
        radius = self.patch_radius_px
        if isinstance(radius, bool) or not isinstance(radius, (int, np.integer)) or radius < 1:
            raise ValueError(
                f"DatasetEstimatorConstants.patch_radius_px must be a positive integer, "
                f"got {radius!r}"
            )

    @property
    def pixel_size_m(self) -> float:
        """Side of one pixel [m] as the original computed it, ``0.001 / px_per_mm``."""
        return _M_PER_MM / self.px_per_mm

    @property
    def pixel_area_m2(self) -> float:
        """Area of one pixel [m^2], ``(0.001 / px_per_mm)^2``."""
        return self.pixel_size_m**2


DATASET_CONSTANTS = DatasetEstimatorConstants()
"""The dataset's constants (the defaults of :class:`DatasetEstimatorConstants`)."""


# ---------------------------------------------------------------------------------------
# Preprocessing of the raw series (the driver's steps before the fits)
# ---------------------------------------------------------------------------------------


def _first_true(flags: npt.NDArray[np.bool_]) -> int:
    """Index of the first True, or 0 when there is none (what ``np.argmax`` gives)."""
    return int(np.argmax(flags)) if flags.size else 0


def dataset_force_press(
    forces_n: npt.ArrayLike, constants: DatasetEstimatorConstants = DATASET_CONSTANTS
) -> tuple[int, int] | None:
    """The press clip by force ``[start, end)`` of a whole recording's forces [N], (T,), or
    None when that leaves no frames (docs/physics.md, "The dataset's estimator, step by
    step", step 1).

    Raises:
        ValueError: not a finite, non-empty 1-D array.
    """
    forces = _series(forces_n, "forces_n")
    press_start = max(_first_true(forces >= constants.press_force_n) - 1, 0)
    peak = int(np.argmax(forces))
    last = peak
    # The first post-peak frame under the fraction ends the press (the frame before it is
    # kept); if the force never falls that far the press ends at the peak itself.
    falls = np.flatnonzero(
        (np.arange(forces.size) > peak) & (forces < constants.press_peak_fraction * forces[peak])
    )
    if falls.size and constants.press_peak_fraction < 1:
        last = int(falls[0]) - 1
    return (press_start, last + 1) if press_start < last else None


def dataset_press_window(
    forces_n: npt.ArrayLike,
    max_depth_mm: npt.ArrayLike,
    marker_max_depth_mm: npt.ArrayLike | None = None,
    constants: DatasetEstimatorConstants = DATASET_CONSTANTS,
) -> tuple[int, int]:
    """The frames ``[start, end)`` of a whole recording that the dataset's fits used: the
    press clip by force, then the depth-onset clip (docs/physics.md, steps 1-2).

    Args:
        forces_n: normal force per frame of the whole recording [N], shape (T,).
        max_depth_mm: maximum depth per frame of the force-sensing finger [mm], (T,).
        marker_max_depth_mm: the same for the marker finger [mm], (T,), or None to use the
            force-sensing finger alone.

    Returns:
        ``(start, end)`` with ``0 <= start < end <= T``.

    Raises:
        ValueError: arrays that are not 1-D, of different lengths, empty or not finite.
    """
    forces = _series(forces_n, "forces_n")
    n_frames = forces.size
    depth_series = [_series(max_depth_mm, "max_depth_mm")]
    if marker_max_depth_mm is not None:
        depth_series.append(_series(marker_max_depth_mm, "marker_max_depth_mm"))
    for series in depth_series:
        if series.size != n_frames:
            raise ValueError(f"the depth series has {series.size} frames, the forces {n_frames}")

    # Without a press the original warned "no press" and went on with the whole series.
    start, end = dataset_force_press(forces, constants) or (0, n_frames)

    # The original's units: metres for this finger, mm for the marker finger (docs).
    depth_series[0] = _M_PER_MM * depth_series[0]
    onsets = []
    for series in depth_series:
        window = series[start:end]
        onsets.append(_first_true(window >= constants.min_depth_fraction * window.max()))
    return start + min(onsets), end


def interpolate_repeated_widths(widths_m: npt.ArrayLike) -> FloatArray:
    """The original's width interpolation over repeated readings of ``widths_m`` [m], (T,),
    as a new array (docs/physics.md, step 3).

    Raises:
        ValueError: not a finite 1-D array.
    """
    widths = _series(widths_m, "widths_m", allow_empty=True)
    out = widths.copy()
    n_frames = widths.size
    i = 0
    while i < n_frames - 1:
        if widths[i] == widths[-1]:
            break
        if widths[i] != widths[i + 1]:
            i += 1
            continue
        # A run exists and cannot reach the end (it would equal the last reading).
        k = i + 1 + int(np.argmax(widths[i + 1 :] != widths[i]))
        slope = (widths[k] - widths[i]) / (k - i)
        for j in range(i + 1, k):
            out[j] = widths[i] + slope * (j - i)
        i = k
    return out


def _series(values: npt.ArrayLike, name: str, allow_empty: bool = False) -> FloatArray:
    array = np.asarray(values)
    if not (np.issubdtype(array.dtype, np.floating) or np.issubdtype(array.dtype, np.integer)):
        raise ValueError(f"{name} must hold real numbers, got dtype {array.dtype}")
    if array.ndim != 1:
        raise ValueError(f"{name} must have shape (T,), got shape {array.shape}")
    if array.size == 0 and not allow_empty:
        raise ValueError(f"{name} is empty (T = 0 frames)")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} contains NaN or infinite values")
    return array.astype(np.float64)


# ---------------------------------------------------------------------------------------
# Per-frame quantities and the two fits
# ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Frames:
    """Per-frame quantities of the clipped sequence, all in metres / m^2, shape (T,)."""

    max_m: FloatArray
    percentile_m: FloatArray
    patch_m: FloatArray
    """NaN where the patch slice is empty (the top/left border quirk)."""
    contact_px: npt.NDArray[np.int64]
    area_m2: FloatArray


def _patch_mean_m(frame_m: FloatArray, radius_px: int) -> float:
    row, col = np.unravel_index(int(np.argmax(frame_m)), frame_m.shape)
    # Deliberately plain Python slicing with possibly negative starts: that is what the
    # stored estimates were made with (docs/physics.md).
    patch = frame_m[row - radius_px : row + radius_px, col - radius_px : col + radius_px]
    return float(patch.mean()) if patch.size else math.nan


def _frames(depths_mm: np.ndarray, constants: DatasetEstimatorConstants) -> _Frames:
    n_frames = depths_mm.shape[0]
    threshold_m = _M_PER_MM * constants.contact_threshold_mm
    max_m = np.empty(n_frames)
    percentile_m = np.empty(n_frames)
    patch_m = np.empty(n_frames)
    contact_px = np.empty(n_frames, dtype=np.int64)
    for i in range(n_frames):
        frame_m = _M_PER_MM * np.asarray(depths_mm[i], dtype=np.float64)
        max_m[i] = frame_m.max()
        percentile_m[i] = np.percentile(frame_m, constants.depth_percentile)
        patch_m[i] = _patch_mean_m(frame_m, constants.patch_radius_px)
        contact_px[i] = np.count_nonzero(frame_m >= threshold_m)
    return _Frames(
        max_m=max_m,
        percentile_m=percentile_m,
        patch_m=patch_m,
        contact_px=contact_px,
        area_m2=constants.pixel_area_m2 * contact_px,
    )


def _initial_length_m(
    widths_m: FloatArray, frames: _Frames, constants: DatasetEstimatorConstants
) -> float:
    threshold_m = _M_PER_MM * constants.contact_threshold_mm
    if frames.max_m.max() < constants.l0_fallback_factor * threshold_m:
        return float(widths_m[0])
    i_contact = _first_true(frames.percentile_m >= threshold_m)
    return float(widths_m[i_contact] + 2 * frames.percentile_m[i_contact])


def _consistent_slope(
    x: list[float], y: list[float], depth: list[float], force: list[float], tolerance: float
) -> float:
    """Through-origin slope over the depth/force consistent points; NaN if not formable,
    not finite or not positive."""
    if not x:
        return math.nan  # the original returned 0 here
    xs, ys, depths, forces = (np.asarray(v) for v in (x, y, depth, force))
    with np.errstate(divide="ignore", invalid="ignore"):
        depth_norm = depths / depths.max()
        force_norm = forces / forces.max()
        keep = (depth_norm <= force_norm + tolerance) & (depth_norm >= force_norm - tolerance)
        sum_xx = float(np.dot(xs[keep], xs[keep]))
        sum_xy = float(np.dot(xs[keep], ys[keep]))
        if sum_xx == 0.0:
            return math.nan  # 0/0 (empty mask) or a zero strain/compliance everywhere
        slope = sum_xy / sum_xx
    return slope if (math.isfinite(slope) and slope > 0) else math.nan


def _elastic_pa(
    forces_n: FloatArray,
    widths_m: FloatArray,
    frames: _Frames,
    length_0_m: float,
    constants: DatasetEstimatorConstants,
) -> float:
    kept_depth_m = constants.min_depth_fraction * frames.percentile_m.max()
    x, y, depth, force = [], [], [], []
    for i in range(forces_n.size):
        if frames.max_m[i] < kept_depth_m or frames.contact_px[i] == 0:
            continue
        shortening_m = length_0_m - (widths_m[i] + 2 * frames.percentile_m[i])
        if shortening_m >= 0 and frames.area_m2[i] >= constants.min_contact_area_m2:
            x.append(shortening_m / length_0_m)
            y.append(abs(forces_n[i]) / frames.area_m2[i])
            depth.append(frames.percentile_m[i])
            force.append(forces_n[i])  # signed, as in the original's consistency mask
    return _consistent_slope(x, y, depth, force, constants.fit_tolerance)


def _hertz_pa(
    forces_n: FloatArray,
    widths_m: FloatArray,
    frames: _Frames,
    length_0_m: float,
    constants: DatasetEstimatorConstants,
) -> float:
    # np.max, not nanmax: a NaN patch makes this NaN and switches the rule off (a quirk).
    kept_depth_m = constants.min_depth_fraction * np.max(frames.patch_m)
    gel_compliance = 1 - constants.gel_poisson**2
    x, y, depth, force = [], [], [], []
    for i in range(forces_n.size):
        force_n = abs(forces_n[i])
        approach_m = (length_0_m - widths_m[i]) / 2
        if frames.max_m[i] < kept_depth_m or frames.contact_px[i] == 0:
            continue
        if approach_m <= constants.min_approach_m:
            continue
        area_m2 = frames.area_m2[i]
        patch_m = frames.patch_m[i]
        if not (force_n > 0 and area_m2 >= constants.min_contact_area_m2 and patch_m > 0):
            continue
        contact_radius_m = math.sqrt(area_m2 / math.pi)
        sphere_radius_m = contact_radius_m**2 / approach_m
        # Hertz peak pressure without its E*^(2/3) factor, then the MDR centre
        # displacement of the gel under it; the fitted slope is E*^(2/3).
        reduced_p0 = (1 / math.pi) * (6 * force_n / sphere_radius_m**2) ** (1 / 3)
        centre_load = reduced_p0 * math.pi * contact_radius_m / 4
        x.append(gel_compliance * centre_load / constants.gel_modulus_pa)
        y.append(patch_m)
        depth.append(patch_m)
        force.append(force_n)
    return float(_consistent_slope(x, y, depth, force, constants.fit_tolerance) ** 1.5)


def dataset_estimates_pa(
    forces_n: npt.ArrayLike,
    widths_m: npt.ArrayLike,
    depths_mm: npt.ArrayLike,
    constants: DatasetEstimatorConstants = DATASET_CONSTANTS,
    *,
    marker_depths_mm: npt.ArrayLike | None = None,
    preprocess: bool = True,
    rig_stiffness_n_per_m: float | None = None,
) -> tuple[float, float]:
    """Both analytical estimates ``(E_elastic [Pa], E*_hertz [Pa])`` as the dataset made them.

    Same conventions as :func:`tactile_compliance.physics.contact.analytical_estimates_pa`,
    but the series is the *whole recording* of one grasp, which this function clips and
    interpolates itself: pass every recorded frame, not a pre-clipped series (the force
    clip is not idempotent: a second pass would also cut the hold after the peak). What
    else the caller must do to reproduce a stored value: docs/physics.md, "The dataset's
    estimator and ours".

    Args:
        forces_n: normal force per frame [N], shape (T,).
        widths_m: gripper width per frame [m], shape (T,), as measured (stair-stepped).
        depths_mm: depth maps of the force-sensing (markerless) finger [mm], (T, H, W).
        constants: the estimator's constants; the defaults are the dataset's.
        marker_depths_mm: depth maps of the marker finger [mm], (T, H', W'), used only for
            the depth-onset clip; None uses the force-sensing finger alone.
        preprocess: False skips steps 1-3 for a series that is already clipped and
            interpolated exactly as the original's driver did.
        rig_stiffness_n_per_m: the rig's stiffness [N/m]: the rig-corrected estimate,
            the rig's closure ``F / k`` taken out of the widths after step 3
            (``contact.rig_corrected_widths_m``). None (default): the dataset's own
            estimate, bit-exact.

    Returns:
        ``(E_elastic, E*_hertz)`` in Pa; ``nan`` for an estimate the original could not
        form or gave as 0, NaN or a non-positive number.

    Raises:
        ValueError: malformed input (shapes, frame counts, NaN/inf values, dtypes).
    """
    forces, widths, depths = _validate_sequence(forces_n, widths_m, depths_mm)
    marker = None
    if marker_depths_mm is not None:
        marker = np.asarray(marker_depths_mm)
        if marker.ndim != 3 or marker.shape[0] != forces.size or 0 in marker.shape:
            raise ValueError(
                "marker_depths_mm must have shape (T, H, W) with the same T as forces_n "
                f"({forces.size}), got shape {marker.shape}"
            )
        if not np.issubdtype(marker.dtype, np.number) or np.iscomplexobj(marker):
            raise ValueError(f"marker_depths_mm must hold real numbers, got dtype {marker.dtype}")
        if not np.all(np.isfinite(marker)):
            raise ValueError("marker_depths_mm contains NaN or infinite values")

    if preprocess:
        max_depth_mm = np.array([np.max(depths[i]) for i in range(forces.size)], dtype=np.float64)
        marker_max_mm = (
            None
            if marker is None
            else np.array([np.max(marker[i]) for i in range(forces.size)], dtype=np.float64)
        )
        start, end = dataset_press_window(forces, max_depth_mm, marker_max_mm, constants)
        forces = forces[start:end]
        widths = interpolate_repeated_widths(widths[start:end])
        depths = depths[start:end]

    if rig_stiffness_n_per_m is not None:
        # After the interpolation: it needs the repeated readings of the raw widths.
        widths = rig_corrected_widths_m(widths, forces, rig_stiffness_n_per_m)
    frames = _frames(depths, constants)
    length_0_m = _initial_length_m(widths, frames, constants)
    return (
        _elastic_pa(forces, widths, frames, length_0_m, constants),
        _hertz_pa(forces, widths, frames, length_0_m, constants),
    )
