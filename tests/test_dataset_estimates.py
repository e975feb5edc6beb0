"""The dataset-compatible estimator (physics.dataset_estimates) against hand computations.

Expected values are computed here, step by step, from the published algorithm of
Burgess et al. (the generator of ``elastic_estimate.pkl`` / ``hertz_estimate.pkl``):
16.40 px/mm, gel 1.5e5 Pa, whole-frame 97th percentile, the asymmetric 10 x 10 patch,
the L0 rule, the filters and the through-origin fits. Nothing below calls the module's
helpers to make an expected value.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from tactile_compliance.physics import (
    DATASET_CONSTANTS,
    DATASET_GEL_MODULUS_PA,
    DATASET_PX_PER_MM,
    DatasetEstimatorConstants,
    SensorConstants,
    analytical_estimates_pa,
    dataset_estimates_pa,
    dataset_press_window,
    interpolate_repeated_widths,
)

# The original's constants, written out: the norm of the two axes' pixel densities of
# the 400 x 300 px warp of the 35 x 25.5 mm pad, the final code's gel, 0.1 mm contact.
PX_PER_MM = math.sqrt((400 / 35) ** 2 + (300 / 25.5) ** 2)  # 16.40
PIXEL_M = 1e-3 / PX_PER_MM
E_GEL = 1.5e5
NU_GEL = 0.485
THRESHOLD_M = 1e-4


# ---------------------------------------------------------------------------------------
# The algorithm by hand, from per-frame quantities
# ---------------------------------------------------------------------------------------


def fits_by_hand(
    forces: np.ndarray,
    widths_m: np.ndarray,
    contact_px: np.ndarray,
    p97_mm: np.ndarray,
    patch_mm: np.ndarray,
    max_mm: np.ndarray,
) -> tuple[float, float]:
    """Burgess's two fits on an already clipped sequence, step by step.

    Per frame: contact pixel count, whole-frame 97th percentile, 10 x 10 patch mean and
    maximum depth. Returns (E_elastic, E*_hertz), NaN where the original gave 0 or NaN.
    """
    area = contact_px * PIXEL_M**2
    p97, patch, dmax = p97_mm * 1e-3, patch_mm * 1e-3, max_mm * 1e-3
    n = forces.size

    # Initial length: the first width when the whole press stays under 0.5 mm, else the
    # width plus two whole-frame percentiles at the first frame whose percentile reaches
    # 0.1 mm (frame 0 if none does).
    if dmax.max() < 5 * THRESHOLD_M:
        length_0 = widths_m[0]
    else:
        reached = [i for i in range(n) if p97[i] >= THRESHOLD_M]
        i_c = reached[0] if reached else 0
        length_0 = widths_m[i_c] + 2 * p97[i_c]

    def fit(points: list[tuple[float, float, float, float]]) -> float:
        if not points:
            return math.nan
        d_max = max(p[2] for p in points)
        f_max = max(p[3] for p in points)
        if d_max == 0 or f_max == 0:
            return math.nan  # 0/0 normalisation: no point is consistent
        used = [p for p in points if abs(p[2] / d_max - p[3] / f_max) <= 0.25 + 1e-12]
        sxx = sum(p[0] ** 2 for p in used)
        if sxx == 0:
            return math.nan
        return sum(p[0] * p[1] for p in used) / sxx

    # Elastic: strain of the object between the two gels, stress over the contact area.
    elastic_points = []
    for i in range(n):
        if dmax[i] < 0.075 * p97.max() or contact_px[i] == 0 or area[i] < 1e-5:
            continue
        shortening = length_0 - (widths_m[i] + 2 * p97[i])
        if shortening >= 0:
            elastic_points.append(
                (shortening / length_0, abs(forces[i]) / area[i], p97[i], forces[i])
            )
    elastic = fit(elastic_points)

    # Hertz/MDR: sphere radius from the apparent approach, the gel's centre displacement
    # under the Hertz pressure (without E*^(2/3)) against the patch depth.
    hertz_points = []
    for i in range(n):
        approach = (length_0 - widths_m[i]) / 2
        if dmax[i] < 0.075 * np.max(patch) or contact_px[i] == 0 or approach <= 1e-4:
            continue
        if not (abs(forces[i]) > 0 and area[i] >= 1e-5 and patch[i] > 0):
            continue
        a = math.sqrt(area[i] / math.pi)
        radius = a**2 / approach
        p0 = (6 * abs(forces[i]) / radius**2) ** (1 / 3) / math.pi
        x = (1 - NU_GEL**2) / E_GEL * (math.pi * a / 4) * p0
        hertz_points.append((x, patch[i], patch[i], abs(forces[i])))
    k = fit(hertz_points)
    hertz = k**1.5 if (math.isfinite(k) and k > 0) else math.nan
    if not (math.isfinite(elastic) and elastic > 0):
        elastic = math.nan
    return elastic, hertz


def block_frames(
    depths_mm: list[float], shape: tuple[int, int], rows: slice, cols: slice
) -> np.ndarray:
    """Flat-bottomed rectangular imprints of the given depths (a punch), zero elsewhere."""
    frames = np.zeros((len(depths_mm), *shape))
    for i, depth in enumerate(depths_mm):
        frames[i, rows, cols] = depth
    return frames


def sphere_frames(
    depths_mm: list[float], shape: tuple[int, int], centre: tuple[int, int], radius_mm: float
) -> np.ndarray:
    """Spherical caps of the given depths on the dataset's 16.40 px/mm grid [mm]."""
    rows, cols = np.mgrid[0 : shape[0], 0 : shape[1]]
    r_mm = np.hypot(rows - centre[0], cols - centre[1]) / PX_PER_MM
    sag = radius_mm - np.sqrt(np.clip(radius_mm**2 - r_mm**2, 0.0, None))
    return np.stack([np.clip(d - sag, 0.0, None) for d in depths_mm])


