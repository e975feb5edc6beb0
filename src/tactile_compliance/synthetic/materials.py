"""Material catalogue of the synthetic generator: material grades, physics, shapes, surfaces.

The real object table is the model for every number here. See docs/synthetic.md,
"Objects and material grades".
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from functools import lru_cache

import numpy as np

from tactile_compliance.synthetic.rng import log_uniform, stream

__all__ = [
    "MATERIALS",
    "SHAPES",
    "Grade",
    "TextureSpec",
    "draw_object_grade",
    "elastic_share",
    "grade_catalogue",
    "material_model",
    "object_texture",
    "pore_imprint_gain",
    "stock_grade",
]

SHAPES = ("Irregular", "Cylinder", "Rectangular", "Sphere", "Hex")
"""Shape classes of the real table."""

TEXTURE_KINDS = (
    "smooth",  # polished metal, glass, glazed ceramic, paint: a few um of roughness
    "machined",  # turned / milled metal: fine parallel lay lines
    "knurled",  # tool handles: crossed ridges
    "matte",  # moulded or bead-blasted surfaces: isotropic fine roughness
    "grain",  # wood: elongated anisotropic ridges and growth rings
    "rubbery",  # cast rubber / silicone: soft isotropic moulding roughness
    "cellular",  # foams and sponges: open pores
    "organic",  # food skins: low-frequency bumps plus fine roughness
)

# Per texture family: ranges of the grade's surface parameters, drawn once per grade.
# amplitude [um] (std of the surface height), scale [mm] (period / correlation length).
_FAMILY_RANGES: dict[str, tuple[tuple[float, float], tuple[float, float]]] = {
    "smooth": ((1.0, 3.0), (0.05, 0.15)),
    "machined": ((2.0, 10.0), (0.08, 0.5)),
    "knurled": ((15.0, 45.0), (0.6, 1.2)),
    "matte": ((3.0, 10.0), (0.05, 0.25)),
    "grain": ((8.0, 25.0), (0.15, 0.45)),
    "rubbery": ((5.0, 18.0), (0.08, 0.4)),
    "cellular": ((40.0, 120.0), (0.2, 1.2)),
    "organic": ((15.0, 50.0), (0.3, 1.5)),
}

OBJECT_AMPLITUDE_DEX = 0.1
"""Per-object spread of a grade's texture amplitude [decades]."""

OBJECT_SCALE_DEX = 0.06
"""Per-object spread of a grade's texture scale [decades]."""


@dataclass(frozen=True)
class TextureSpec:
    """Surface texture of an object (imprinted on the gel where it touches).

    Attributes:
        kind: one of :data:`TEXTURE_KINDS`.
        amplitude_mm: standard deviation of the surface height [mm].
        scale_mm: characteristic length (correlation length or period) [mm].
        angle_rad: orientation of anisotropic textures (grain, machining) in the image
            [rad]; a pose nuisance, drawn per object.
        elongation: along/across ratio of the grain streaks (``grain``) [-].
        open_fraction: share of the surface in open pores (``cellular``) [-].
        fine_share: relative amplitude of the fine roughness on top of the bumps
            (``organic``, ``machined``) [-].
        imprint_gain: factor on the canvas that compensates the renderer's elastic
            share for surfaces that print by another mechanism (open pores: the gel
            bulges into them; see :func:`pore_imprint_gain`) [-].
    """

    kind: str
    amplitude_mm: float
    scale_mm: float
    angle_rad: float
    elongation: float = 6.0
    open_fraction: float = 0.2
    fine_share: float = 0.3
    imprint_gain: float = 1.0


PORE_PRINT_SHARE = 0.5
"""Share of an open pore's depth that the gel fills at grasp pressures [-]: the gel
bulges into a pore of width d by ~ p d / E_gel' (~70 um at 0.05 MPa over a 0.5 mm pore,
about the pores' 40-120 um depth) whatever the foam's own stiffness."""


def elastic_share(modulus_pa: float, poisson: float) -> float:
    """The gel's share of a homogeneous surface's roughness, E_o' / (E_o' + E_g') [-]
    (what the renderer scales textures by, with the default gel)."""
    from tactile_compliance.physics.contact import DEFAULT_GEL_MODULUS_PA, DEFAULT_GEL_POISSON

    e_obj = modulus_pa / (1.0 - poisson**2)
    e_gel = DEFAULT_GEL_MODULUS_PA / (1.0 - DEFAULT_GEL_POISSON**2)
    return float(e_obj / (e_obj + e_gel))


