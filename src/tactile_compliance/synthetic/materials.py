"""Material catalogue of the synthetic generator: labels, physics, shapes and surface cues.

The real object table (DATA_FORMATS.md section 1) is the model for every number here:

* material frequencies (Rubber .28, Metal .25, Plastic .24, Wood .08, Foam .06,
  Food .03, Glass .03, Ceramic .015);
* label distributions, in Pa. Hard labels are *handbook grades* (steel 2.0e11,
  aluminium 7.0e10, ABS 2.35e9, pine 1.0e10, ...), so many objects share a label and
  above ~1e8 Pa only weak cues (texture, shape) separate them;
* the label-vs-physics mismatch ``E_physics = E_label * 10**N(0, sigma)``: handbook
  values are not the modulus of the particular object (grade, temperature, anisotropy,
  Shore-conversion error); sigma in decades (dex);
* wood is loaded across the grain in a grasp, so its physics modulus is E/10 - E/20
  of the (along-grain) handbook label; cork is the exception;
* shapes conditional on material (crosstab of the real table, rounded), hollow /
  thin-walled probabilities and surface-texture kinds (weak, overlapping cues).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "MATERIALS",
    "SHAPES",
    "TEXTURE_KINDS",
    "MaterialModel",
    "material_model",
]

SHAPES = ("Irregular", "Cylinder", "Rectangular", "Sphere", "Hex")
"""Shape classes of the real table."""

TEXTURE_KINDS = (
    "smooth",  # polished metal, glass, glazed ceramic: a few um of roughness
    "machined",  # turned / milled metal: fine parallel lines
    "knurled",  # tool handles: crossed ridges
    "matte",  # moulded plastic: isotropic fine roughness
    "grain",  # wood: elongated anisotropic ridges
    "rubbery",  # cast rubber / silicone: soft isotropic roughness
    "cellular",  # foams and sponges: pores
    "organic",  # food: low-frequency bumps plus fine roughness
)


def _log_uniform(rng: np.random.Generator, low: float, high: float) -> float:
    return float(10.0 ** rng.uniform(np.log10(low), np.log10(high)))


@dataclass(frozen=True)
class MaterialModel:
    """How one material class is simulated.

    Attributes:
        name: material name as in the real table (``Rubber``, ``Metal``, ...).
        weight: relative frequency in the default object mix [-].
        poisson_range: uniform range of the object's Poisson ratio [-].
        mismatch_dex: sigma of the label-vs-physics mismatch [decades].
        shape_weights: relative frequency of each shape for this material [-].
        texture_weights: relative frequency of each texture kind [-].
        hollow_probability: probability that an object is hollow / thin-walled [-].
        shell_thickness_mm: uniform range of the wall thickness of hollow objects [mm].
        max_strain: saturating compressive strain of the object (densification of
            foams, bulging limit of rubbers) [-].
        across_grain: physics modulus = label / U(10, 20) (wood loaded across the grain).
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
    grades: tuple[tuple[float, float], ...] = field(default_factory=tuple)

    def sample_label_pa(self, rng: np.random.Generator) -> float:
        """Draw a ground-truth label [Pa] from this material's label distribution."""
        return float(_LABEL_SAMPLERS[self.name](rng))

    def physics_modulus_pa(self, label_pa: float, rng: np.random.Generator) -> float:
        """The modulus that drives the mechanics [Pa]: label x mismatch (x across-grain)."""
        modulus = label_pa * 10.0 ** rng.normal(0.0, self.mismatch_dex)
        # Cork (label 1e8) is isotropic enough; real wood is loaded across the grain.
        if self.across_grain and label_pa > 1e9:
            modulus /= rng.uniform(10.0, 20.0)
        return float(modulus)

    def sample_poisson(self, rng: np.random.Generator) -> float:
        """Draw the object's Poisson ratio [-]."""
        return float(rng.uniform(*self.poisson_range))


def _grade(rng: np.random.Generator, grades: list[float], weights: list[float]) -> float:
    p = np.asarray(weights, dtype=float)
    return float(grades[int(rng.choice(len(grades), p=p / p.sum()))])


def _rubber(rng: np.random.Generator) -> float:
    # 3 % hard rubbers (ebonite, hard urethane) reach into the plastics' range.
    if rng.random() < 0.03:
        return _log_uniform(rng, 1e7, 3e9)
    return _log_uniform(rng, 1.3e4, 7e6)


def _metal(rng: np.random.Generator) -> float:
    # aluminium, brass, bronze/iron, cast iron, steel, stainless/tool steel
    return _grade(rng, [7.0e10, 1.0e11, 1.5e11, 1.9e11, 2.0e11, 2.2e11], [27, 18, 3, 4, 42, 6])


def _plastic(rng: np.random.Generator) -> float:
    u = rng.random()
    if u < 0.04:
        return 2.6e8  # LDPE
    if u < 0.07:
        return _log_uniform(rng, 8.0e8, 1.5e9)
    if u < 0.10:
        return _log_uniform(rng, 3.5e9, 8.9e9)  # filled / reinforced grades
    return _grade(
        rng,
        [1.67e9, 1.8e9, 2.1e9, 2.35e9, 2.7e9, 2.9e9, 3.0e9, 3.2e9],
        [5, 10, 12, 25, 12, 15, 10, 11],
    )