# ---------------------------------------------------------------------------------------
# Constants
# ---------------------------------------------------------------------------------------


def test_constants_are_the_originals() -> None:
    assert abs(DATASET_PX_PER_MM - 16.4018) < 1e-4
    assert DATASET_PX_PER_MM == PX_PER_MM
    assert DATASET_CONSTANTS.pixel_size_m == pytest.approx(1e-3 / 16.4018, rel=1e-5)
    assert DATASET_GEL_MODULUS_PA == E_GEL
    assert DATASET_CONSTANTS.gel_poisson == NU_GEL
    assert DATASET_CONSTANTS.contact_threshold_mm == 0.1
    assert DATASET_CONSTANTS.min_contact_area_m2 == 1e-5
    assert DATASET_CONSTANTS.patch_radius_px == 5
    # Our estimator uses one axis' density (400 px over 35 mm) and the paper's gel.
    assert 1e-3 / SensorConstants().pixel_size_m == pytest.approx(11.4286, abs=1e-4)
    assert SensorConstants().gel_modulus_pa == 2.75e5


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("px_per_mm", 0.0),
        ("gel_modulus_pa", -1.0),
        ("gel_poisson", 0.6),
        ("contact_threshold_mm", math.nan),
        ("depth_percentile", 101.0),
        ("min_depth_fraction", 1.5),
        ("patch_radius_px", 0),
        ("patch_radius_px", 2.5),
    ],
)
def test_constants_validation(field: str, value: float) -> None:
    with pytest.raises(ValueError, match=field):
        DatasetEstimatorConstants(**{field: value})


# ---------------------------------------------------------------------------------------
# Closed-form case: a flat square punch (every per-frame quantity known by hand)
# ---------------------------------------------------------------------------------------

PUNCH_DEPTHS_MM = [0.4, 0.8, 1.2, 1.6]
PUNCH_FORCES_N = np.array([2.0, 6.0, 12.0, 20.0])  # starts under 2.5 N: nothing is clipped
OBJECT_LENGTH_M = 0.04


def punch_widths(compression_mm: list[float]) -> np.ndarray:
    """Width = object length - both gels' indentation - both sides' object compression."""
    h = np.array(PUNCH_DEPTHS_MM) * 1e-3
    c = np.array(compression_mm) * 1e-3
    return OBJECT_LENGTH_M - 2 * h - 2 * c


@pytest.mark.parametrize("compression_mm", [[0.0, 0.2, 0.5, 0.9], [0.0, 0.0, 0.0, 0.0]])
def test_flat_punch_closed_form(compression_mm: list[float]) -> None:
    # A 60 x 60 px punch in a 120 x 120 px frame (25 % of the frame is in contact):
    # whole-frame 97th percentile = h, maximum = h, 3600 contact pixels, and the first
    # deepest pixel is the punch's top-left corner (30, 30), whose [25:35, 25:35] patch
    # holds 5 x 5 punch pixels out of 10 x 10: patch mean = h / 4.
    depths = block_frames(PUNCH_DEPTHS_MM, (120, 120), slice(30, 90), slice(30, 90))
    widths = punch_widths(compression_mm)
    elastic, hertz = dataset_estimates_pa(PUNCH_FORCES_N, widths, depths)

    h = np.array(PUNCH_DEPTHS_MM) * 1e-3
    c = np.array(compression_mm) * 1e-3
    area = 3600 / PX_PER_MM**2 * 1e-6  # 1.338e-5 m^2, above the 1e-5 m^2 minimum
    length_0 = widths[0] + 2 * h[0]  # = object length (c[0] = 0): deepest frame >= 0.5 mm
    # Depth/force consistency: h/h_max = (.25, .5, .75, 1), F/F_max = (.1, .3, .6, 1).
    if any(compression_mm):
        strain = 2 * c / length_0  # the gels' indentation cancels out
        stress = PUNCH_FORCES_N / area
        expected_elastic = np.sum(strain * stress) / np.sum(strain**2)
        assert elastic == pytest.approx(expected_elastic, rel=1e-9)
        # strain (0, .01, .025, .045), stress F / 1.3382e-5 m^2: 94158 Pa / 2.75e-3.
        assert elastic == pytest.approx(3.4239e7, rel=1e-4)
    else:
        # A rigid object: zero strain up to rounding, an infinite (or unformable) modulus.
        assert math.isnan(elastic) or elastic > 1e12

    approach = h + c  # (L0 - W) / 2
    a = math.sqrt(area / math.pi)
    radius = a**2 / approach
    x = (1 - 0.485**2) / 1.5e5 * (math.pi * a / 4) * (6 * PUNCH_FORCES_N / radius**2) ** (1 / 3)
    x /= math.pi
    y = h / 4  # the quarter-punch patch
    expected_hertz = (np.sum(x * y) / np.sum(x**2)) ** 1.5
    assert hertz == pytest.approx(expected_hertz, rel=1e-9)
    # ... and the same from the step-by-step reference.
    by_hand = fits_by_hand(
        PUNCH_FORCES_N,
        widths,
        np.full(4, 3600),
        np.array(PUNCH_DEPTHS_MM),
        np.array(PUNCH_DEPTHS_MM) / 4,
        np.array(PUNCH_DEPTHS_MM),
    )
    assert hertz == pytest.approx(by_hand[1], rel=1e-9)