def pore_imprint_gain(modulus_pa: float, poisson: float) -> float:
    """Canvas gain that makes open pores print with at least :data:`PORE_PRINT_SHARE`:
    the renderer scales a texture by the elastic share, which would hide the pores of
    a soft foam although the gel bulges into them [-]."""
    share = elastic_share(modulus_pa, poisson)
    return float(max(share, PORE_PRINT_SHARE) / max(share, 1e-6))


def _round_label(value: float) -> float:
    """A label as a table would write it: 3 significant digits [Pa]."""
    return float(f"{value:.3g}")


@dataclass(frozen=True)
class GradeEntry:
    """One stock grade of a material's catalogue.

    Attributes:
        name: what it is (``steel``, ``ABS``, ``Shore A 30``, ...).
        label_pa: handbook label [Pa].
        weight: relative frequency among the material's stock objects [-].
    """

    name: str
    label_pa: float
    weight: float


@dataclass(frozen=True)
class MaterialModel:
    """How one material class is simulated.

    Attributes:
        name: material name as in the real table (``Rubber``, ``Metal``, ...).
        weight: relative frequency in the default object mix [-].
        poisson_range: uniform range of the Poisson ratio (one value per grade) [-].
        mismatch_dex: sigma of the grade's label-vs-physics mismatch [decades].
        object_spread_dex: sigma of the per-object modulus spread within a grade [decades].
        shape_weights: relative frequency of each shape for this material [-].
        texture_weights: relative frequency of each texture family among its grades [-].
        hollow_probability: mean probability that an object is hollow / thin-walled [-].
        shell_thickness_mm: uniform range of the wall thickness of hollow objects [mm].
        max_strain: saturating compressive strain of the object (densification of
            foams, bulging limit of rubbers) [-].
        across_grain: physics modulus = label / U(10, 20) per grade (wood loaded across
            the grain; labels above 1e9 Pa only, cork is isotropic enough).
        one_off_share: share of objects that are one-off grades of their own [-].
        one_off_range_pa: log-uniform range of one-off labels [Pa].
        coated_probability: share of objects painted or lacquered (smooth surface) [-].
    """

    name: str
    weight: float
    poisson_range: tuple[float, float]
    mismatch_dex: float
    shape_weights: dict[str, float]
    texture_weights: dict[str, float]
    hollow_probability: float = 0.0
    shell_thickness_mm: tuple[float, float] = (0.6, 2.0)
    max_strain: float = 0.3
    across_grain: bool = False
    object_spread_dex: float = 0.03
    one_off_share: float = 0.0
    one_off_range_pa: tuple[float, float] = (1e6, 1e9)
    coated_probability: float = 0.0
    grades: tuple[GradeEntry, ...] = field(default_factory=tuple)

    def sample_poisson(self, rng: np.random.Generator) -> float:
        """Draw a Poisson ratio [-]."""
        return float(rng.uniform(*self.poisson_range))

    def sample_one_off_label_pa(self, rng: np.random.Generator) -> float:
        """Label of a one-off object [Pa] (3 significant digits).

        Rubber one-offs follow what found rubber objects are: 7 % hard rubbers
        (ebonite, hard urethane; logU(1e7, 3e9)), 20 % soft gels and silicones
        (logU(1.3e4, 2e5)), and the rest everyday Shore A rubbers, log-normal around
        1e6 Pa (sigma 0.4 dex, within [1e5, 7e6]); the real table's rubber labels
        cluster the same way (half of them within 5.6e5-3.1e6). Other materials:
        log-uniform over ``one_off_range_pa``.
        """
        if self.name == "Rubber":
            u = rng.random()
            if u < 0.07:
                return _round_label(log_uniform(rng, 1e7, 3e9))
            if u < 0.27:
                return _round_label(log_uniform(rng, 1.3e4, 2e5))
            low, high = 5.0, float(np.log10(self.one_off_range_pa[1]))
            value = float(np.clip(rng.normal(6.0, 0.4), low, high))
            for _ in range(8):  # truncated normal by rejection (clip as a last resort)
                draw = rng.normal(6.0, 0.4)
                if low <= draw <= high:
                    value = float(draw)
                    break
            return _round_label(10.0**value)
        return _round_label(log_uniform(rng, *self.one_off_range_pa))


