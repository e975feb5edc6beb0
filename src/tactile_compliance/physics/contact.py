"""Contact mechanics of a GelSight grasp and our analytical estimators (Hooke, Hertz/MDR).

SI units, depth maps in mm (positive into the gel). See docs/physics.md, "Contact
mechanics" and "The analytical estimates on a grasp sequence (ours)".
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeAlias

import numpy as np
import numpy.typing as npt

__all__ = [
    "DEFAULT_GEL_MODULUS_PA",
    "DEFAULT_GEL_POISSON",
    "FINAL_PIPELINE_GEL_MODULUS_PA",
    "SensorConstants",
    "analytical_estimates_pa",
    "effective_modulus_pa",
    "estimate_elastic_modulus_pa",
    "estimate_hertz_effective_modulus_pa",
    "hertz_contact_radius_m",
    "hertz_force_n",
    "hertz_indentation_m",
    "hertz_max_pressure_pa",
    "object_modulus_from_effective_pa",
    "rig_corrected_widths_m",
]

ArrayOrFloat: TypeAlias = float | npt.NDArray[np.float64]
"""A scalar (returned as ``float``) or a numpy array (returned as float64 array)."""

FloatArray: TypeAlias = npt.NDArray[np.float64]

DEFAULT_GEL_MODULUS_PA = 2.75e5
"""Gel Young's modulus [Pa] used in the paper (Shore 00 60 via Larson: 0.275 MPa)."""

FINAL_PIPELINE_GEL_MODULUS_PA = 1.5e5
"""Gel Young's modulus [Pa] of the final published code of Burgess et al."""

DEFAULT_GEL_POISSON = 0.485
"""Poisson ratio [-] of the GelSight silicone gel (nearly incompressible)."""

DEFAULT_OBJECT_POISSON = 0.45
"""Poisson ratio [-] assumed for every grasped object (its true value is unknown)."""

_M_PER_MM = 1.0e-3
_DEPTH_PERCENTILE = 97.0


_FIELD_RULES: dict[str, Callable[[float], bool]] = {
    "finite and > 0": lambda value: bool(np.isfinite(value) and value > 0),
    "finite and >= 0": lambda value: bool(np.isfinite(value) and value >= 0),
    "in (-1, 0.5]": lambda value: -1.0 < value <= 0.5,
    "in [0, 1]": lambda value: 0.0 <= value <= 1.0,
    "in [0, 100]": lambda value: 0.0 <= value <= 100.0,
}


def _check_fields(constants: object, rules: dict[str, tuple[str, ...]]) -> None:
    """Raise ValueError naming the first field of a constants dataclass that breaks its
    rule (a key of :data:`_FIELD_RULES`), checked in the order given."""
    for rule, names in rules.items():
        for name in names:
            value = getattr(constants, name)
            if not _FIELD_RULES[rule](value):
                raise ValueError(f"{type(constants).__name__}.{name} must be {rule}, got {value!r}")


@dataclass(frozen=True)
class SensorConstants:
    """Constants of the GelSight Wedge sensor and of the analytical pipeline.

    Units are in the names (Poisson ratios and fractions are [-]); docs/physics.md,
    "Sensor constants", gives each one's meaning and origin. The gel modulus is the
    paper's; the final published code used 1.5e5 Pa (``FINAL_PIPELINE_GEL_MODULUS_PA``).
    """

    gel_modulus_pa: float = DEFAULT_GEL_MODULUS_PA
    gel_poisson: float = DEFAULT_GEL_POISSON
    object_poisson: float = DEFAULT_OBJECT_POISSON
    gel_thickness_m: float = 5.5e-3
    pad_width_m: float = 35e-3
    pad_height_m: float = 25.5e-3
    pixel_size_m: float = 35e-3 / 400
    contact_depth_threshold_mm: float = 0.1
    min_contact_area_m2: float = 1e-5
    min_depth_fraction: float = 0.075
    fit_tolerance: float = 0.25
    hertz_patch_px: int = 11

    def __post_init__(self) -> None:
        _check_fields(
            self,
            {
                "finite and > 0": (
                    "gel_modulus_pa",
                    "gel_thickness_m",
                    "pad_width_m",
                    "pad_height_m",
                    "pixel_size_m",
                ),
                "finite and >= 0": (
                    "contact_depth_threshold_mm",
                    "min_contact_area_m2",
                    "fit_tolerance",
                ),
                "in (-1, 0.5]": ("gel_poisson", "object_poisson"),
                "in [0, 1]": ("min_depth_fraction",),
            },
        )
        patch = self.hertz_patch_px
        if (
            isinstance(patch, bool)
            or not isinstance(patch, (int, np.integer))
            or patch < 1
            or patch % 2 == 0
        ):
            raise ValueError(
                f"SensorConstants.hertz_patch_px must be a positive odd integer, got {patch!r}"
            )

    @property
    def pixel_area_m2(self) -> float:
        """Area of one depth-map pixel [m^2]."""
        return self.pixel_size_m**2

    @property
    def gel_compliance_per_pa(self) -> float:
        """The gel's term of the effective modulus, ``(1 - nu_gel^2) / E_gel`` [1/Pa]."""
        return (1.0 - self.gel_poisson**2) / self.gel_modulus_pa