def test_flat_punch_soft_object_lowers_the_hertz_estimate() -> None:
    depths = block_frames(PUNCH_DEPTHS_MM, (120, 120), slice(30, 90), slice(30, 90))
    _, rigid = dataset_estimates_pa(PUNCH_FORCES_N, punch_widths([0.0] * 4), depths)
    _, soft = dataset_estimates_pa(PUNCH_FORCES_N, punch_widths([0.0, 0.2, 0.5, 0.9]), depths)
    assert 0 < soft < rigid


# ---------------------------------------------------------------------------------------
# The analytic case of the issue: a Hertz sphere pressed into the gel
# ---------------------------------------------------------------------------------------

SPHERE_SHAPE = (160, 200)
SPHERE_CENTRE = (80, 100)
SPHERE_RADIUS_MM = 10.0
SPHERE_DEPTHS_MM = [0.3, 0.5, 0.7, 0.9]
SPHERE_FORCES_N = 20.0 * (np.array(SPHERE_DEPTHS_MM) / 0.9) ** 1.5  # Hertz-like, 3.8-20 N


def sphere_by_hand(depths: np.ndarray, widths: np.ndarray, centre: tuple[int, int]):
    r, c = centre
    count = np.array([np.count_nonzero(f >= 0.1) for f in depths])
    p97 = np.array([np.percentile(f, 97) for f in depths])  # every pixel of the frame
    # The 10 x 10 patch: rows r-5 .. r+4 and columns c-5 .. c+4 (the peak is the 6th).
    patch = np.array([f[r - 5 : r + 5, c - 5 : c + 5].mean() for f in depths])
    peak = depths.max(axis=(1, 2))
    return fits_by_hand(SPHERE_FORCES_N, widths, count, p97, patch, peak), (count, p97)


@pytest.mark.parametrize(
    ("compression_mm", "label"),
    [([0.0, 0.0, 0.0, 0.0], "rigid"), ([0.0, 0.15, 0.35, 0.6], "soft")],
)
def test_hertz_sphere_press_by_hand(compression_mm: list[float], label: str) -> None:
    depths = sphere_frames(SPHERE_DEPTHS_MM, SPHERE_SHAPE, SPHERE_CENTRE, SPHERE_RADIUS_MM)
    # Soft: the gripper closes by more than the gels' indentation, the object compresses.
    widths = (
        OBJECT_LENGTH_M
        - 2 * np.array(SPHERE_DEPTHS_MM) * 1e-3
        - 2 * np.array(compression_mm) * 1e-3
    )
    (expected_elastic, expected_hertz), (count, p97) = sphere_by_hand(depths, widths, SPHERE_CENTRE)
    # The case is what the test means: every frame is fitted and in contact over > 3 %.
    assert np.all(count * PIXEL_M**2 >= 1e-5)
    assert np.all(p97 >= 0.1)

    elastic, hertz = dataset_estimates_pa(SPHERE_FORCES_N, widths, depths)
    assert hertz == pytest.approx(expected_hertz, rel=1e-9)
    if label == "soft":
        assert elastic == pytest.approx(expected_elastic, rel=1e-9)
        assert math.isfinite(elastic) and elastic > 0
    else:
        # For a rigid sphere the whole-frame percentile is the depth at a fixed radius,
        # h - const, so the strain W + 2 p97 is constant: zero up to rounding.
        assert math.isnan(elastic) or elastic > 1e12
    assert math.isfinite(hertz) and hertz > 0