def _entries(*rows: tuple[str, float, float]) -> tuple[GradeEntry, ...]:
    return tuple(GradeEntry(name, float(label), float(weight)) for name, label, weight in rows)


def _shore_grades() -> tuple[GradeEntry, ...]:
    """Silicone and rubber stock sold by nominal hardness: Shore 00 (Larson fit) and
    Shore A (Gent fit), the package's conversions, so the labels are what a table
    would compute from the nominal hardness (weights are drawn per seed)."""
    from tactile_compliance.physics.shore import (
        shore00_to_modulus_pa,
        shore_a_to_modulus_pa_gent,
    )

    rows = [(f"Shore 00-{s}", float(shore00_to_modulus_pa(s)), 1.0) for s in (20, 30, 50)]
    rows += [(f"Shore A{s}", float(shore_a_to_modulus_pa_gent(s)), 1.0) for s in range(10, 71, 10)]
    return tuple(GradeEntry(n, _round_label(e), w) for n, e, w in rows)


SOLID_ELASTOMER_MAX_STRAIN = 0.9
"""Saturating strain [-] of solid, nearly incompressible soft objects (rubber, gels, food).

A solid elastomer does not densify like a foam: squeezed, it flows sideways and keeps
giving way roughly in proportion to the load, so a softer object closes the gripper
further (the press videos' silicone, ``shore_videos.SILICONE_MAX_STRAIN``, rests on the
same argument). The foundation's cap ``delta_o <= l_o eps_o`` is kept only so that two
fingers never meet: ``l_o < L/2``, so 0.9 leaves at least a tenth of the object between
them. The earlier 0.5 made every object below ~1e5 Pa bottom out before the first stored
frame, so its force, width, estimates and images all looked like a 1e5-1e6 Pa rubber's
(docs/synthetic.md, "Soft against hard objects")."""

