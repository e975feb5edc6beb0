"""Contact mechanics of a gel pad pressed against an object: closed form, per cell.

Gel and object are two foundations in series; lengths in mm, pressures in Pa. See
docs/synthetic.md, "Mechanics" (the model, its limits, the conformity of rendered fields).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from tactile_compliance.physics.contact import DEFAULT_GEL_MODULUS_PA
from tactile_compliance.synthetic.geometry import NO_SURFACE, PadGrid

__all__ = [
    "CONFORM_SIGMA_H",
    "ContactCurve",
    "GelModel",
    "ObjectMechanics",
    "contact_curve",
    "force_curve",
    "gel_compression",
    "shell_stiffness_n_per_m",
]


CONFORM_SIGMA_H = 0.3
"""Spread of the gel's response to a compliant object's smooth pressure, in gel
thicknesses (sigma of the Gaussian in :func:`gel_compression_fields`) [-]."""


@dataclass(frozen=True)
class GelModel:
    """The sensor's elastomer.

    Attributes:
        modulus_pa: Young's modulus of the gel [Pa] (Shore 00 ~60: 2.75e5,
            ``physics.contact.DEFAULT_GEL_MODULUS_PA``).
        poisson: Poisson ratio of the gel [-].
        thickness_mm: gel thickness h [mm].
        max_strain: saturating compressive strain of the gel [-].
        confinement_kappa: ``(a_c / h)^2`` at which the layer is halfway stiffened
            towards its confined modulus [-]; calibrated (docs/synthetic.md, "Mechanics").
    """

    modulus_pa: float = DEFAULT_GEL_MODULUS_PA
    poisson: float = 0.485
    thickness_mm: float = 5.0
    max_strain: float = 0.55
    confinement_kappa: float = 16.0

    @property
    def plane_strain_modulus_pa(self) -> float:
        """E / (1 - nu^2) [Pa]."""
        return self.modulus_pa / (1.0 - self.poisson**2)

    @property
    def confined_ratio(self) -> float:
        """Confined modulus over plane-strain modulus, (1 - nu)^2 / (1 - 2 nu) [-]."""
        return (1.0 - self.poisson) ** 2 / (1.0 - 2.0 * self.poisson)

    def contact_modulus_pa(self, semi_axis_mm: np.ndarray) -> np.ndarray:
        """Effective gel modulus for a contact of minor semi-axis ``a_c`` [Pa]."""
        r2 = (np.asarray(semi_axis_mm, dtype=np.float64) / self.thickness_mm) ** 2
        stiffening = (self.confined_ratio - 1.0) * r2 / (r2 + self.confinement_kappa)
        return self.plane_strain_modulus_pa * (1.0 + stiffening)


@dataclass(frozen=True)
class ObjectMechanics:
    """The object's side of the contact.

    Attributes:
        modulus_pa: Young's modulus that drives the physics [Pa] (label x mismatch).
        poisson: Poisson ratio [-].
        size_mm: object size along the grasp axis, sets the depth of influence [mm].
        max_strain: saturating compressive strain [-].
        shell_stiffness_n_per_m: series stiffness of a hollow shell per contact [N/m]
            (``inf`` for solid objects).
    """

    modulus_pa: float
    poisson: float = 0.45
    size_mm: float = 50.0
    max_strain: float = 0.3
    shell_stiffness_n_per_m: float = float("inf")

    @property
    def plane_strain_modulus_pa(self) -> float:
        """E / (1 - nu^2) [Pa]."""
        return self.modulus_pa / (1.0 - self.poisson**2)


def shell_stiffness_n_per_m(
    modulus_pa: float, poisson: float, thickness_mm: float, radius_mm: float
) -> float:
    """Point-load stiffness of a thin spherical/cylindrical shell [N/m].

    ``k = 4 E t^2 / (R sqrt(3 (1 - nu^2)))`` (Reissner), with t, R in metres.
    """
    t, r = thickness_mm * 1e-3, max(radius_mm, thickness_mm) * 1e-3
    return float(4.0 * modulus_pa * t**2 / (r * np.sqrt(3.0 * (1.0 - poisson**2))))


@dataclass
class ContactCurve:
    """Force-approach curve of one finger and the fields needed to render it.

    Attributes:
        approaches_mm: approaches Delta [mm], increasing.
        forces_n: normal force at each approach [N], non-decreasing.
        contact_area_mm2: area of {s < Delta} inside the pad [mm^2].
        gel_depth_mm: gel compression field delta_g per approach, (K, rows, cols) [mm]
            (only when fields were requested).
        object_share: the object's share of the deformation per approach,
            sum(delta_o) / sum(delta_g + delta_o) over the contact [-] (only with fields).
    """

    approaches_mm: np.ndarray
    forces_n: np.ndarray
    contact_area_mm2: np.ndarray
    gel_depth_mm: np.ndarray | None = None
    object_share: np.ndarray | None = None

    def approach_at(self, force_n: np.ndarray | float) -> np.ndarray:
        """Approach [mm] at a force [N] (monotone interpolation in log-log)."""
        f = np.maximum(np.asarray(force_n, dtype=np.float64), 1e-9)
        logf = np.log(np.maximum(self.forces_n, 1e-12))
        # A strictly increasing abscissa for np.interp (plateaus only at ~0 N).
        logf = np.maximum.accumulate(logf + np.arange(logf.size) * 1e-12)
        delta = np.exp(np.interp(np.log(f), logf, np.log(self.approaches_mm)))
        # Below the first point the contact is Hertz-like: Delta ~ F^(2/3).
        low = f < self.forces_n[0]
        if np.any(low):
            delta = np.where(
                low,
                self.approaches_mm[0] * (f / max(self.forces_n[0], 1e-12)) ** (2 / 3),
                delta,
            )
        return delta


def _semi_axis_mm(
    w: np.ndarray,
    approaches: np.ndarray,
    candidates: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    grid_shape: tuple[int, int],
    cell_mm: float,
) -> np.ndarray:
    """Minor semi-axis a_c [mm] of each contact (K, n).

    Two estimates, the smaller wins: the second moments of the contact (right for one
    elongated patch: a strip of half-width b gives b) and ``2 A / P`` (area over
    perimeter: right for several separate patches, which the moments would treat as one
    huge patch). Cells are weighted by ``min(w / (0.1 Delta), 1)``, so a cell entering
    the contact starts with weight 0 and a_c grows continuously with the approach
    instead of jumping when a ring of pixels appears; the perimeter is the total
    variation of that weight field (x pi/4, the grid's excess for round shapes).
    The factor 1.03 splits the remaining model error between a flat punch (-3 %)
    and a Hertz sphere (+3 %).
    """
    weight32 = np.clip(w / (0.1 * approaches[:, None]).astype(np.float32), 0.0, 1.0)
    weight = weight32.astype(np.float64)
    n = weight.sum(axis=1)
    safe = np.maximum(n, 1e-12)
    mx, my = weight @ x / safe, weight @ y / safe
    cxx = weight @ (x * x) / safe - mx**2
    cyy = weight @ (y * y) / safe - my**2
    cxy = weight @ (x * y) / safe - mx * my
    half_trace = 0.5 * (cxx + cyy)
    lam_min = half_trace - np.sqrt(np.maximum((0.5 * (cxx - cyy)) ** 2 + cxy**2, 0.0))
    # Pixelation adds cell^2 / 12 to the variance of a few-cell contact.
    a_moments = 2.0 * np.sqrt(np.maximum(lam_min, 0.0) + cell_mm**2 / 12.0)
    field = np.zeros((w.shape[0], grid_shape[0] * grid_shape[1]), dtype=np.float32)
    field[:, candidates] = weight32
    field = field.reshape(w.shape[0], *grid_shape)
    tv = np.abs(np.diff(field, axis=1)).sum(axis=(1, 2)) + np.abs(np.diff(field, axis=2)).sum(
        axis=(1, 2)
    )
    # Contact touching the pad border: the border is not free perimeter.
    perimeter = np.maximum(tv * (np.pi / 4.0), 1e-12) * cell_mm
    a_patches = 2.0 * n * cell_mm**2 / perimeter
    a = 1.03 * np.minimum(a_moments, np.maximum(a_patches, 0.5 * cell_mm))
    return np.where(n > 0, a, 0.0)


def contact_curve(
    sag_mm: np.ndarray,
    gel: GelModel,
    obj: ObjectMechanics,
    grid: PadGrid,
    approaches_mm: np.ndarray,
    fields: bool = False,
) -> ContactCurve:
    """Force-approach curve of one finger at ``approaches_mm`` [mm] for the sag map
    ``sag_mm`` [mm] on ``grid``; ``fields`` also returns the gel compression fields
    (K, rows, cols) [mm]."""
    approaches = np.asarray(approaches_mm, dtype=np.float64)
    sag = np.asarray(sag_mm, dtype=np.float64)
    flat = sag.ravel()
    # Only cells that can ever touch matter: work on that compressed set.
    candidates = np.flatnonzero(flat < min(approaches.max(), NO_SURFACE * 0.5))
    s = flat[candidates]
    xx, yy = grid.coords()
    x = xx.ravel()[candidates].astype(np.float64)
    y = yy.ravel()[candidates].astype(np.float64)

    # float32 is enough: the root below is taken in its cancellation-free form.
    w = (approaches[:, None] - s[None, :]).astype(np.float32)  # interference [mm], (K, n)
    masks = w > 0
    area_mm2 = masks.sum(axis=1) * grid.cell_mm**2
    a_c = _semi_axis_mm(w, approaches, candidates, x, y, sag.shape, grid.cell_mm)
    if np.all(np.diff(approaches) > 0):
        # A contact never shrinks while the finger advances: keep a_c non-decreasing so
        # the depths of influence (and the force) cannot drop when a new patch appears.
        a_c = np.maximum.accumulate(a_c)
    a_safe = np.maximum(a_c, 1e-6)[:, None]
    l_g = (1.0 / (2.0 / (np.pi * a_safe) + 1.0 / gel.thickness_mm)).astype(np.float32)
    l_o = (1.0 / (2.0 / (np.pi * a_safe) + 2.0 / max(obj.size_mm, 1e-3))).astype(np.float32)
    e_c = gel.contact_modulus_pa(a_safe).astype(np.float32)
    e_o = np.float32(obj.plane_strain_modulus_pa)
    inv_eg, inv_eo = np.float32(1.0 / gel.max_strain), np.float32(1.0 / obj.max_strain)
    # Beyond w_max both foundations are fully compressed: clip just below it.
    w_max = l_g * gel.max_strain + l_o * obj.max_strain
    wc = np.clip(w, np.float32(0.0), np.float32(0.995) * w_max)
    qa = inv_eg * inv_eo * (wc - w_max)
    qb = wc * (e_c * inv_eo + e_o * inv_eg) - (l_g * e_o + l_o * e_c)
    qc = wc * e_c * e_o
    disc = np.sqrt(np.maximum(qb * qb - np.float32(4.0) * qa * qc, np.float32(0.0)))
    denom = -qb + disc
    # Divide only inside the contact: np.where would divide in every cell and overflow
    # (a RuntimeWarning in every generator process) where denom is tiny outside it.
    valid = masks & (denom > 0)
    pressure = np.divide(2.0 * qc, denom, out=np.zeros(valid.shape, np.float32), where=valid)
    forces = pressure.sum(axis=1, dtype=np.float64) * grid.cell_area_m2
    gel_depth = None
    object_share = None
    if fields:
        dg = l_g * pressure / (e_c + pressure * inv_eg)
        do = l_o * pressure / (e_o + pressure * inv_eo)
        total = (dg + do).sum(axis=1, dtype=np.float64)
        object_share = np.where(
            total > 0, do.sum(axis=1, dtype=np.float64) / np.maximum(total, 1e-30), 0.0
        )
        gel_depth = np.zeros((approaches.size, flat.size), dtype=np.float32)
        gel_depth[:, candidates] = dg
        gel_depth = gel_depth.reshape(approaches.size, *sag.shape)
    return ContactCurve(approaches, forces, area_mm2, gel_depth, object_share)


def force_curve(
    sag_mm: np.ndarray,
    gel: GelModel,
    obj: ObjectMechanics,
    grid: PadGrid,
    max_force_n: float = 90.0,
) -> ContactCurve:
    """Force-approach curve resolved where it is used: up to ``max_force_n`` [N].

    A coarse pass over 1 um - 20 mm brackets the approach at ``max_force_n``; the
    returned curve has 32 geometric approaches from 1/400 of it up to it (the
    force there is ~1e-4 of the maximum; below, :meth:`ContactCurve.approach_at`
    extrapolates Hertz-like). Restricting the range keeps the work on the cells that
    can touch.
    """
    coarse = contact_curve(sag_mm, gel, obj, grid, np.geomspace(1e-3, 20.0, 16))
    # log-log interpolation of the bracket, with 20 % headroom; widen if still short.
    top = 1.2 * float(coarse.approach_at(max_force_n))
    for _ in range(4):
        curve = contact_curve(sag_mm, gel, obj, grid, np.geomspace(top / 400.0, top, 32))
        if curve.forces_n[-1] >= max_force_n or top >= 40.0:
            return curve
        top *= 1.5
    return curve


def _conform(stack: np.ndarray, object_share: np.ndarray, gel: GelModel, grid: PadGrid) -> None:
    """Shape gel fields (n, rows, cols) [mm], float32, in place as a compliant object presses
    them: ``(1 - c_o) d_g + c_o G_sigma * d_g`` inside the contact (zero
    outside, where the renderer's skirt drapes the membrane), ``sigma = CONFORM_SIGMA_H x
    h``, rescaled to the volume of ``d_g`` (the same load); ``object_share`` is each
    field's ``c_o`` [-]."""
    shares = np.clip(object_share, 0.0, 1.0)
    active = np.flatnonzero(shares >= 1e-3)
    if active.size == 0:
        return
    touched = stack[active].max(axis=0) > 0
    rows, cols = np.flatnonzero(touched.any(axis=1)), np.flatnonzero(touched.any(axis=0))
    if rows.size == 0:
        return
    # The blur reaches 4 sigma (OpenCV's kernel): work on the contact's box only.
    sigma = CONFORM_SIGMA_H * gel.thickness_mm / grid.cell_mm
    m = int(np.ceil(4.0 * sigma)) + 1
    box = (
        slice(max(int(rows[0]) - m, 0), min(int(rows[-1]) + m + 1, touched.shape[0])),
        slice(max(int(cols[0]) - m, 0), min(int(cols[-1]) + m + 1, touched.shape[1])),
    )
    crop = stack[(active, *box)]  # (k, h, w) copy
    h, w = crop.shape[1:]
    coarse = (max(w // 2, 1), max(h // 2, 1))  # OpenCV's (width, height)
    smooth = np.empty_like(crop)
    for i in range(crop.shape[0]):
        # The response is smooth: blur a 2x coarser copy (4x fewer cells, a 2x shorter
        # kernel) and interpolate back.
        small = cv2.resize(crop[i], coarse, interpolation=cv2.INTER_AREA)
        small = cv2.GaussianBlur(small, (0, 0), sigma / 2, borderType=cv2.BORDER_CONSTANT)
        smooth[i] = cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)
    smooth -= crop
    smooth *= shares[active].astype(np.float32)[:, None, None]
    smooth += crop
    smooth[crop <= 0] = 0.0
    # What the blur moved past the contact's edge stays in it: the same volume.
    before = crop.sum(axis=(1, 2), dtype=np.float64)
    after = smooth.sum(axis=(1, 2), dtype=np.float64)
    scale = np.where(after > 0, before / np.maximum(after, 1e-30), 1.0)
    smooth *= scale.astype(np.float32)[:, None, None]
    stack[(active, *box)] = smooth


def _narrow(stack: np.ndarray, object_share: np.ndarray, spread: float) -> None:
    """Scale each compliant field (n, rows, cols) [mm] about its centroid, in place, by
    ``1 - c_o (1 - spread)`` in radius, keeping its volume (the same load): a rigid
    contact (``c_o`` 0) keeps its footprint, a soft one's shrinks (``spread`` < 1) and
    deepens. The rig's ``soft_contact_spread`` (``synthetic.rig.GripperRig``)."""
    shares = np.clip(object_share, 0.0, 1.0)
    rows, cols = stack.shape[1:]
    yy, xx = np.mgrid[0:rows, 0:cols].astype(np.float32)
    for k in np.flatnonzero(np.abs(shares * (1.0 - spread)) > 1e-3):
        field = stack[k]
        volume = float(field.sum(dtype=np.float64))
        if volume <= 0:
            continue
        factor = float(1.0 - shares[k] * (1.0 - spread))
        cy = float((field * yy).sum(dtype=np.float64)) / volume
        cx = float((field * xx).sum(dtype=np.float64)) / volume
        matrix = np.array(
            [[factor, 0.0, cx * (1.0 - factor)], [0.0, factor, cy * (1.0 - factor)]],
            dtype=np.float64,
        )
        warped = cv2.warpAffine(
            field, matrix, (cols, rows), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT
        )
        np.maximum(warped, 0.0, out=warped)
        after = float(warped.sum(dtype=np.float64))
        stack[k] = warped * np.float32(volume / after) if after > 0 else field


def gel_compression(
    sag_mm: np.ndarray,
    gel: GelModel,
    obj: ObjectMechanics,
    grid: PadGrid,
    approaches_mm: np.ndarray,
    conformity: bool = True,
    spread: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Gel compression fields (n, rows, cols) [mm] at each approach and the object's share
    of the deformation (n,) [-]; both zero where the approach is 0 (no contact), which
    :func:`contact_curve` cannot evaluate.

    With ``conformity`` (default) each field is shaped by :func:`_conform`: compliant
    objects press soft-edged imprints, rigid ones print their geometry; ``spread`` (the
    rig's ``soft_contact_spread``, 1: none) then narrows compliant imprints
    (:func:`_narrow`)."""
    approaches = np.asarray(approaches_mm, dtype=np.float64)
    fields = np.zeros((approaches.size, *grid.shape), dtype=np.float32)
    shares = np.zeros(approaches.size, dtype=np.float64)
    touching = np.flatnonzero(approaches > 0)
    if touching.size:
        curve = contact_curve(sag_mm, gel, obj, grid, approaches[touching], fields=True)
        assert curve.gel_depth_mm is not None and curve.object_share is not None
        if conformity:
            _conform(curve.gel_depth_mm, curve.object_share, gel, grid)
            if spread != 1.0:
                _narrow(curve.gel_depth_mm, curve.object_share, spread)
        fields[touching] = curve.gel_depth_mm
        shares[touching] = curve.object_share
    return fields, shares


def gel_compression_fields(
    sag_mm: np.ndarray,
    gel: GelModel,
    obj: ObjectMechanics,
    grid: PadGrid,
    approaches_mm: np.ndarray,
    conformity: bool = True,
) -> np.ndarray:
    """The fields of :func:`gel_compression` alone (no ``spread``)."""
    return gel_compression(sag_mm, gel, obj, grid, approaches_mm, conformity)[0]
