"""Object geometry as sag maps on the sensor pad, and the grasp poses.

A sag map ``s(x, y) >= 0`` [mm] is the object's surface height below its apex plane;
:data:`NO_SURFACE` where it has none. See docs/synthetic.md, "Geometry".
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

__all__ = [
    "NO_SURFACE",
    "PAD_SIZE_MM",
    "PadGrid",
    "Pose",
    "ShapeSpec",
    "sag_map",
    "sample_pose",
    "sample_shape",
]

PAD_SIZE_MM = (35.0, 25.5)
"""Gel pad size (x = along the image width, y = along the image height) [mm]."""

NO_SURFACE = 60.0
"""Sag [mm] used where the object has no surface over a pad cell (never touched)."""

_CANVAS_MM = (110.0, 90.0)  # extent (x, y) of an irregular object's side surface [mm]
_CANVAS_CELL_MM = 0.25  # resolution of that surface [mm]


@dataclass(frozen=True)
class PadGrid:
    """The mechanics grid covering the whole pad.

    Attributes:
        cell_mm: grid spacing [mm].
    """

    cell_mm: float = 0.25

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, cols) of the grid."""
        return (
            round(PAD_SIZE_MM[1] / self.cell_mm),
            round(PAD_SIZE_MM[0] / self.cell_mm),
        )

    def coords(self) -> tuple[np.ndarray, np.ndarray]:
        """Cell-centre coordinates (x, y) [mm], origin at the pad centre, float32."""
        rows, cols = self.shape
        x = (np.arange(cols, dtype=np.float32) + 0.5) * self.cell_mm - PAD_SIZE_MM[0] / 2
        y = (np.arange(rows, dtype=np.float32) + 0.5) * self.cell_mm - PAD_SIZE_MM[1] / 2
        xx, yy = np.meshgrid(x, y)
        return xx, yy

    @property
    def cell_area_m2(self) -> float:
        """Area of one cell [m^2]."""
        return (self.cell_mm * 1e-3) ** 2


@dataclass(frozen=True)
class Pose:
    """Placement of the object on one finger's pad for one grasp.

    Attributes:
        offset_mm: in-plane offset (x, y) of the object's apex from the pad centre [mm].
        angle_rad: in-plane rotation of the object [rad].
        tilt: surface tilt (dz/dx, dz/dy) from gripper misalignment [-].
        canvas_offset_mm: for irregular objects, which part of the surface is grasped [mm].
    """

    offset_mm: tuple[float, float]
    angle_rad: float
    tilt: tuple[float, float]
    canvas_offset_mm: tuple[float, float] = (0.0, 0.0)


@dataclass
class ShapeSpec:
    """An object's geometry.

    Attributes:
        kind: one of ``Sphere``, ``Cylinder``, ``Rectangular``, ``Hex``, ``Irregular``.
        params: shape parameters [mm] (radius_mm, length_mm, face_mm, edge_radius_mm,
            flats_mm, hex_mode, ...).
        thickness_mm: object size along the grasp axis (gripper width at first contact) [mm].
        sides: irregular objects only: the two side surfaces (sag canvases) [mm].
    """

    kind: str
    params: dict[str, float | str]
    thickness_mm: float
    sides: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False)


def _smooth_field(
    rng: np.random.Generator, shape: tuple[int, int], corr_cells: float
) -> np.ndarray:
    """Zero-mean, unit-std Gaussian random field with correlation length ``corr_cells``."""
    white = rng.standard_normal(shape).astype(np.float32)
    smooth = cv2.GaussianBlur(white, (0, 0), corr_cells, borderType=cv2.BORDER_REFLECT)
    std = float(smooth.std())
    return smooth / (std if std > 0 else 1.0)