def test_hertz_sphere_soft_object_gives_a_lower_hertz_estimate() -> None:
    depths = sphere_frames(SPHERE_DEPTHS_MM, SPHERE_SHAPE, SPHERE_CENTRE, SPHERE_RADIUS_MM)
    h = np.array(SPHERE_DEPTHS_MM) * 1e-3
    _, rigid = dataset_estimates_pa(SPHERE_FORCES_N, OBJECT_LENGTH_M - 2 * h, depths)
    softer = []
    for scale in (0.5, 1.0, 2.0):
        widths = OBJECT_LENGTH_M - 2 * h - 2 * scale * np.array([0.0, 0.15, 0.35, 0.6]) * 1e-3
        softer.append(dataset_estimates_pa(SPHERE_FORCES_N, widths, depths))
    hertz = [rigid] + [s[1] for s in softer]
    elastic = [s[0] for s in softer]
    assert np.all(np.diff(hertz) < 0)  # the more the object gives, the lower E*
    assert np.all(np.diff(elastic) < 0)


# ---------------------------------------------------------------------------------------
# The quirks
# ---------------------------------------------------------------------------------------


def test_quirk_percentile_is_over_the_whole_frame() -> None:
    # The same 60 x 60 px punch: in a 120 x 120 frame it covers 25 %, in a 120 x 1300
    # frame 2.3 %, so there the whole-frame 97th percentile is 0 in every frame.
    widths = punch_widths([0.0, 0.2, 0.5, 0.9])
    small = block_frames(PUNCH_DEPTHS_MM, (120, 120), slice(30, 90), slice(30, 90))
    wide = block_frames(PUNCH_DEPTHS_MM, (120, 1300), slice(30, 90), slice(30, 90))
    assert np.percentile(wide[-1], 97) == 0.0
    elastic_small, _ = dataset_estimates_pa(PUNCH_FORCES_N, widths, small)
    elastic_wide, hertz_wide = dataset_estimates_pa(PUNCH_FORCES_N, widths, wide)
    assert math.isfinite(elastic_small)
    # No usable depth: p97/max(p97) = 0/0, no frame passes the consistency mask.
    assert math.isnan(elastic_wide)
    # Our estimator takes the percentile over the contact mask and is unaffected.
    ours_small = analytical_estimates_pa(PUNCH_FORCES_N, widths, small)[0]
    ours_wide = analytical_estimates_pa(PUNCH_FORCES_N, widths, wide)[0]
    assert ours_wide == pytest.approx(ours_small, rel=1e-12)
    # The Hertz fit still works, but its L0 falls back to frame 0 without any gel
    # indentation (no percentile reaches 0.1 mm; argmax of all-False is 0): L0 = W[0].
    expected = fits_by_hand(
        PUNCH_FORCES_N,
        widths,
        np.full(4, 3600),
        np.zeros(4),
        np.array(PUNCH_DEPTHS_MM) / 4,
        np.array(PUNCH_DEPTHS_MM),
    )
    assert hertz_wide == pytest.approx(expected[1], rel=1e-9)
    h = np.array(PUNCH_DEPTHS_MM) * 1e-3
    c = np.array([0.0, 0.2, 0.5, 0.9]) * 1e-3
    approach = (widths[0] - widths) / 2  # frame 0 has no approach and is dropped
    assert np.allclose(approach, (h + c) - (h[0] + c[0]))


def test_quirk_l0_fallback_for_shallow_presses() -> None:
    # Deepest frame 0.4 mm < 5 x 0.1 mm: L0 = W[0], the first width without the gels'
    # indentation, so the strain W[0] - W - 2 p97 starts negative (frame 0 is dropped).
    shallow = [0.1, 0.2, 0.3, 0.4]
    depths = block_frames(shallow, (120, 120), slice(30, 90), slice(30, 90))
    compression = np.array([0.0, 0.3, 0.6, 1.0]) * 1e-3
    widths = OBJECT_LENGTH_M - 2 * np.array(shallow) * 1e-3 - 2 * compression
    elastic, hertz = dataset_estimates_pa(PUNCH_FORCES_N, widths, depths)

    h = np.array(shallow) * 1e-3
    area = 3600 * PIXEL_M**2
    strain = (widths[0] - (widths + 2 * h)) / widths[0]
    assert strain[0] < 0 < strain[1]
    keep = strain >= 0
    stress = PUNCH_FORCES_N / area
    expected = np.sum(strain[keep] * stress[keep]) / np.sum(strain[keep] ** 2)
    assert elastic == pytest.approx(expected, rel=1e-9)
    by_hand = fits_by_hand(PUNCH_FORCES_N, widths, np.full(4, 3600), h * 1e3, h * 1e3 / 4, h * 1e3)
    assert elastic == pytest.approx(by_hand[0], rel=1e-9)
    assert hertz == pytest.approx(by_hand[1], rel=1e-9)
    # Without the fallback (L0 = W[0] + 2 p97[0]) the strain would be 2 c / L0 instead.
    strain_without = 2 * compression / (widths[0] + 2 * h[0])
    without = np.sum(strain_without * stress) / np.sum(strain_without**2)
    assert abs(elastic / without - 1) > 0.01