MATERIALS: dict[str, MaterialModel] = {
    m.name: m
    for m in (
        MaterialModel(
            "Rubber",
            0.28,
            (0.47, 0.499),
            0.15,
            {"Irregular": 56, "Sphere": 20, "Cylinder": 13, "Rectangular": 11},
            dict(rubbery=60, matte=20, smooth=12, organic=8),
            max_strain=SOLID_ELASTOMER_MAX_STRAIN,
            object_spread_dex=0.03,
            one_off_share=0.46,
            one_off_range_pa=(1.3e4, 7e6),
            grades=_shore_grades(),
        ),
        MaterialModel(
            "Metal",
            0.25,
            (0.28, 0.34),
            0.05,
            {"Irregular": 55, "Cylinder": 25, "Rectangular": 11, "Hex": 6, "Sphere": 3},
            dict(machined=45, smooth=25, knurled=12, matte=18),
            hollow_probability=0.15,
            object_spread_dex=0.01,
            one_off_share=0.015,
            one_off_range_pa=(4.5e10, 2.1e11),
            coated_probability=0.10,
            grades=_entries(
                ("aluminium", 7.0e10, 24),
                ("brass", 1.0e11, 18),
                ("titanium", 1.1e11, 1.5),
                ("copper", 1.2e11, 2),
                ("bronze / iron", 1.5e11, 3),
                ("cast iron", 1.9e11, 4),
                ("steel", 2.0e11, 44),
                ("tool steel", 2.2e11, 6),
            ),
        ),
        MaterialModel(
            "Plastic",
            0.24,
            (0.35, 0.42),
            0.10,
            {"Irregular": 62, "Cylinder": 19, "Sphere": 10, "Rectangular": 7, "Hex": 2},
            dict(matte=45, smooth=25, knurled=8, rubbery=10, machined=12),
            hollow_probability=0.30,
            object_spread_dex=0.03,
            one_off_share=0.10,
            one_off_range_pa=(8.0e8, 8.9e9),
            coated_probability=0.05,
            grades=_entries(
                ("LDPE", 2.6e8, 4),
                ("HDPE", 1.1e9, 3),
                ("PP", 1.5e9, 5),
                ("PETG", 2.1e9, 7),
                ("ABS", 2.35e9, 22),
                ("PC", 2.4e9, 6),
                ("nylon", 2.7e9, 8),
                ("PET", 2.8e9, 6),
                ("POM", 2.9e9, 8),
                ("PS", 3.0e9, 6),
                ("acrylic", 3.2e9, 8),
                ("PLA", 3.5e9, 6),
            ),
        ),
        MaterialModel(
            "Wood",
            0.08,
            (0.30, 0.40),
            0.20,
            {"Cylinder": 33, "Irregular": 29, "Rectangular": 29, "Sphere": 5, "Hex": 4},
            dict(grain=75, matte=15, organic=10),
            across_grain=True,
            object_spread_dex=0.05,
            one_off_share=0.08,
            one_off_range_pa=(8e9, 1.4e10),
            coated_probability=0.15,
            grades=_entries(
                ("cork", 1.0e8, 5),
                ("spruce", 9.6e9, 5),
                ("pine", 1.0e10, 70),
                ("oak", 1.1e10, 12),
                ("maple", 1.2e10, 8),
                ("birch", 1.25e10, 5),
            ),
        ),
        MaterialModel(
            "Foam",
            0.06,
            (0.05, 0.30),
            0.20,
            {"Rectangular": 75, "Cylinder": 10, "Irregular": 8, "Sphere": 7},
            dict(cellular=80, rubbery=12, matte=8),
            max_strain=0.75,
            object_spread_dex=0.05,
            one_off_share=0.55,
            one_off_range_pa=(5e3, 4.5e5),
            # Three polyurethane stock foams are drawn per seed (see grade_catalogue).
            grades=_entries(("EPS", 1.65e6, 8), ("rigid foam board", 4.0e8, 4)),
        ),
        MaterialModel(
            "Food",
            0.03,
            (0.30, 0.49),
            0.20,
            {"Irregular": 65, "Sphere": 23, "Cylinder": 12},
            dict(organic=70, rubbery=15, smooth=15),
            max_strain=SOLID_ELASTOMER_MAX_STRAIN,
            object_spread_dex=0.05,
            one_off_share=0.80,
            one_off_range_pa=(3e4, 3.3e6),
            # One soft stock food (gummies, tofu, ...) is drawn per seed.
            grades=_entries(("hard candy", 1.0e9, 1)),
        ),
        MaterialModel(
            "Glass",
            0.03,
            (0.21, 0.24),
            0.05,
            {"Cylinder": 38, "Sphere": 37, "Irregular": 25},
            dict(smooth=80, matte=20),
            hollow_probability=0.30,
            shell_thickness_mm=(1.5, 4.0),
            object_spread_dex=0.01,
            one_off_share=0.10,
            one_off_range_pa=(5e10, 9e10),
            grades=_entries(
                ("soda-lime", 6.7e10, 3), ("borosilicate", 6.25e10, 3), ("lead", 6.5e10, 2)
            ),
        ),
        MaterialModel(
            "Ceramic",
            0.015,
            (0.20, 0.25),
            0.05,
            {"Cylinder": 50, "Irregular": 25, "Sphere": 25},
            dict(smooth=60, matte=40),
            hollow_probability=0.50,
            shell_thickness_mm=(2.0, 5.0),
            object_spread_dex=0.01,
            grades=_entries(("stoneware", 5.85e10, 3), ("porcelain", 7.0e10, 1)),
        ),
    )
}

# Materials that appear in user tables but not in the default mix (e.g. Paper).
_FALLBACK = MaterialModel(
    "Other",
    0.0,
    (0.25, 0.45),
    0.15,
    {"Irregular": 50, "Cylinder": 20, "Rectangular": 15, "Sphere": 12, "Hex": 3},
    dict(matte=40, rubbery=20, grain=20, smooth=20),
    max_strain=0.5,
    object_spread_dex=0.05,
    one_off_share=1.0,
)

_PAPER = MaterialModel(
    "Paper",
    0.0,
    (0.2, 0.4),
    0.2,
    {"Rectangular": 1.0},
    dict(matte=50, grain=50),
    max_strain=0.6,
    object_spread_dex=0.05,
    one_off_share=1.0,
)


def material_model(name: str) -> MaterialModel:
    """The catalogue entry for ``name`` (case-insensitive); a generic model otherwise."""
    for key, model in MATERIALS.items():
        if key.lower() == name.strip().lower():
            return model
    if name.strip().lower() == "paper":
        return _PAPER
    return _FALLBACK