# ---------------------------------------------------------------------------------------
# Small helpers for the scalar/array promise and input checks
# ---------------------------------------------------------------------------------------


def _like_inputs(result: FloatArray, *inputs: object) -> ArrayOrFloat:
    """A float when every input was a scalar (not an array, not even a 0-d one), otherwise
    the (broadcast) array: the 'same kind' promise."""
    if all(not isinstance(v, np.ndarray) and np.ndim(v) == 0 for v in inputs):
        return float(result)
    return result


def _as_array(value: object, name: str) -> FloatArray:
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a number or an array of numbers, got {value!r}") from exc
    if np.any(np.isnan(array)):
        raise ValueError(f"{name} contains NaN")
    return array


def _check_positive(
    array: FloatArray, name: str, *, allow_zero: bool = False, allow_inf: bool = False
) -> None:
    bad = array < 0 if allow_zero else array <= 0
    if not allow_inf:
        bad = bad | np.isinf(array)
    if np.any(bad):
        bound = ">= 0" if allow_zero else "> 0"
        finite = "" if allow_inf else "finite and "
        first = float(array[bad].flat[0])
        raise ValueError(f"{name} must be {finite}{bound}, got {first!r}")


def _check_poisson(array: FloatArray, name: str) -> None:
    bad = (array <= -1.0) | (array > 0.5)
    if np.any(bad):
        raise ValueError(f"{name} must be in (-1, 0.5], got {float(array[bad].flat[0])!r}")


# ---------------------------------------------------------------------------------------
# Effective modulus
# ---------------------------------------------------------------------------------------


def effective_modulus_pa(
    modulus_1_pa: ArrayOrFloat,
    poisson_1: ArrayOrFloat,
    modulus_2_pa: ArrayOrFloat,
    poisson_2: ArrayOrFloat,
) -> ArrayOrFloat:
    """Effective (reduced) modulus E* [Pa] of two elastic bodies in contact.

    ``1/E* = (1 - nu1^2)/E1 + (1 - nu2^2)/E2`` with moduli in Pa and Poisson ratios [-].
    Broadcasts like numpy. ``np.inf`` is a valid modulus (a rigid body adds no
    compliance); two rigid bodies give ``inf``.

    Raises:
        ValueError: a modulus that is NaN or <= 0, a Poisson ratio outside (-1, 0.5].
    """
    e1 = _as_array(modulus_1_pa, "modulus_1_pa")
    nu1 = _as_array(poisson_1, "poisson_1")
    e2 = _as_array(modulus_2_pa, "modulus_2_pa")
    nu2 = _as_array(poisson_2, "poisson_2")
    _check_positive(e1, "modulus_1_pa", allow_inf=True)
    _check_positive(e2, "modulus_2_pa", allow_inf=True)
    _check_poisson(nu1, "poisson_1")
    _check_poisson(nu2, "poisson_2")
    compliance_per_pa = (1.0 - nu1**2) / e1 + (1.0 - nu2**2) / e2
    # Zero compliance (both rigid) is an infinitely stiff contact, not an error.
    with np.errstate(divide="ignore"):
        result = 1.0 / compliance_per_pa
    return _like_inputs(
        np.asarray(result, dtype=np.float64), modulus_1_pa, poisson_1, modulus_2_pa, poisson_2
    )