def test_quirk_asymmetric_10x10_patch_at_the_borders() -> None:
    widths = punch_widths([0.0, 0.2, 0.5, 0.9])
    # Punch whose top-left corner is 5 px from the border: patch [0:10, 0:10], h / 4.
    inside = block_frames(PUNCH_DEPTHS_MM, (120, 120), slice(5, 65), slice(5, 65))
    # 3 px from the border: the slice [-2:8] starts at row 118 and is empty: no Hertz
    # frame at all; the elastic fit does not use the patch.
    near = block_frames(PUNCH_DEPTHS_MM, (120, 120), slice(3, 63), slice(3, 63))
    elastic_in, hertz_in = dataset_estimates_pa(PUNCH_FORCES_N, widths, inside)
    elastic_near, hertz_near = dataset_estimates_pa(PUNCH_FORCES_N, widths, near)
    h = np.array(PUNCH_DEPTHS_MM)
    expected = fits_by_hand(PUNCH_FORCES_N, widths, np.full(4, 3600), h, h / 4, h)
    assert hertz_in == pytest.approx(expected[1], rel=1e-9)
    assert math.isnan(hertz_near)
    assert elastic_near == pytest.approx(elastic_in, rel=1e-12)
    # Our 11 x 11 patch is clipped at the border instead and keeps the estimate.
    assert math.isfinite(analytical_estimates_pa(PUNCH_FORCES_N, widths, near)[1])


def test_quirk_patch_cut_short_at_the_bottom_right_border() -> None:
    # A sphere whose apex is the last pixel: the patch is rows H-6 .. H-1 and columns
    # W-6 .. W-1 (6 x 6, the slice end H+4 is cut to H), a quarter cap in contact.
    shape = (120, 150)
    depths_mm = [0.9, 1.1, 1.3, 1.5]
    depths = sphere_frames(depths_mm, shape, (119, 149), SPHERE_RADIUS_MM)
    widths = OBJECT_LENGTH_M - 2 * np.array(depths_mm) * 1e-3 - np.array([0, 2, 5, 9]) * 1e-4
    count = np.array([np.count_nonzero(f >= 0.1) for f in depths])
    p97 = np.array([np.percentile(f, 97) for f in depths])
    patch = np.array([f[114:120, 144:150].mean() for f in depths])
    assert np.all(count * PIXEL_M**2 >= 1e-5)
    expected = fits_by_hand(SPHERE_FORCES_N, widths, count, p97, patch, np.array(depths_mm))
    got = dataset_estimates_pa(SPHERE_FORCES_N, widths, depths)
    assert got[1] == pytest.approx(expected[1], rel=1e-9)
    assert got[0] == pytest.approx(expected[0], rel=1e-9)


def test_quirk_pixel_size_sets_the_minimum_contact() -> None:
    # 1e-5 m^2 is 2690.2 px at 16.40 px/mm (it would be 1306 px at 11.43 px/mm).
    assert abs(1e-5 / PIXEL_M**2 - 2690.2) < 0.1
    widths = punch_widths([0.0, 0.2, 0.5, 0.9])
    fitted = block_frames(PUNCH_DEPTHS_MM, (120, 120), slice(30, 75), slice(30, 90))  # 2700
    too_small = block_frames(PUNCH_DEPTHS_MM, (120, 120), slice(30, 70), slice(30, 97))  # 2680
    assert np.all(np.isfinite(dataset_estimates_pa(PUNCH_FORCES_N, widths, fitted)))
    assert np.all(np.isnan(dataset_estimates_pa(PUNCH_FORCES_N, widths, too_small)))
    # The stress uses the 16.40 px/mm area: 2700 px are 1.0037e-5 m^2.
    h = np.array(PUNCH_DEPTHS_MM)
    expected = fits_by_hand(PUNCH_FORCES_N, widths, np.full(4, 2700), h, h / 4, h)
    got = dataset_estimates_pa(PUNCH_FORCES_N, widths, fitted)
    assert got[0] == pytest.approx(expected[0], rel=1e-9)


# ---------------------------------------------------------------------------------------
# The driver's preprocessing: press clip, depth onset, width interpolation
# ---------------------------------------------------------------------------------------

RAW_FORCES = np.array([0, 0.5, 1.5, 2.4, 3, 6, 10, 12, 11.5, 11, 10.5, 9, 2, 0], float)
RAW_MAX_DEPTH = np.array([0, 0, 0, 0.01, 0.05, 0.2, 0.5, 0.6, 0.6, 0.6, 0.6, 0.5, 0.1, 0.0])


def test_press_window_by_hand() -> None:
    # Start: one frame before the first F >= 2.5 N (frame 4) -> 3. Peak 12 N at frame 7;
    # the first later frame under 0.9 x 12 = 10.8 N is frame 10 -> the press ends at 9.
    # Depth onset in [3, 10): 7.5 % of 0.6 mm = 0.045 mm, first reached at frame 4.
    assert dataset_press_window(RAW_FORCES, RAW_MAX_DEPTH) == (4, 10)
    # With the marker finger already deep at frame 3, the earlier onset wins.
    marker = RAW_MAX_DEPTH.copy()
    marker[3] = 0.3
    assert dataset_press_window(RAW_FORCES, RAW_MAX_DEPTH, marker) == (3, 10)
    # A force that never falls under 90 % of its peak ends the press at the peak.
    rising = np.array([1.0, 2.0, 3.0, 5.0, 8.0, 9.0, 9.5])
    assert dataset_press_window(rising, np.ones(7)) == (1, 7)
    # No press (start >= end): the whole series is kept.
    falling = np.array([9.0, 5.0, 3.0, 1.0])
    assert dataset_press_window(falling, np.ones(4)) == (0, 4)