@dataclass(frozen=True)
class Grade:
    """A material grade: what all its objects share.

    Attributes:
        key: identity of the grade (``"Metal/2e+11"``, ``"Rubber/own/obj_0012"``).
        material: material class (real table names).
        name: what it is (``steel``, ``Shore A 30``, ``one-off``, ...).
        label_pa: handbook label [Pa] (the ground truth of its objects).
        physics_modulus_pa: the grade's physical modulus, label x mismatch [Pa].
        poisson: Poisson ratio [-].
        object_spread_dex: sigma of the per-object modulus spread [decades].
        texture: the grade's surface (objects vary it slightly, see :func:`object_texture`).
        coated_probability: share of its objects that are painted / lacquered [-].
        shape_weights: relative frequency of each shape among its objects [-].
        size_bias: size tendency of its objects (0 = the material's, > 0 larger) [-].
        hollow_probability: probability that one of its objects is hollow [-].
    """

    key: str
    material: str
    name: str
    label_pa: float
    physics_modulus_pa: float
    poisson: float
    object_spread_dex: float
    texture: TextureSpec
    coated_probability: float
    shape_weights: dict[str, float]
    size_bias: float
    hollow_probability: float

    def object_physics_modulus_pa(self, rng: np.random.Generator) -> float:
        """One object's physical modulus [Pa]: the grade's x 10^N(0, object_spread_dex)."""
        return float(self.physics_modulus_pa * 10.0 ** rng.normal(0.0, self.object_spread_dex))

    def sample_shape(self, rng: np.random.Generator) -> str:
        """Draw a shape class from the grade's shape weights."""
        shapes = list(self.shape_weights)
        p = np.array([self.shape_weights[s] for s in shapes], dtype=float)
        return shapes[int(rng.choice(len(shapes), p=p / p.sum()))]


def grade_key(material: str, label_pa: float) -> str:
    """The key of the stock grade of ``(material, label)`` (also used for table rows)."""
    return f"{material}/{float(label_pa):.4g}"


SIZE_BIAS_SIGMA = 0.35
"""Sigma of a grade's size tendency (see ``geometry.sample_shape``) [-]."""

SHAPE_CONCENTRATION = 30.0
"""Dirichlet concentration of a grade's shape weights around its material's [-]."""


def _grade_texture(rng: np.random.Generator, weights: dict[str, float]) -> TextureSpec:
    kinds = [k for k in TEXTURE_KINDS if weights.get(k, 0.0) > 0]
    p = np.array([weights[k] for k in kinds], dtype=float)
    kind = str(kinds[int(rng.choice(len(kinds), p=p / p.sum()))])
    (a_lo, a_hi), (s_lo, s_hi) = _FAMILY_RANGES[kind]
    return TextureSpec(
        kind,
        amplitude_mm=log_uniform(rng, a_lo, a_hi) * 1e-3,
        scale_mm=log_uniform(rng, s_lo, s_hi),
        angle_rad=0.0,  # orientation is per object (a pose nuisance)
        elongation=float(rng.uniform(4.0, 12.0)),
        open_fraction=float(rng.uniform(0.1, 0.45)),
        fine_share=float(rng.uniform(0.1, 0.6)),
    )


def make_grade(seed: int, material: str, label_pa: float, key: str, name: str = "one-off") -> Grade:
    """Draw a grade's physics, surface and shape tendencies from ``stream(seed, "grade",
    key)`` (independent of the order in which grades or objects are built)."""
    model = material_model(material)
    rng = stream(seed, "grade", key)
    modulus = label_pa * 10.0 ** rng.normal(0.0, model.mismatch_dex)
    ratio = rng.uniform(10.0, 20.0)  # drawn for every grade: the stream stays aligned
    if model.across_grain and label_pa > 1e9:
        modulus /= ratio
    poisson = model.sample_poisson(rng)
    texture = _grade_texture(rng, model.texture_weights)
    shapes = list(model.shape_weights)
    base = np.array([model.shape_weights[s] for s in shapes], dtype=float)
    base /= base.sum()
    tilt = rng.dirichlet(SHAPE_CONCENTRATION * base + 1e-3)
    size_bias = float(rng.normal(0.0, SIZE_BIAS_SIGMA))
    hollow = float(min(model.hollow_probability * rng.uniform(0.3, 1.7), 0.95))
    return Grade(
        key=key,
        material=_material_name(material),
        name=name,
        label_pa=float(label_pa),
        physics_modulus_pa=float(modulus),
        poisson=poisson,
        object_spread_dex=model.object_spread_dex,
        texture=texture,
        coated_probability=model.coated_probability,
        shape_weights={s: float(w) for s, w in zip(shapes, tilt, strict=True)},
        size_bias=size_bias,
        hollow_probability=hollow,
    )