def _irregular_side(rng: np.random.Generator) -> np.ndarray:
    """One side of an irregular object: min over primitives on a curved base [mm]."""
    cols = round(_CANVAS_MM[0] / _CANVAS_CELL_MM)
    rows = round(_CANVAS_MM[1] / _CANVAS_CELL_MM)
    u = (np.arange(cols, dtype=np.float32) + 0.5) * _CANVAS_CELL_MM - _CANVAS_MM[0] / 2
    v = (np.arange(rows, dtype=np.float32) + 0.5) * _CANVAS_CELL_MM - _CANVAS_MM[1] / 2
    uu, vv = np.meshgrid(u, v)
    # Gently curved base (large radius) with a smooth random field: the object's bulk.
    base_radius = 10 ** rng.uniform(np.log10(15.0), np.log10(80.0))
    aspect = rng.uniform(0.4, 1.0)
    base = (uu**2 + (vv / aspect) ** 2) / (2 * base_radius)
    base += rng.uniform(0.05, 0.8) * _smooth_field(
        rng, (rows, cols), rng.uniform(3.0, 10.0) / _CANVAS_CELL_MM
    )
    surface = base + rng.uniform(0.3, 2.5)
    for _ in range(int(rng.integers(2, 7))):
        kind = rng.choice(["cap", "stud", "thread", "wedge"], p=[0.45, 0.25, 0.1, 0.2])
        cu, cv = rng.normal(0.0, 8.0, size=2)
        z0 = rng.uniform(0.0, 1.5)
        phi = rng.uniform(0.0, np.pi)
        du, dv = uu - cu, vv - cv
        along = du * np.cos(phi) + dv * np.sin(phi)
        across = -du * np.sin(phi) + dv * np.cos(phi)
        if kind == "cap":
            radius = 10 ** rng.uniform(np.log10(2.0), np.log10(25.0))
            extent = rng.uniform(2.0, 12.0)
            r2 = du**2 + dv**2
            prim = np.where(r2 < extent**2, z0 + r2 / (2 * radius), NO_SURFACE)
        elif kind == "stud":
            radius = rng.uniform(1.0, 4.0)
            edge = rng.uniform(0.2, 0.8)
            r = np.sqrt(du**2 + dv**2)
            excess = np.maximum(r - (radius - edge), 0.0)
            cap = edge - np.sqrt(np.maximum(edge**2 - excess**2, 0.0))
            prim = np.where(excess < edge, z0 + cap, NO_SURFACE)
        elif kind == "thread":
            pitch = rng.uniform(0.8, 2.5)
            amp = rng.uniform(0.2, 0.8)
            half_width = rng.uniform(3.0, 10.0)
            bend = rng.uniform(3.0, 15.0)
            prim = z0 + amp * 0.5 * (1 - np.cos(2 * np.pi * along / pitch))
            prim = prim + across**2 / (2 * bend)
            prim = np.where(np.abs(across) < half_width, prim, NO_SURFACE)
        else:  # wedge: an edge line
            slope = rng.uniform(0.2, 1.0)
            rounding = rng.uniform(0.2, 1.5)
            length = rng.uniform(5.0, 30.0)
            prim = z0 + slope * (np.sqrt(across**2 + rounding**2) - rounding)
            prim = np.where(np.abs(along) < length / 2, prim, NO_SURFACE)
        surface = np.minimum(surface, prim.astype(np.float32))
    surface -= surface.min()
    return np.minimum(surface, NO_SURFACE).astype(np.float32)


def _sized(rng: np.random.Generator, low: float, high: float, bias: float) -> float:
    """A size in [low, high]: uniform for ``bias`` 0, skewed to large sizes for bias > 0
    (the quantile u ** exp(-bias)) and to small ones for bias < 0. With bias 0 it draws
    exactly what ``rng.uniform(low, high)`` draws."""
    u = rng.random()
    if bias:
        u = u ** math.exp(-bias)
    return float(low + (high - low) * u)