def test_width_interpolation_by_hand() -> None:
    widths = np.array([10, 10, 10, 7, 7, 4, 4, 4], float)
    assert interpolate_repeated_widths(widths).tolist() == [10, 9, 8, 7, 5.5, 4, 4, 4]
    # The scan stops at the first reading equal to the last one (frame 1 here).
    assert interpolate_repeated_widths([5.0, 3, 3, 1, 1, 3]).tolist() == [5, 3, 3, 1, 1, 3]
    assert interpolate_repeated_widths([3.0, 2.0, 1.0]).tolist() == [3, 2, 1]


def test_preprocessing_is_inside_and_not_idempotent() -> None:
    # A whole recording: approach, press, hold, release; stair-stepped widths.
    n = RAW_FORCES.size
    depths_mm = np.zeros((n, 120, 120))
    for i, d in enumerate(RAW_MAX_DEPTH * 3):  # deep enough for the 0.5 mm rule
        depths_mm[i, 30:90, 30:90] = d
    # The object (40 mm at first) compresses while the gels indent (W + 2 d decreases).
    stairs = [40, 40, 40, 39.8, 39.6, 38.6, 36.6, 35.8, 35.8, 35.6, 35.6, 35.6, 37, 40]
    widths = np.array(stairs) * 1e-3
    raw = dataset_estimates_pa(RAW_FORCES, widths, depths_mm)
    # The same by hand: frames [4, 10) (test_press_window_by_hand), widths
    # (39.6, 38.6, 36.6, 35.8, 35.8, 35.6) mm with the repeated 35.8 made 35.7.
    clipped_widths = np.array([39.6, 38.6, 36.6, 35.8, 35.7, 35.6]) * 1e-3
    assert np.allclose(interpolate_repeated_widths(widths[4:10]), clipped_widths, atol=1e-15)
    clipped = dataset_estimates_pa(
        RAW_FORCES[4:10], clipped_widths, depths_mm[4:10], preprocess=False
    )
    assert raw == pytest.approx(clipped, rel=1e-12, nan_ok=True)
    assert np.all(np.isfinite(raw))
    # Clipping twice is not the same: the second pass also cuts the hold after the peak
    # (the force no longer falls under 90 %, so the press ends at the peak, frame 3 of 6).
    assert dataset_press_window(RAW_FORCES[4:10], RAW_MAX_DEPTH[4:10]) == (0, 4)
    twice = dataset_estimates_pa(RAW_FORCES[4:10], clipped_widths, depths_mm[4:10])
    assert twice != pytest.approx(raw, rel=1e-6)


def test_width_interpolation_changes_the_estimate() -> None:
    depths = block_frames(PUNCH_DEPTHS_MM, (120, 120), slice(30, 90), slice(30, 90))
    widths = punch_widths([0.0, 0.2, 0.5, 0.9])
    stepped = widths.copy()
    stepped[2] = stepped[1]  # the encoder did not update at frame 2
    got = dataset_estimates_pa(PUNCH_FORCES_N, stepped, depths)
    fixed = stepped.copy()
    fixed[2] = (stepped[1] + stepped[3]) / 2
    assert got == pytest.approx(
        dataset_estimates_pa(PUNCH_FORCES_N, fixed, depths, preprocess=False), rel=1e-12
    )
    assert got != pytest.approx(
        dataset_estimates_pa(PUNCH_FORCES_N, stepped, depths, preprocess=False), rel=1e-6
    )


# ---------------------------------------------------------------------------------------
# Degenerate grasps and malformed input
# ---------------------------------------------------------------------------------------


def test_no_contact_gives_nan_where_the_original_stored_zero() -> None:
    depths = np.zeros((4, 120, 120))
    elastic, hertz = dataset_estimates_pa(PUNCH_FORCES_N, punch_widths([0.0] * 4), depths)
    assert math.isnan(elastic) and math.isnan(hertz)