def _material_name(material: str) -> str:
    """The catalogue's spelling of a material (a table's own name if it has none)."""
    model = material_model(material)
    return model.name if model is not _FALLBACK else material.strip()


def stock_grade(seed: int, material: str, label_pa: float, name: str = "") -> Grade:
    """The stock grade of ``(material, label)`` for a dataset seed (a table row's grade)."""
    material = _material_name(material)
    return make_grade(seed, material, label_pa, grade_key(material, label_pa), name or "stock")


def one_off_grade(seed: int, material: str, object_name: str) -> Grade:
    """A one-off grade of its own for an object: a continuous label (measured on it)."""
    model = material_model(material)
    material = _material_name(material)
    key = f"{material}/own/{object_name}"
    label = model.sample_one_off_label_pa(stream(seed, "grade", key, "label"))
    return make_grade(seed, material, label, key)


@lru_cache(maxsize=64)
def grade_catalogue(seed: int, material: str) -> tuple[GradeEntry, ...]:
    """The stock grades of a material for a dataset seed, with their weights.

    Handbook grades (metals, plastics, woods, glasses, ceramics) keep their fixed
    frequencies (steel the most common metal, ABS the most common plastic, pine the most
    common wood). Rubber stock (nominal Shore hardnesses) gets per-seed popularity
    weights (a Dirichlet draw, concentration 1 for the Shore 00 silicones and 2.5 for
    the Shore A rubbers: some hardnesses are more common, as on a lab's shelf);
    foam gets three polyurethane stock grades and food one soft stock food, with
    labels drawn per seed.
    """
    model = material_model(material)
    rng = stream(seed, "catalogue", model.name)
    entries = list(model.grades)
    if model.name == "Rubber":
        # Soft silicone stock (Shore 00) is rarer than Shore A rubber stock.
        alpha = np.array([1.0 if e.name.startswith("Shore 00") else 2.5 for e in entries])
        weights = rng.dirichlet(alpha)
        entries = [replace(e, weight=float(w)) for e, w in zip(entries, weights, strict=True)]
    elif model.name == "Foam":
        weights = rng.dirichlet(np.ones(3)) * 30.0
        entries += [
            GradeEntry(f"PU foam {i + 1}", _round_label(log_uniform(rng, 8e3, 4.5e5)), float(w))
            for i, w in enumerate(weights)
        ]
    elif model.name == "Food":
        entries.append(
            GradeEntry("soft stock food", _round_label(log_uniform(rng, 3e4, 3.3e6)), 1.0)
        )
    return tuple(entries)


def draw_object_grade(seed: int, material: str, object_name: str) -> Grade:
    """The grade of a default-mix object: a one-off with the material's one-off share,
    else a stock grade by catalogue weight (stream ``(seed, object, "label")``)."""
    model = material_model(material)
    rng = stream(seed, object_name, "label")
    entries = grade_catalogue(seed, model.name)
    if not entries or rng.random() < model.one_off_share:
        return one_off_grade(seed, model.name, object_name)
    p = np.array([e.weight for e in entries], dtype=float)
    entry = entries[int(rng.choice(len(entries), p=p / p.sum()))]
    return stock_grade(seed, model.name, entry.label_pa, entry.name)


def object_texture(grade: Grade, rng: np.random.Generator) -> TextureSpec:
    """One object's surface: its grade's, varied slightly (or painted)."""
    base = grade.texture
    if rng.random() < grade.coated_probability:
        # Paint or lacquer fills the surface: a smooth, low-amplitude finish.
        (a_lo, a_hi), (s_lo, s_hi) = _FAMILY_RANGES["smooth"]
        base = replace(
            base,
            kind="smooth",
            amplitude_mm=log_uniform(rng, a_lo, a_hi) * 1e-3,
            scale_mm=log_uniform(rng, s_lo, s_hi),
        )
    return replace(
        base,
        amplitude_mm=float(base.amplitude_mm * 10.0 ** rng.normal(0.0, OBJECT_AMPLITUDE_DEX)),
        scale_mm=float(base.scale_mm * 10.0 ** rng.normal(0.0, OBJECT_SCALE_DEX)),
        angle_rad=float(rng.uniform(0.0, math.pi)),
    )