def _wood(rng: np.random.Generator) -> float:
    if rng.random() < 0.05:
        return 1.0e8  # cork
    return _grade(rng, [9.6e9, 1.0e10, 1.1e10, 1.2e10, 1.25e10], [5, 70, 12, 8, 5])


def _foam(rng: np.random.Generator) -> float:
    u = rng.random()
    if u < 0.04:
        return 4.0e8  # rigid foam board
    if u < 0.12:
        return 1.65e6  # expanded polystyrene
    return _log_uniform(rng, 5e3, 4.5e5)


def _food(rng: np.random.Generator) -> float:
    if rng.random() < 0.10:
        return 1.0e9  # hard candy
    return _log_uniform(rng, 3e4, 3.3e6)


def _glass(rng: np.random.Generator) -> float:
    return _grade(rng, [6.25e10, 6.5e10, 6.7e10], [3, 2, 3])


def _ceramic(rng: np.random.Generator) -> float:
    return 5.85e10


def _generic(rng: np.random.Generator) -> float:
    return _log_uniform(rng, 1e6, 1e9)


_LABEL_SAMPLERS = {
    "Rubber": _rubber,
    "Metal": _metal,
    "Plastic": _plastic,
    "Wood": _wood,
    "Foam": _foam,
    "Food": _food,
    "Glass": _glass,
    "Ceramic": _ceramic,
    "Paper": _generic,
    "Other": _generic,
}


def _tex(**weights: float) -> dict[str, float]:
    return {k: float(v) for k, v in weights.items()}


MATERIALS: dict[str, MaterialModel] = {
    m.name: m
    for m in (
        MaterialModel(
            "Rubber",
            0.28,
            (0.47, 0.499),
            0.15,
            {"Irregular": 56, "Sphere": 20, "Cylinder": 13, "Rectangular": 11},
            _tex(rubbery=55, matte=20, smooth=10, organic=8, cellular=7),
            max_strain=0.5,
        ),
        MaterialModel(
            "Metal",
            0.25,
            (0.28, 0.34),
            0.05,
            {"Irregular": 55, "Cylinder": 25, "Rectangular": 11, "Hex": 6, "Sphere": 3},
            _tex(machined=40, smooth=30, knurled=15, matte=15),
            hollow_probability=0.15,
        ),
        MaterialModel(
            "Plastic",
            0.24,
            (0.35, 0.42),
            0.10,
            {"Irregular": 62, "Cylinder": 19, "Sphere": 10, "Rectangular": 7, "Hex": 2},
            _tex(matte=45, smooth=25, knurled=10, rubbery=10, machined=10),
            hollow_probability=0.30,
        ),
        MaterialModel(
            "Wood",
            0.08,
            (0.30, 0.40),
            0.20,
            {"Cylinder": 33, "Irregular": 29, "Rectangular": 29, "Sphere": 5, "Hex": 4},
            _tex(grain=60, matte=25, organic=15),
            across_grain=True,
        ),
        MaterialModel(
            "Foam",
            0.06,
            (0.05, 0.30),
            0.20,
            {"Rectangular": 75, "Cylinder": 10, "Irregular": 8, "Sphere": 7},
            _tex(cellular=65, rubbery=20, matte=15),
            max_strain=0.75,
        ),
        MaterialModel(
            "Food",
            0.03,
            (0.30, 0.49),
            0.20,
            {"Irregular": 65, "Sphere": 23, "Cylinder": 12},
            _tex(organic=60, rubbery=20, smooth=20),
            max_strain=0.5,
        ),
        MaterialModel(
            "Glass",
            0.03,
            (0.21, 0.24),
            0.05,
            {"Cylinder": 38, "Sphere": 37, "Irregular": 25},
            _tex(smooth=80, matte=20),
            hollow_probability=0.30,
            shell_thickness_mm=(1.5, 4.0),
        ),
        MaterialModel(
            "Ceramic",
            0.015,
            (0.20, 0.25),
            0.05,
            {"Cylinder": 50, "Irregular": 25, "Sphere": 25},
            _tex(smooth=60, matte=40),
            hollow_probability=0.50,
            shell_thickness_mm=(2.0, 5.0),
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
    _tex(matte=40, rubbery=20, grain=20, smooth=20),
    max_strain=0.5,
)


def material_model(name: str) -> MaterialModel:
    """The catalogue entry for ``name`` (case-insensitive); a generic model otherwise."""
    for key, model in MATERIALS.items():
        if key.lower() == name.strip().lower():
            return model
    if name.strip().lower() == "paper":
        return MaterialModel(
            "Paper",
            0.0,
            (0.2, 0.4),
            0.2,
            {"Rectangular": 1.0},
            _tex(matte=50, grain=50),
            max_strain=0.6,
        )
    return _FALLBACK