def sample_shape(
    kind: str,
    rng: np.random.Generator,
    radius_mm: float | None = None,
    size_bias: float = 0.0,
) -> ShapeSpec:
    """Draw the geometry of an object of shape class ``kind``.

    Args:
        kind: shape class (``Sphere``, ``Cylinder``, ``Rectangular``, ``Hex``,
            ``Irregular``; anything else is treated as ``Irregular``).
        rng: the object's geometry stream (never sees the label).
        radius_mm: a known radius (the table's ``Radius [m]``) for spheres/cylinders [mm].
        size_bias: size tendency of the object's material grade (0: sizes uniform over
            their ranges; +0.35, one sigma of ``materials.SIZE_BIAS_SIGMA``, moves the
            median of a range from its middle to ~62 % of the way up) [-]. Radii, lengths,
            faces, flats and thicknesses follow it; edge radii and poses do not.
    """
    kind = kind if kind in {"Sphere", "Cylinder", "Rectangular", "Hex"} else "Irregular"
    b = float(size_bias)
    if kind == "Sphere":
        radius = radius_mm if radius_mm else _sized(rng, 5.0, 35.0, b)
        return ShapeSpec(kind, {"radius_mm": radius}, thickness_mm=min(2 * radius, 75.0))
    if kind == "Cylinder":
        # A log-uniform radius: every factor of R between 1.5 and 25 mm as likely.
        radius = radius_mm or float(10 ** _sized(rng, np.log10(1.5), np.log10(25.0), b))
        length = _sized(rng, 8.0, 150.0, b)
        return ShapeSpec(
            kind, {"radius_mm": radius, "length_mm": length}, thickness_mm=min(2 * radius, 75.0)
        )
    if kind == "Rectangular":
        face = (_sized(rng, 5.0, 60.0, b), _sized(rng, 5.0, 60.0, b))
        return ShapeSpec(
            kind,
            {
                "face_u_mm": face[0],
                "face_v_mm": face[1],
                "edge_radius_mm": rng.uniform(0.3, 3.0),
            },
            thickness_mm=_sized(rng, 5.0, 60.0, b),
        )
    if kind == "Hex":
        flats = _sized(rng, 5.0, 40.0, b)
        mode = "flats" if rng.random() < 0.6 else "corners"
        thickness = flats if mode == "flats" else 2 * flats / np.sqrt(3)
        return ShapeSpec(
            kind,
            {
                "flats_mm": flats,
                "length_mm": _sized(rng, 10.0, 100.0, b),
                "hex_mode": mode,
                "edge_radius_mm": rng.uniform(0.2, 1.0),
            },
            thickness_mm=min(float(thickness), 75.0),
        )
    sides = (_irregular_side(rng), _irregular_side(rng))
    return ShapeSpec(kind, {}, thickness_mm=_sized(rng, 8.0, 60.0, b), sides=sides)


def sample_pose(rng: np.random.Generator, kind: str, mirror_of: Pose | None = None) -> Pose:
    """Draw a grasp pose for one finger (offset, in-plane angle, tilt).

    With ``mirror_of`` (the other finger's pose) the in-plane angle is mirrored - the
    two sensors look at the object from opposite sides - up to a few degrees of play;
    offsets and tilts are drawn independently.
    """
    offset = (
        float(np.clip(rng.normal(0.0, 2.5), -6.0, 6.0)),
        float(np.clip(rng.normal(0.0, 2.0), -5.0, 5.0)),
    )
    angle = float(rng.uniform(0.0, np.pi))
    if mirror_of is not None:
        angle = float(np.pi - mirror_of.angle_rad + rng.normal(0.0, 0.05))
    # Misalignment of a few hundredths: enough to make flat contacts partial.
    tilt = (float(rng.normal(0.0, 0.012)), float(rng.normal(0.0, 0.012)))
    canvas = (0.0, 0.0)
    if kind == "Irregular":
        canvas = (float(rng.uniform(-18.0, 18.0)), float(rng.uniform(-14.0, 14.0)))
    return Pose(offset, angle, tilt, canvas)


