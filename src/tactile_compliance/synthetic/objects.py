"""Synthetic objects: the default mix that follows the real object table, or a user table.

An :class:`ObjectSpec` holds everything fixed for an object across its grasps. See
docs/synthetic.md, "Objects and material grades".
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from tactile_compliance.data.preprocess import UNKNOWN_GROUND_TRUTH_OBJECTS
from tactile_compliance.synthetic.geometry import ShapeSpec, sample_shape
from tactile_compliance.synthetic.materials import (
    MATERIALS,
    Grade,
    TextureSpec,
    draw_object_grade,
    material_model,
    object_texture,
    pore_imprint_gain,
    stock_grade,
)
from tactile_compliance.synthetic.mechanics import shell_stiffness_n_per_m
from tactile_compliance.synthetic.rng import stream

__all__ = [
    "ObjectSpec",
    "TextureSpec",
    "default_identities",
    "default_objects",
    "objects_from_table",
]

_HOLLOW_NAME_HINTS = (
    "bottle",
    "cup",
    "mug",
    "can",
    "tube",
    "pipe",
    "jar",
    "bowl",
    "vial",
    "bushing",
    "fitting",
    "junction",
    "extrusion",
    "channel",
    "case",
)


@dataclass
class ObjectSpec:
    """One synthetic object (fixed across its grasps).

    Attributes:
        name: directory name (neutral ``obj_NNNN`` in the default mix).
        index: position in the generated list.
        material: material class (real table names).
        shape: shape class (real table names).
        modulus_pa: ground-truth label [Pa] (what ``metadata.json`` stores).
        physics_modulus_pa: the modulus that drives the mechanics [Pa]: the grade's
            physical modulus x 10^N(0, grade.object_spread_dex).
        poisson: the object's Poisson ratio [-].
        max_strain: saturating compressive strain of the object [-].
        hollow: thin-walled object.
        shell_thickness_mm: wall thickness of a hollow object [mm].
        shell_stiffness_n_per_m: series stiffness of the shell per contact [N/m] (inf if solid).
        geometry: sag-map geometry.
        texture: surface texture.
        n_grasps: number of grasps to simulate.
        shore_00, shore_a, shore_d: hardness values for ``metadata.json`` (None if n/a).
        used_in_training: ``metadata.json`` flag (False for unknown ground truth).
        grade: the object's material grade (shared with the other objects of the grade).
    """

    name: str
    index: int
    material: str
    shape: str
    modulus_pa: float
    physics_modulus_pa: float
    poisson: float
    max_strain: float
    hollow: bool
    shell_thickness_mm: float
    shell_stiffness_n_per_m: float
    geometry: ShapeSpec = field(repr=False)
    texture: TextureSpec
    n_grasps: int
    shore_00: float | None = None
    shore_a: float | None = None
    shore_d: float | None = None
    used_in_training: bool = True
    grade: Grade | None = field(default=None, repr=False)


def _shore_values(material: str, modulus_pa: float) -> tuple[float | None, ...]:
    """Hardness values a durometer would give, where its scale applies (metadata only)."""
    from tactile_compliance.physics.shore import modulus_pa_to_shore00

    if material not in {"Rubber", "Foam", "Food"}:
        return (None, None, None)
    try:
        shore_00 = round(float(modulus_pa_to_shore00(modulus_pa)) * 2) / 2
    except ValueError:
        shore_00 = None
    # Inverse of the exponential Shore A fit E[MPa] = exp(0.0235 S - 0.6403).
    shore_a_value = (math.log(modulus_pa / 1e6) + 0.6403) / 0.0235
    shore_a = round(shore_a_value * 2) / 2 if 10.0 <= shore_a_value <= 95.0 else None
    return (shore_00, shore_a, None)


def _build(
    name: str,
    index: int,
    seed: int,
    material: str,
    shape: str,
    grade: Grade,
    n_grasps: int,
    radius_mm: float | None = None,
    shore: tuple[float | None, float | None, float | None] | None = None,
    used_in_training: bool = True,
) -> ObjectSpec:
    model = material_model(material)
    physics_modulus = grade.object_physics_modulus_pa(stream(seed, name, "physics"))
    poisson = grade.poisson
    geometry = sample_shape(
        shape, stream(seed, name, "geometry"), radius_mm, size_bias=grade.size_bias
    )
    hollow_rng = stream(seed, name, "hollow")
    hollow_p = grade.hollow_probability
    if any(h in name.lower() for h in _HOLLOW_NAME_HINTS):
        hollow_p = max(hollow_p, 0.8)
    hollow = bool(hollow_rng.random() < hollow_p) and geometry.kind != "Hex"
    shell_t = float(hollow_rng.uniform(*model.shell_thickness_mm)) if hollow else 0.0
    radius_for_shell = 0.5 * geometry.thickness_mm
    shell_k = (
        shell_stiffness_n_per_m(physics_modulus, poisson, shell_t, radius_for_shell)
        if hollow
        else math.inf
    )
    texture = object_texture(grade, stream(seed, name, "texture"))
    if texture.kind == "cellular":
        texture = replace(texture, imprint_gain=pore_imprint_gain(physics_modulus, poisson))
    if shore is None:
        shore = _shore_values(model.name, grade.label_pa)
    return ObjectSpec(
        name=name,
        index=index,
        material=material,
        shape=shape,
        modulus_pa=float(grade.label_pa),
        physics_modulus_pa=physics_modulus,
        poisson=poisson,
        max_strain=model.max_strain,
        hollow=hollow,
        shell_thickness_mm=shell_t,
        shell_stiffness_n_per_m=shell_k,
        geometry=geometry,
        texture=texture,
        n_grasps=n_grasps,
        shore_00=shore[0],
        shore_a=shore[1],
        shore_d=shore[2],
        used_in_training=used_in_training,
        grade=grade,
    )


@dataclass(frozen=True)
class ObjectIdentity:
    """What the default mix decides about an object before its geometry is drawn (the
    fields as in :class:`ObjectSpec`)."""

    name: str
    index: int
    material: str
    grade: Grade
    shape: str
    n_grasps: int


def default_identities(
    n_objects: int, seed: int = 0, grasps_per_object: int | None = None
) -> list[ObjectIdentity]:
    """Material, grade, shape and grasp count of each default object (cheap: no geometry).

    Each object draws its material (real frequencies) from ``stream(seed, name,
    "identity")``, then its grade (``materials.draw_object_grade``: a stock grade of
    the material's catalogue or a one-off of its own), then its shape from the grade's
    shape tendencies and its number of grasps.
    """
    names = list(MATERIALS)
    weights = np.array([MATERIALS[m].weight for m in names])
    weights /= weights.sum()
    identities = []
    for i in range(n_objects):
        name = f"obj_{i:04d}"
        rng = stream(seed, name, "identity")
        material = names[int(rng.choice(len(names), p=weights))]
        grade = draw_object_grade(seed, material, name)
        shape = grade.sample_shape(rng)
        if grasps_per_object is None:
            n_grasps = int(rng.choice([5, 6, 7, 8], p=[0.62, 0.05, 0.04, 0.29]))
        else:
            n_grasps = int(grasps_per_object)
        identities.append(ObjectIdentity(name, i, material, grade, shape, n_grasps))
    return identities


def default_objects(
    n_objects: int, seed: int = 0, grasps_per_object: int | None = None
) -> list[ObjectSpec]:
    """The default object mix (materials, grades and shapes as in the real table).

    See :func:`default_identities` for the draws; then every object gets its geometry,
    its modulus (the grade's x a small per-object spread), hollowness and surface.

    Args:
        n_objects: number of objects.
        seed: base seed; object i depends only on (seed, i) (grades only on the seed and
            the grade).
        grasps_per_object: fixed number of grasps; default 5-8 per object like the
            real data (mostly 5, ~30 % with 8).
    """
    return [
        _build(o.name, o.index, seed, o.material, o.shape, o.grade, o.n_grasps)
        for o in default_identities(n_objects, seed, grasps_per_object)
    ]


def objects_from_table(
    path: str | Path, seed: int = 0, grasps_per_object: int | None = None
) -> tuple[list[ObjectSpec], list[str]]:
    """One object per row of a table in the real CSV format.

    Uses ``Label`` (directory name), ``Material``, ``Shape``, ``Modulus [Pa]`` (label),
    ``Radius [m]`` (sphere/cylinder radius when given), ``Trials Recorded?`` (number of
    grasps unless ``grasps_per_object`` is given) and the Shore columns (metadata).
    Rows of one ``(Material, Modulus [Pa])`` share one grade
    (``materials.stock_grade``: the same physics draw, surface family and shape
    tendencies; the same grade as a default-mix stock grade of that label and seed).

    Returns:
        ``(objects, skipped)`` with a reason string per skipped row.
    """
    from tactile_compliance.data.object_table import read_object_table, valid_modulus

    table = read_object_table(path)
    objects: list[ObjectSpec] = []
    skipped: list[str] = []

    def number(row: object, key: str) -> float | None:
        value = getattr(row, key, None)
        try:
            value = float(value)  # type: ignore[arg-type]
        except (TypeError, ValueError):
            return None
        return value if math.isfinite(value) else None

    for index, (name, row) in enumerate(table.iterrows()):
        if not valid_modulus(row["modulus_pa"]):
            skipped.append(f"{name}: no valid 'Modulus [Pa]'")
            continue
        if grasps_per_object is not None:
            n_grasps = int(grasps_per_object)
        else:
            trials = number(row, "trials_recorded")
            n_grasps = int(trials) if trials and trials > 0 else 5
        radius_m = number(row, "radius_m")
        shore = (number(row, "shore_00"), number(row, "shore_a"), number(row, "shore_d"))
        material = str(row["material"]) or "Other"
        objects.append(
            _build(
                str(name),
                index,
                seed,
                material,
                str(row["shape"]) or "Irregular",
                stock_grade(seed, material, float(row["modulus_pa"])),
                n_grasps,
                radius_mm=radius_m * 1e3 if radius_m else None,
                shore=shore,
                used_in_training=str(name) not in UNKNOWN_GROUND_TRUTH_OBJECTS,
            )
        )
    return objects, skipped


RIGID_MODULUS_PA = 1e9
"""The label of :func:`rigid_sphere` [Pa]: stiff enough that the gel takes all the
indentation (a golf ball is 8.5e8 Pa)."""


def rigid_sphere(
    name: str, radius_mm: float, seed: int, n_grasps: int, index: int = 0
) -> ObjectSpec:
    """A rigid plastic sphere of ``radius_mm`` [mm] (``calibrate-rig``'s stand-in for a
    user's rigid calibration object), drawn as the table objects are (``_build``)."""
    return reference_sphere(name, radius_mm, RIGID_MODULUS_PA, "Plastic", seed, n_grasps, index)


def reference_sphere(
    name: str,
    radius_mm: float,
    modulus_pa: float,
    material: str,
    seed: int,
    n_grasps: int,
    index: int = 0,
) -> ObjectSpec:
    """A sphere of ``radius_mm`` [mm] and ``modulus_pa`` [Pa] of ``material``, drawn as a
    table row of that label is (``objects_from_table``): ``calibrate-rig``'s stand-in for
    a user's reference object."""
    if not (math.isfinite(radius_mm) and radius_mm > 0):
        raise ValueError(f"radius must be a positive length in mm, got {radius_mm!r}")
    grade = stock_grade(seed, material, modulus_pa)
    return _build(name, index, seed, material, "Sphere", grade, n_grasps, radius_mm=radius_mm)