def test_no_elastic_point_gives_nan_and_hertz_uses_what_is_left() -> None:
    # Widths that open while the force rises: every strain after frame 0 is negative and
    # frame 0's is zero (0/0 slope): the original stored 0 or NaN, we give NaN. The
    # Hertz fit keeps frame 0 alone, whose approach (L0 - W)/2 = h0 = 0.4 mm > 0.1 mm.
    depths = block_frames(PUNCH_DEPTHS_MM, (120, 120), slice(30, 90), slice(30, 90))
    widths = OBJECT_LENGTH_M + np.array([0.0, 1.0, 2.0, 3.0]) * 1e-3
    elastic, hertz = dataset_estimates_pa(PUNCH_FORCES_N, widths, depths)
    assert math.isnan(elastic)
    h = np.array(PUNCH_DEPTHS_MM)
    expected = fits_by_hand(PUNCH_FORCES_N, widths, np.full(4, 3600), h, h / 4, h)
    assert hertz == pytest.approx(expected[1], rel=1e-9)
    a = math.sqrt(3600 * PIXEL_M**2 / math.pi)
    x0 = (1 - NU_GEL**2) / E_GEL * a / 4 * (6 * 2.0 * (0.4e-3 / a**2) ** 2) ** (1 / 3)
    assert hertz == pytest.approx((0.1e-3 / x0) ** 1.5, rel=1e-9)


VALID = (PUNCH_FORCES_N, punch_widths([0.0] * 4), np.zeros((4, 20, 20)))