def object_modulus_from_effective_pa(
    effective_modulus_pa: ArrayOrFloat,
    gel_modulus_pa: ArrayOrFloat = DEFAULT_GEL_MODULUS_PA,
    gel_poisson: ArrayOrFloat = DEFAULT_GEL_POISSON,
    object_poisson: ArrayOrFloat = DEFAULT_OBJECT_POISSON,
) -> ArrayOrFloat:
    """The object's Young's modulus E [Pa] from the gel-object effective modulus E* [Pa].

    ``inf`` for an E* at or above the gel's cap ``E_gel / (1 - nu_gel^2)`` (rigid as far as
    the sensor can tell), ``nan`` stays ``nan``; docs/physics.md, "E* -> the object's E".

    Raises:
        ValueError: E* <= 0, a gel modulus that is NaN or <= 0, a Poisson ratio outside
            (-1, 0.5].
    """
    e_star = np.asarray(effective_modulus_pa, dtype=np.float64)
    e_gel = _as_array(gel_modulus_pa, "gel_modulus_pa")
    nu_gel = _as_array(gel_poisson, "gel_poisson")
    nu_obj = _as_array(object_poisson, "object_poisson")
    _check_positive(e_star[~np.isnan(e_star)], "effective_modulus_pa", allow_inf=True)
    _check_positive(e_gel, "gel_modulus_pa", allow_inf=True)
    _check_poisson(nu_gel, "gel_poisson")
    _check_poisson(nu_obj, "object_poisson")
    object_compliance_per_pa = 1.0 / e_star - (1.0 - nu_gel**2) / e_gel
    with np.errstate(divide="ignore", invalid="ignore"):
        result = np.where(
            object_compliance_per_pa > 0.0,
            (1.0 - nu_obj**2) / object_compliance_per_pa,
            np.inf,
        )
    # np.where sends NaN (failed estimates) to the inf branch; keep them NaN.
    result = np.where(np.isnan(object_compliance_per_pa), np.nan, result)
    return _like_inputs(
        np.asarray(result, dtype=np.float64),
        effective_modulus_pa,
        gel_modulus_pa,
        gel_poisson,
        object_poisson,
    )


# ---------------------------------------------------------------------------------------
# Hertz sphere-on-flat contact
# ---------------------------------------------------------------------------------------