def sag_map(spec: ShapeSpec, grid: PadGrid, pose: Pose, side: int = 0) -> np.ndarray:
    """The object's sag map on ``grid`` for a pose [mm], float32, minimum 0.

    Args:
        spec: the object geometry.
        grid: the pad grid.
        pose: grasp pose of this finger.
        side: 0 or 1, which side of the object this finger touches (irregular objects).
    """
    xx, yy = grid.coords()
    dx, dy = xx - pose.offset_mm[0], yy - pose.offset_mm[1]
    c, s = np.cos(pose.angle_rad), np.sin(pose.angle_rad)
    u = dx * c + dy * s
    v = -dx * s + dy * c
    p = spec.params
    if spec.kind == "Sphere":
        radius = float(p["radius_mm"])
        r2 = u**2 + v**2
        sag = np.where(r2 < radius**2, radius - np.sqrt(np.maximum(radius**2 - r2, 0)), NO_SURFACE)
    elif spec.kind == "Cylinder":
        radius, length = float(p["radius_mm"]), float(p["length_mm"])
        sag = radius - np.sqrt(np.maximum(radius**2 - v**2, 0))
        sag = np.where((np.abs(v) < radius) & (np.abs(u) < length / 2), sag, NO_SURFACE)
    elif spec.kind == "Rectangular":
        half_u, half_v = float(p["face_u_mm"]) / 2, float(p["face_v_mm"]) / 2
        edge = min(float(p["edge_radius_mm"]), 0.45 * min(half_u, half_v) * 2)
        eu = np.maximum(np.abs(u) - (half_u - edge), 0)
        ev = np.maximum(np.abs(v) - (half_v - edge), 0)
        e = np.sqrt(eu**2 + ev**2)
        sag = np.where(e < edge, edge - np.sqrt(np.maximum(edge**2 - e**2, 0)), NO_SURFACE)
    elif spec.kind == "Hex":
        flats, length = float(p["flats_mm"]), float(p["length_mm"])
        edge = float(p["edge_radius_mm"])
        side_mm = flats / np.sqrt(3)
        if p["hex_mode"] == "flats":
            # A flat face up; the neighbouring faces fall away at 60 degrees.
            beyond = np.maximum(np.abs(v) - side_mm / 2, 0)
            slope = np.float32(np.tan(np.pi / 3))
            sag = slope * (np.sqrt(beyond**2 + edge**2) - edge)
            sag = np.where(np.abs(v) < side_mm, sag, NO_SURFACE)
        else:
            # A corner up; both faces fall away at 30 degrees.
            slope = np.float32(np.tan(np.pi / 6))
            sag = slope * (np.sqrt(v**2 + edge**2) - edge)
            sag = np.where(np.abs(v) < flats / 2, sag, NO_SURFACE)
        sag = np.where(np.abs(u) < length / 2, sag, NO_SURFACE)
    else:
        assert spec.sides is not None, "irregular shapes carry their side surfaces"
        canvas = spec.sides[side]
        rows, cols = canvas.shape
        # Pad coords -> canvas pixel coords: rotate, shift by the grasped location.
        scale = grid.cell_mm / _CANVAS_CELL_MM
        cu = pose.canvas_offset_mm[0] / _CANVAS_CELL_MM + cols / 2
        cv_ = pose.canvas_offset_mm[1] / _CANVAS_CELL_MM + rows / 2
        gr, gc = grid.shape
        ox = -(gc / 2) * scale - pose.offset_mm[0] / _CANVAS_CELL_MM
        oy = -(gr / 2) * scale - pose.offset_mm[1] / _CANVAS_CELL_MM
        # Inverse map: canvas = R * (scale * grid + o) + centre
        mat = np.array(
            [
                [c * scale, s * scale, c * ox + s * oy + cu],
                [-s * scale, c * scale, -s * ox + c * oy + cv_],
            ],
            dtype=np.float64,
        )
        sag = cv2.warpAffine(
            canvas,
            mat,
            (gc, gr),
            flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=NO_SURFACE,
        )
    sag = sag.astype(np.float32) + np.float32(pose.tilt[0]) * xx + np.float32(pose.tilt[1]) * yy
    touchable = sag < NO_SURFACE * 0.5
    if not touchable.any():
        # The object misses the pad entirely (should not happen with the pose ranges):
        # centre a point contact so every grasp has a contact.
        return np.minimum((xx**2 + yy**2) / 20.0, NO_SURFACE).astype(np.float32)
    sag = sag - sag[touchable].min()
    return np.where(touchable, sag, NO_SURFACE).astype(np.float32)