@pytest.mark.parametrize(
    ("forces", "widths", "depths", "kwargs", "match"),
    [
        (VALID[0][:3], VALID[1], VALID[2], {}, "same number of frames"),
        (VALID[0], VALID[1], VALID[2][0], {}, "depths_mm"),
        (VALID[0][None], VALID[1], VALID[2], {}, "forces_n"),
        (np.array([1.0, np.nan, 2, 3]), VALID[1], VALID[2], {}, "forces_n"),
        (VALID[0], np.array([0.05, np.inf, 0.04, 0.03]), VALID[2], {}, "widths_m"),
        (VALID[0], VALID[1], np.full((4, 20, 20), np.nan), {}, "depths_mm"),
        (np.zeros(0), np.zeros(0), np.zeros((0, 20, 20)), {}, "empty"),
        (np.array(["a", "b", "c", "d"]), VALID[1], VALID[2], {}, "forces_n"),
        (VALID[0], VALID[1], VALID[2], {"marker_depths_mm": np.zeros((3, 20, 20))}, "marker"),
        (VALID[0], VALID[1], VALID[2], {"marker_depths_mm": np.full((4, 5, 5), np.nan)}, "marker"),
        (VALID[0], VALID[1], VALID[2], {"marker_depths_mm": np.zeros((4, 20))}, "marker"),
    ],
)
def test_malformed_input_raises(forces, widths, depths, kwargs, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        dataset_estimates_pa(forces, widths, depths, **kwargs)


def test_press_window_validation() -> None:
    with pytest.raises(ValueError, match="frames"):
        dataset_press_window(np.ones(4), np.ones(3))
    with pytest.raises(ValueError, match="forces_n"):
        dataset_press_window(np.ones((2, 2)), np.ones(4))
    with pytest.raises(ValueError, match="widths_m"):
        interpolate_repeated_widths([1.0, math.nan])


# ---------------------------------------------------------------------------------------
# Against our estimator on a Hertz sphere press (the numbers quoted in docs/physics.md)
# ---------------------------------------------------------------------------------------


def hertz_press(object_modulus_pa: float, radius_m: float = 0.0125, peak_n: float = 10.0):
    """A 25 mm sphere pressed into the gel, two Hertz springs in series (15 frames).

    On the real frame (250 x 350 px at 35 mm / 400 px, ~11.4 px/mm, the physical pixel of
    both the dataset and our estimator), paper gel (2.75e5 Pa); gel depth inside the
    contact = the gel's share of the approach profile; widths close by both approaches.
    """
    sensor = SensorConstants()
    gel_term = (1 - sensor.gel_poisson**2) / sensor.gel_modulus_pa
    e_star = 1 / (gel_term + (1 - sensor.object_poisson**2) / object_modulus_pa)
    rows, cols = np.mgrid[0:250, 0:350]
    r2 = ((rows - 124.5) ** 2 + (cols - 174.5) ** 2) * sensor.pixel_size_m**2
    forces = np.linspace(2.0, peak_n, 15)
    a = (3 * forces * radius_m / (4 * e_star)) ** (1 / 3)
    delta = a**2 / radius_m
    inside = r2[None] <= (a**2)[:, None, None]
    gel_mm = 1e3 * gel_term * e_star * (delta[:, None, None] - r2[None] / (2 * radius_m))
    return forces, OBJECT_LENGTH_M - 2 * delta, np.where(inside, gel_mm, 0.0)


RATIO_MODULI_PA = (3e4, 1e5, 3e5, 1e6, 1e7)


def measure_ratios() -> list[tuple[float, float, float, float, float]]:
    """(E, ours/dataset elastic, ours/dataset Hertz, same with our constants set to the
    dataset's, elastic and Hertz) for each object modulus of the Hertz press."""
    matched = SensorConstants(gel_modulus_pa=1.5e5, pixel_size_m=1e-3 / PX_PER_MM)
    rows = []
    for modulus in RATIO_MODULI_PA:
        forces, widths, depths = hertz_press(modulus)
        ours = analytical_estimates_pa(forces, widths, depths)
        same_constants = analytical_estimates_pa(forces, widths, depths, matched)
        theirs = dataset_estimates_pa(forces, widths, depths)
        rows.append(
            (
                modulus,
                ours[0] / theirs[0],
                ours[1] / theirs[1],
                same_constants[0] / theirs[0],
                same_constants[1] / theirs[1],
            )
        )
    return rows


def test_ratio_to_our_estimator_on_a_hertz_sphere_press() -> None:
    rows = measure_ratios()
    print("\nE [Pa]   ours/dataset elastic  Hertz (decades)   same constants: elastic  Hertz")
    for modulus, el, hz, el_same, hz_same in rows:
        print(
            f"{modulus:8.0e}  {el:8.3f}  {hz:8.3f} ({math.log10(hz):+.2f})"
            f"   {el_same:8.3f}  {hz_same:8.3f}"
        )
    elastic = np.array([r[1] for r in rows])
    hertz = np.array([r[2] for r in rows])
    # Our Hertz E* is ~2.7-3.0x theirs (+0.43..+0.47 decades): (2.75/1.5 gel x
    # (16.40/11.43)^(1/3) from a^(-1/3))^(3/2) = 2.97 for soft objects.
    assert np.all((hertz > 2.6) & (hertz < 3.0))
    assert hertz[0] == pytest.approx(
        (2.75 / 1.5 * (PX_PER_MM * 0.035 / 0.4) ** (1 / 3)) ** 1.5, rel=0.01
    )
    # Our elastic is 0.32-0.49x theirs: (11.43/16.40)^2 = 0.486 from the pixel area for
    # soft objects, less for stiff ones (whole-frame vs contact-mask percentile).
    assert np.all((elastic > 0.3) & (elastic < 0.5))
    assert elastic[0] == pytest.approx((0.4 / (PX_PER_MM * 0.035)) ** 2, rel=0.01)
    # With our constants set to the dataset's, the soft-object gap closes: what is left
    # is the algorithm (percentile, patch, filters), and it grows with stiffness.
    assert rows[0][3] == pytest.approx(1.0, abs=0.01)
    assert rows[0][4] == pytest.approx(1.0, abs=0.01)
    assert rows[-1][3] < 0.8


# ---------------------------------------------------------------------------------------
# The rig-corrected estimate (next to the dataset's two, which the tests above pin)
# ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["dataset", "contact"])
def test_the_rig_corrected_estimate_takes_the_rigs_closure_out(name: str) -> None:
    """Series springs: a gripper of stiffness k closes F / k more than the object and
    gels do. Given k, the rig-corrected estimate is the estimate of the same press on a
    rigid rig; without it, the rig's closure reads as a softer object."""
    from tactile_compliance.physics import rig_corrected_widths_m
    from tactile_compliance.physics.estimators import AnalyticalEstimator

    estimator = AnalyticalEstimator(name)
    depths = block_frames(PUNCH_DEPTHS_MM, (120, 120), slice(30, 90), slice(30, 90))
    rigid_rig = punch_widths([0.0, 0.2, 0.5, 0.9])
    k_rig = 2.2e3  # N/m, the Wedge rig's order
    measured = rigid_rig - np.asarray(PUNCH_FORCES_N) / k_rig
    np.testing.assert_allclose(rig_corrected_widths_m(measured, PUNCH_FORCES_N, k_rig), rigid_rig)
    truth = estimator.estimate(PUNCH_FORCES_N, rigid_rig, depths)
    plain = estimator.estimate(PUNCH_FORCES_N, measured, depths)
    corrected = estimator.estimate(PUNCH_FORCES_N, measured, depths, rig_stiffness_n_per_m=k_rig)
    np.testing.assert_allclose(corrected, truth, rtol=1e-9)
    assert plain[0] < 0.5 * truth[0]  # the rig's closure reads as a much softer object
    # No stiffness: the estimator's own values, bit for bit.
    assert estimator.estimate(PUNCH_FORCES_N, measured, depths, rig_stiffness_n_per_m=None) == plain
    with pytest.raises(ValueError, match="positive stiffness"):
        rig_corrected_widths_m(measured, PUNCH_FORCES_N, 0.0)


def test_the_dataset_estimator_corrects_after_its_width_interpolation() -> None:
    """The stair-stepped widths are interpolated first (the correction would hide the
    repeated readings the interpolation looks for)."""
    from tactile_compliance.physics import rig_corrected_widths_m

    depths = block_frames(PUNCH_DEPTHS_MM, (120, 120), slice(30, 90), slice(30, 90))
    widths = punch_widths([0.0, 0.2, 0.5, 0.9])
    widths[2] = widths[1]  # a repeated reading
    k_rig = 3e3
    corrected = dataset_estimates_pa(PUNCH_FORCES_N, widths, depths, rig_stiffness_n_per_m=k_rig)
    by_hand = dataset_estimates_pa(
        PUNCH_FORCES_N,
        rig_corrected_widths_m(interpolate_repeated_widths(widths), PUNCH_FORCES_N, k_rig),
        depths,
        preprocess=False,
    )
    assert corrected == by_hand