def _hertz_arguments(
    load: ArrayOrFloat, load_name: str, radius_m: ArrayOrFloat, effective_modulus_pa: ArrayOrFloat
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Checked arrays of a Hertz formula's arguments: the load (a force or an indentation,
    >= 0), the radius of curvature R [m] and the effective modulus E* [Pa] (both > 0)."""
    load_array = _as_array(load, load_name)
    radius = _as_array(radius_m, "radius_m")
    e_star = _as_array(effective_modulus_pa, "effective_modulus_pa")
    _check_positive(load_array, load_name, allow_zero=True)
    _check_positive(radius, "radius_m")
    _check_positive(e_star, "effective_modulus_pa")
    return load_array, radius, e_star


def hertz_contact_radius_m(
    force_n: ArrayOrFloat, radius_m: ArrayOrFloat, effective_modulus_pa: ArrayOrFloat
) -> ArrayOrFloat:
    """Hertz contact radius ``a = (3 F R / (4 E*))^(1/3)`` [m].

    Args:
        force_n: normal force F [N], >= 0.
        radius_m: effective radius of curvature R [m], > 0.
        effective_modulus_pa: effective modulus E* [Pa], > 0.
    """
    force, radius, e_star = _hertz_arguments(force_n, "force_n", radius_m, effective_modulus_pa)
    result = np.cbrt(3.0 * force * radius / (4.0 * e_star))
    return _like_inputs(result, force_n, radius_m, effective_modulus_pa)


def hertz_indentation_m(
    force_n: ArrayOrFloat, radius_m: ArrayOrFloat, effective_modulus_pa: ArrayOrFloat
) -> ArrayOrFloat:
    """Hertz indentation (total approach of the two bodies) ``delta = a^2 / R`` [m].

    The arguments are those of :func:`hertz_contact_radius_m` (F [N], R [m], E* [Pa]).
    """
    contact_radius_m = np.asarray(
        hertz_contact_radius_m(force_n, radius_m, effective_modulus_pa), dtype=np.float64
    )
    result = contact_radius_m**2 / np.asarray(radius_m, dtype=np.float64)
    return _like_inputs(result, force_n, radius_m, effective_modulus_pa)


def hertz_force_n(
    indentation_m: ArrayOrFloat, radius_m: ArrayOrFloat, effective_modulus_pa: ArrayOrFloat
) -> ArrayOrFloat:
    """Hertz normal force ``F = 4/3 E* sqrt(R) delta^(3/2)`` [N].

    Args:
        indentation_m: total approach delta [m], >= 0.
        radius_m: effective radius of curvature R [m], > 0.
        effective_modulus_pa: effective modulus E* [Pa], > 0.
    """
    delta, radius, e_star = _hertz_arguments(
        indentation_m, "indentation_m", radius_m, effective_modulus_pa
    )
    result = 4.0 / 3.0 * e_star * np.sqrt(radius) * delta**1.5
    return _like_inputs(result, indentation_m, radius_m, effective_modulus_pa)


def hertz_max_pressure_pa(force_n: ArrayOrFloat, contact_radius_m: ArrayOrFloat) -> ArrayOrFloat:
    """Peak Hertz contact pressure ``p0 = 3 F / (2 pi a^2)`` [Pa].

    Args:
        force_n: normal force F [N], >= 0.
        contact_radius_m: contact radius a [m], > 0.
    """
    force = _as_array(force_n, "force_n")
    radius = _as_array(contact_radius_m, "contact_radius_m")
    _check_positive(force, "force_n", allow_zero=True)
    _check_positive(radius, "contact_radius_m")
    result = 3.0 * force / (2.0 * np.pi * radius**2)
    return _like_inputs(result, force_n, contact_radius_m)


# ---------------------------------------------------------------------------------------
# The analytical estimators on a grasp sequence
# ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _GraspContact:
    """Per-frame contact quantities shared by both estimators (all arrays shape (T,))."""

    forces_n: FloatArray
    widths_m: FloatArray
    area_m2: FloatArray
    """Contact area: pixels with depth >= threshold, times the pixel area."""
    d97_mm: FloatArray
    """97th percentile of the depth over the contact mask (0 without contact)."""
    max_depth_mm: FloatArray
    patch_depth_mm: FloatArray
    """Mean depth of the patch centred on the deepest pixel."""
    fit_mask: npt.NDArray[np.bool_]
    """Frames entering the fits: kept (depth/area) and depth/force consistent."""
    initial_length_m: float
    """L0 = W[i_c] + 2 d97[i_c]; NaN when no frame reaches the contact threshold."""


def _validate_sequence(
    forces_n: npt.ArrayLike, widths_m: npt.ArrayLike, depths_mm: npt.ArrayLike
) -> tuple[FloatArray, FloatArray, np.ndarray]:
    forces = np.asarray(forces_n)
    widths = np.asarray(widths_m)
    depths = np.asarray(depths_mm)
    for name, array in (("forces_n", forces), ("widths_m", widths), ("depths_mm", depths)):
        if not (np.issubdtype(array.dtype, np.floating) or np.issubdtype(array.dtype, np.integer)):
            raise ValueError(f"{name} must hold real numbers, got dtype {array.dtype}")
    if forces.ndim != 1:
        raise ValueError(f"forces_n must have shape (T,), got shape {forces.shape}")
    if widths.ndim != 1:
        raise ValueError(f"widths_m must have shape (T,), got shape {widths.shape}")
    if depths.ndim != 3:
        raise ValueError(f"depths_mm must have shape (T, H, W), got shape {depths.shape}")
    n_frames = forces.shape[0]
    if n_frames == 0:
        raise ValueError("the grasp sequence is empty (T = 0 frames)")
    if widths.shape[0] != n_frames or depths.shape[0] != n_frames:
        raise ValueError(
            "forces_n, widths_m and depths_mm must have the same number of frames, got "
            f"{n_frames}, {widths.shape[0]} and {depths.shape[0]}"
        )
    if depths.shape[1] == 0 or depths.shape[2] == 0:
        raise ValueError(f"depths_mm frames are empty, got shape {depths.shape}")
    for name, array in (("forces_n", forces), ("widths_m", widths), ("depths_mm", depths)):
        if not np.all(np.isfinite(array)):
            raise ValueError(f"{name} contains NaN or infinite values")
    # Depths stay in their own dtype (possibly a memmap); frames are upcast one at a time.
    return forces.astype(np.float64), widths.astype(np.float64), depths


def _patch_mean(frame: FloatArray, size_px: int) -> float:
    """Mean of the size x size patch centred on the deepest pixel, clipped at the borders.

    Ties for the deepest pixel go to the first one in row-major order (``np.argmax``).
    """
    row, col = np.unravel_index(int(np.argmax(frame)), frame.shape)
    half = size_px // 2
    patch = frame[max(row - half, 0) : row + half + 1, max(col - half, 0) : col + half + 1]
    return float(patch.mean())


def _grasp_contact(
    forces_n: npt.ArrayLike,
    widths_m: npt.ArrayLike,
    depths_mm: npt.ArrayLike,
    constants: SensorConstants,
) -> _GraspContact:
    forces, widths, depths = _validate_sequence(forces_n, widths_m, depths_mm)
    n_frames = forces.shape[0]
    threshold_mm = constants.contact_depth_threshold_mm

    area_m2 = np.zeros(n_frames)
    d97_mm = np.zeros(n_frames)
    max_depth_mm = np.zeros(n_frames)
    patch_depth_mm = np.zeros(n_frames)
    for i in range(n_frames):
        frame = np.asarray(depths[i], dtype=np.float64)
        mask = frame >= threshold_mm
        n_contact = int(np.count_nonzero(mask))
        area_m2[i] = n_contact * constants.pixel_area_m2
        if n_contact:
            # Over the contact mask, not the whole frame: a whole-frame percentile would be
            # ~0 whenever the contact covers < 3 % of the pad, which most contacts do.
            d97_mm[i] = float(np.percentile(frame[mask], _DEPTH_PERCENTILE))
        max_depth_mm[i] = float(frame.max())
        patch_depth_mm[i] = _patch_mean(frame, constants.hertz_patch_px)

    peak_depth_mm = float(max_depth_mm.max())
    # i_c: the first frame in contact. With d97 taken over the mask this is the first frame
    # with any pixel at/above the threshold; the area test covers a threshold of 0.
    touching = np.flatnonzero((area_m2 > 0) & (d97_mm >= threshold_mm))
    if touching.size == 0 or peak_depth_mm <= 0:
        initial_length_m = float("nan")
    else:
        i_c = int(touching[0])
        initial_length_m = float(widths[i_c] + 2.0 * d97_mm[i_c] * _M_PER_MM)

    kept = (
        (max_depth_mm >= constants.min_depth_fraction * peak_depth_mm)
        & (area_m2 >= constants.min_contact_area_m2)
        & (area_m2 > 0)
    )
    peak_force_n = float(forces.max())
    if peak_depth_mm > 0 and peak_force_n > 0:
        # Depth and force must agree on how far into the press a frame is; frames where
        # they disagree (slip, reconstruction glitches, the unloading tail) are dropped.
        consistent = (
            np.abs(max_depth_mm / peak_depth_mm - forces / peak_force_n) <= constants.fit_tolerance
        )
        fit_mask = kept & consistent
    else:
        fit_mask = np.zeros(n_frames, dtype=bool)

    return _GraspContact(
        forces_n=forces,
        widths_m=widths,
        area_m2=area_m2,
        d97_mm=d97_mm,
        max_depth_mm=max_depth_mm,
        patch_depth_mm=patch_depth_mm,
        fit_mask=fit_mask,
        initial_length_m=initial_length_m,
    )


def _slope_through_origin(x: FloatArray, y: FloatArray) -> float:
    """Least-squares slope of ``y = k x`` (``sum(x y) / sum(x^2)``); NaN if not formable,
    not finite or not positive."""
    if x.size < 1:
        return float("nan")
    sum_xx = float(np.dot(x, x))
    if not (np.isfinite(sum_xx) and sum_xx > 0):
        return float("nan")
    slope = float(np.dot(x, y)) / sum_xx
    return slope if np.isfinite(slope) and slope > 0 else float("nan")


def _elastic_from_contact(contact: _GraspContact) -> float:
    length_0_m = contact.initial_length_m
    if not (np.isfinite(length_0_m) and length_0_m > 0):
        return float("nan")
    sel = contact.fit_mask
    # Object's compressed length: the width plus both gels' indentation (two fingers).
    compressed_m = contact.widths_m[sel] + 2.0 * contact.d97_mm[sel] * _M_PER_MM
    strain = (length_0_m - compressed_m) / length_0_m
    stress_pa = contact.forces_n[sel] / contact.area_m2[sel]
    return _slope_through_origin(strain, stress_pa)


def _hertz_from_contact(contact: _GraspContact, constants: SensorConstants) -> float:
    length_0_m = contact.initial_length_m
    if not np.isfinite(length_0_m):
        return float("nan")
    approach_m = (length_0_m - contact.widths_m) / 2.0
    # A Hertz point needs a real approach and a pushing force, else R and p0 are undefined.
    sel = contact.fit_mask & (approach_m > 0) & (contact.forces_n > 0)
    force_n = contact.forces_n[sel]
    contact_radius_m = np.sqrt(contact.area_m2[sel] / np.pi)
    sphere_radius_m = contact_radius_m**2 / approach_m[sel]
    # p0 without the E*^(2/3) factor: the fit's slope k is E*^(2/3).
    reduced_p0 = np.cbrt(6.0 * force_n / sphere_radius_m**2) / np.pi
    x = constants.gel_compliance_per_pa * (np.pi * contact_radius_m / 4.0) * reduced_p0
    y = contact.patch_depth_mm[sel] * _M_PER_MM
    return float(_slope_through_origin(x, y) ** 1.5)


def estimate_elastic_modulus_pa(
    forces_n: npt.ArrayLike,
    widths_m: npt.ArrayLike,
    depths_mm: npt.ArrayLike,
    constants: SensorConstants = SensorConstants(),
) -> float:
    """Hooke (simple elastic) estimate E_elastic [Pa] of the object from a grasp sequence,
    ``nan`` when it cannot be formed. Arguments and errors as :func:`analytical_estimates_pa`.
    """
    return _elastic_from_contact(_grasp_contact(forces_n, widths_m, depths_mm, constants))


def estimate_hertz_effective_modulus_pa(
    forces_n: npt.ArrayLike,
    widths_m: npt.ArrayLike,
    depths_mm: npt.ArrayLike,
    constants: SensorConstants = SensorConstants(),
) -> float:
    """Hertz/MDR estimate of the gel-object effective modulus E* [Pa] from a grasp sequence,
    ``nan`` when it cannot be formed; :func:`object_modulus_from_effective_pa` converts it
    to the object's E. Arguments and errors as :func:`analytical_estimates_pa`.
    """
    return _hertz_from_contact(_grasp_contact(forces_n, widths_m, depths_mm, constants), constants)


def analytical_estimates_pa(
    forces_n: npt.ArrayLike,
    widths_m: npt.ArrayLike,
    depths_mm: npt.ArrayLike,
    constants: SensorConstants = SensorConstants(),
) -> tuple[float, float]:
    """Both analytical estimates ``(E_elastic [Pa], E*_hertz [Pa])`` of one grasp sequence.

    Same results as :func:`estimate_elastic_modulus_pa` and
    :func:`estimate_hertz_effective_modulus_pa`, but the per-frame contact analysis
    (masks, areas, percentiles, patches) is done once.

    Args:
        forces_n: normal force per frame [N], shape (T,).
        widths_m: gripper width per frame [m], shape (T,).
        depths_mm: gel indentation depth maps [mm] (positive into the gel), shape
            (T, H, W), on a grid of ``constants.pixel_size_m``.
        constants: sensor constants.

    Returns:
        Two floats; ``nan`` for an estimate a degenerate grasp cannot give (no contact, no
        usable frame, a non-positive fitted slope).

    Raises:
        ValueError: malformed input (shapes, frame counts, NaN/inf values).
    """
    contact = _grasp_contact(forces_n, widths_m, depths_mm, constants)
    return _elastic_from_contact(contact), _hertz_from_contact(contact, constants)


def rig_corrected_widths_m(
    widths_m: npt.ArrayLike, forces_n: npt.ArrayLike, rig_stiffness_n_per_m: float
) -> FloatArray:
    """Gripper widths [m] with the rig's own closure taken out: ``W + F / k_rig``.

    The gripper's fingers and mount are a spring in series with the gel and the object,
    so the measured closure is the object's (and gel's) plus ``F / k_rig``: subtracting it
    is ``1 / k_object = 1 / k_measured - 1 / k_rig``. ``k_rig`` [N/m] is what a grasp of a
    rigid object measures (``calibrate-rig``'s ``GripperRig.stiffness_n_per_m``).

    Args:
        widths_m: measured widths per frame [m], (T,).
        forces_n: normal force per frame [N], (T,).
        rig_stiffness_n_per_m: the rig's stiffness [N/m], finite and > 0.

    Returns:
        A new float64 array (T,) [m].

    Raises:
        ValueError: a non-positive or non-finite stiffness, or shapes that differ.
    """
    stiffness = float(rig_stiffness_n_per_m)
    if not (np.isfinite(stiffness) and stiffness > 0):
        raise ValueError(
            f"rig_stiffness_n_per_m must be a positive stiffness in N/m, got {stiffness}"
        )
    widths = np.asarray(widths_m, dtype=np.float64)
    forces = np.asarray(forces_n, dtype=np.float64)
    if widths.shape != forces.shape:
        raise ValueError(f"widths {widths.shape} and forces {forces.shape} differ in shape")
    return widths + forces / stiffness
