"""``calibrate-rig``: fit a gripper rig (``synthetic.rig.GripperRig``) from recordings of
rigid spheres, with no modulus label.

The recordings are what ``record`` writes (the raw layout: every sample's three frames,
forces and widths). The same statistics are read from them and from the generator's
simulation of the same spheres with a candidate rig, and the rig's fields are fitted one
after the other, each on the statistic it drives (staged, as TacAlign aligns a simulator):

1. the press force (``peak_force_n``): the mean and sd of the grasps' peak forces;
2. the lights (``light_balance``, only with ``fit_lights``): each light's factor by the
   ratio of the real to the simulated 99th percentile of its channel's |difference|;
3. the gel (``gel_modulus_pa``): the contact share of the three selected frames (a rigid
   ball's contact area at a known force), by a bounded 1-D search in log10 E;
4. the finger and mount (``finger_stiffness_n_per_m``): the closure, the slope of force
   against width over the selected frames, by root finding in log10 K_f;
5. the edge glow (``edge_glow_grey_per_mm``): its G - R at the left edge, by root finding.

Deterministic: the simulation uses fixed seeds (common random numbers, so every candidate
is simulated with the same poses, sessions and noise). See docs/synthetic.md, "The rig:
calibrate-rig".
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from tactile_compliance.data.object_table import read_object_table
from tactile_compliance.data.raw_layout import (
    FINGER_FILES,
    FORCES_FILE,
    WIDTHS_FILE,
    SampleError,
    load_frames,
    load_vector,
    sample_dirs,
)
from tactile_compliance.synthetic.rig import DATASET_RIG, GripperRig

__all__ = [
    "CONTACT_GREY",
    "GLOW_STRIP",
    "GraspObservation",
    "RigFit",
    "RigFitError",
    "fit_rig",
    "grasp_statistics",
    "read_rigid_grasps",
    "simulate_rigid_grasps",
]

CONTACT_GREY = 15
"""A pixel is in contact where some channel differs from the reference by more than this
many grey levels (the rule of ``benchmarks/real_vs_synthetic.py``)."""

GLOW_STRIP = 0.15
"""Left share of the frame left out of the contact share: the Wedge's green edge glow,
fitted on its own (step 5), would otherwise count as contact."""

STIFFNESS_SPREAD = 1.3
"""The fitted ``K_f`` becomes the session range ``(K / sqrt(1.3), K * sqrt(1.3))``: the
spread between recording sessions that the hand-fitted wedge-2023 rig had (3.5e3-4.6e3
N/m); the generator's +-25 % per grasp (where the object sits on the finger) is on top."""

GLOW_SPREAD = 2.0
"""The fitted glow gain ``g`` becomes the session range ``(g / 2, 2 g)`` (as wedge-2023)."""

MIN_GLOW_GREY = 3.0
"""A real edge glow below this many grey levels of G - R is no glow: the rig gets (0, 0)."""

GEL_BOUNDS_PA = (1e4, 1e6)
"""The gel moduli the search covers [Pa] (Wedge and Mini gels are 5e4-3e5)."""

STIFFNESS_BOUNDS_N_PER_M = (3e2, 3e7)
"""The finger/mount stiffness the root search covers [N/m]."""

GLOW_BOUNDS = (10.0, 3e4)
"""The glow gains the root search covers [grey levels per mm]."""

PEAK_SD_FLOOR_N = 0.5
"""The smallest peak-force sd a rig gets [N]: the unzeroed force baseline of a real rig
scatters by +-0.5 N (real/README.md), so fewer grasps than that cannot measure less."""


class RigFitError(ValueError):
    """The recordings cannot calibrate a rig (no spheres, no radius, too few frames)."""


@dataclass
class GraspObservation:
    """What the fit reads of one grasp of a rigid sphere.

    Attributes:
        object_name: the object (its directory).
        grasp: the grasp number.
        radius_mm: the sphere's radius [mm].
        forces_n, widths_m: the distinct (force [N], width [m]) points of every sample's
            three frames, shape (n,).
        diff: augmentation 0's difference images, RGB in [0, 1] (0.5: no change),
            shape (3, H, W, 3).
        frame_forces_n: augmentation 0's three forces [N].
    """

    object_name: str
    grasp: int
    radius_mm: float
    forces_n: np.ndarray
    widths_m: np.ndarray
    diff: np.ndarray = field(repr=False)
    frame_forces_n: np.ndarray


def _observation(
    name: str, grasp: int, radius_mm: float, samples: Sequence[tuple[Any, Any, Any]]
) -> GraspObservation:
    """``samples``: (forces (3,), widths (3,), RGB diff (3, H, W, 3)) per augmentation."""
    points = {
        (float(f), float(w))
        for forces, widths, _ in samples
        for f, w in zip(forces, widths, strict=True)
    }
    ordered = np.array(sorted(points))
    return GraspObservation(
        object_name=name,
        grasp=grasp,
        radius_mm=radius_mm,
        forces_n=ordered[:, 0],
        widths_m=ordered[:, 1],
        diff=np.asarray(samples[0][2], dtype=np.float32),
        frame_forces_n=np.asarray(samples[0][0], dtype=np.float64),
    )


def _radii(datasets: Sequence[Path], given: dict[str, float]) -> dict[str, float]:
    """``object -> radius [mm]``: ``given`` first, then the ``Radius [m]`` of each dataset's
    object table (spheres only)."""
    radii: dict[str, float] = {}
    for dataset in datasets:
        table_path = dataset / "dataset_objects_and_compliance.csv"
        if not table_path.is_file():
            continue
        table = read_object_table(table_path)
        for name, row in table.iterrows():
            shape = str(row.get("shape", "")).strip().lower()
            radius_m = row.get("radius_m")
            if shape == "sphere" and radius_m is not None and np.isfinite(float(radius_m)):
                radii.setdefault(str(name), float(radius_m) * 1e3)
    return radii | dict(given)


def object_grasps(object_dir: Path, radius_mm: float) -> list[GraspObservation]:
    """Every grasp of one object directory (markerless finger), as a sphere of
    ``radius_mm`` [mm]; RigFitError naming a sample that cannot be read."""
    by_grasp: dict[int, list[tuple[Any, Any, Any]]] = {}
    for grasp, _, directory in sample_dirs(object_dir):
        try:
            sample = (
                load_vector(directory, FORCES_FILE),
                load_vector(directory, WIDTHS_FILE),
                load_frames(directory, FINGER_FILES["markerless"][0], None),
            )
        except SampleError as err:
            raise RigFitError(f"{directory}: {err}") from err
        by_grasp.setdefault(grasp, []).append(sample)
    return [_observation(object_dir.name, g, radius_mm, samples) for g, samples in by_grasp.items()]


def read_rigid_grasps(
    datasets: Sequence[str | Path], radii_mm: dict[str, float] | None = None
) -> list[GraspObservation]:
    """Every grasp of the datasets (what ``record`` or ``simulate`` wrote), markerless finger.

    Args:
        datasets: raw-layout directories (one object per sub-directory).
        radii_mm: ``object -> sphere radius [mm]`` for objects whose table has none.

    Raises:
        RigFitError: a dataset without objects, an object without a radius, or a sample
            that cannot be read (naming it).
    """
    paths = [Path(d) for d in datasets]
    for path in paths:
        if not path.is_dir():
            raise RigFitError(f"{path}: no such dataset directory")
    radii = _radii(paths, radii_mm or {})
    observations: list[GraspObservation] = []
    for dataset in paths:
        objects = sorted(d for d in dataset.iterdir() if d.is_dir() and not d.name.startswith("."))
        for object_dir in objects:
            found = sample_dirs(object_dir)
            if not found:
                continue
            name = object_dir.name
            if name not in radii:
                raise RigFitError(
                    f"{object_dir}: no sphere radius for {name!r}; give --radius {name}=MM "
                    "(calibrate-rig needs rigid spheres of known radius)"
                )
            observations += object_grasps(object_dir, radii[name])
    if not observations:
        raise RigFitError(f"no grasps under {', '.join(map(str, paths))}")
    return observations


# ---------------------------------------------------------------------- statistics
STATISTICS = (
    "peak_force_n",
    "stiffness_n_per_mm",
    "contact_share_1",
    "contact_share_2",
    "contact_share_3",
    "p99_r",
    "p99_g",
    "p99_b",
    "edge_glow_grey",
)
"""What :func:`grasp_statistics` returns, in the order the fit prints them."""


def _edge_glow_grey(diff: np.ndarray) -> float:
    """G - R over the left 6 % of the columns less its mean beyond 11 % [grey levels]
    (the measure of docs/synthetic.md, "The green edge's glow"); RGB (..., H, W, 3)."""
    width = diff.shape[-2]
    g_minus_r = (diff[..., 1] - diff[..., 0]) * 255.0
    return float(
        g_minus_r[..., : round(0.06 * width)].mean() - g_minus_r[..., round(0.11 * width) :].mean()
    )


def grasp_statistics(obs: GraspObservation) -> dict[str, float]:
    """The statistics of :data:`STATISTICS` for one grasp.

    ``peak_force_n`` [N]: the largest force of its samples (the last selected frame is at
    >= 97.5 % of the peak); ``stiffness_n_per_mm`` [N/mm]: minus the slope of a line of
    force against width through its samples' distinct points (NaN with fewer than 3
    widths); ``contact_share_i``: the share of frame i (of augmentation 0) where some
    channel differs by more than :data:`CONTACT_GREY`, beyond the left :data:`GLOW_STRIP`;
    ``p99_*``: the 99th percentile of |difference| per channel in frame 3 (0.5 = 128 grey
    levels); ``edge_glow_grey``: the edge glow in frame 3 [grey levels].
    """
    diff = obs.diff.astype(np.float32) - 0.5
    away = diff[:, :, round(GLOW_STRIP * diff.shape[2]) :]
    shares = (np.abs(away).max(axis=-1) > CONTACT_GREY / 255).mean(axis=(1, 2))
    if np.unique(obs.widths_m).size >= 3:
        slope = float(np.polyfit(obs.widths_m * 1e3, obs.forces_n, 1)[0])
    else:
        slope = math.nan
    p99 = np.percentile(np.abs(diff[2]).reshape(-1, 3), 99, axis=0)
    return {
        "peak_force_n": float(obs.forces_n.max()),
        "stiffness_n_per_mm": -slope,
        **{f"contact_share_{i + 1}": float(s) for i, s in enumerate(shares)},
        **{f"p99_{c}": float(v) for c, v in zip("rgb", p99, strict=True)},
        "edge_glow_grey": _edge_glow_grey(diff[2] + 0.5),
    }


def mean_statistics(observations: Sequence[GraspObservation]) -> dict[str, float]:
    """:func:`grasp_statistics` averaged over grasps (NaN-aware), plus ``peak_force_sd_n``."""
    rows = [grasp_statistics(o) for o in observations]
    out = {key: float(np.nanmean([r[key] for r in rows])) for key in STATISTICS}
    peaks = [r["peak_force_n"] for r in rows]
    out["peak_force_sd_n"] = float(np.std(peaks, ddof=1)) if len(peaks) > 1 else 0.0
    return out


# ---------------------------------------------------------------------- simulation
@dataclass(frozen=True)
class SimulationPlan:
    """How the fit simulates the recorded spheres.

    Attributes:
        copies: simulated spheres per recorded object (each its own session: gel, look).
        grasps: grasps per simulated sphere.
        image_size: rendered frame size (H, W) [px]; the statistics are shares and
            percentiles, so a smaller frame than the recordings' reads the same.
        seed: the generator's seed.
    """

    copies: int = 6
    grasps: int = 3
    image_size: tuple[int, int] = (125, 175)
    seed: int = 0


def simulate_rigid_grasps(
    rig: GripperRig, spheres: dict[str, float], plan: SimulationPlan = SimulationPlan()
) -> list[GraspObservation]:
    """The generator's grasps of rigid spheres (``object -> radius [mm]``) with ``rig``,
    as the recordings hold them (``synthetic.grasp.simulate_grasp``); grasps the frame
    selection rejects are left out."""
    from tactile_compliance.synthetic.grasp import SimulationOptions, make_context, simulate_grasp
    from tactile_compliance.synthetic.objects import rigid_sphere

    options = SimulationOptions(image_size=plan.image_size, rig=rig)
    out: list[GraspObservation] = []
    for n, (name, radius_mm) in enumerate(sorted(spheres.items())):
        for copy in range(plan.copies):
            spec = rigid_sphere(f"{name}-{copy}", radius_mm, plan.seed, plan.grasps, index=n)
            ctx = make_context(spec, plan.seed, options)
            for grasp in range(plan.grasps):
                result = simulate_grasp(ctx, grasp)
                if not result.samples:
                    continue
                samples = [(s.forces, s.widths, s.rgb[..., ::-1]) for s in result.samples]
                out.append(_observation(name, grasp, radius_mm, samples))
    if not out:
        raise RigFitError("the generator's frame selection rejected every simulated grasp")
    return out


# ---------------------------------------------------------------------- the fit
@dataclass
class RigFit:
    """A fitted rig, what each field was fitted on, and the residuals.

    Attributes:
        rig: the fitted rig.
        steps: per field, the target statistic, its real value and the fitted value.
        real: the real statistics (means over grasps, :data:`STATISTICS`).
        simulated: the same for the generator with the fitted rig.
        objects: ``object -> grasps`` of the recordings.
        evaluations: simulations run.
    """

    rig: GripperRig
    steps: list[dict[str, Any]]
    real: dict[str, float]
    simulated: dict[str, float]
    objects: dict[str, int]
    evaluations: int
    plan: SimulationPlan
    soft: dict[str, dict[str, dict[str, float]]] = field(default_factory=dict)

    def residuals(self) -> dict[str, dict[str, float]]:
        """Per statistic: real, simulated and simulated - real."""
        return {
            key: {
                "real": self.real[key],
                "simulated": self.simulated[key],
                "residual": self.simulated[key] - self.real[key],
            }
            for key in STATISTICS
        }

    def to_dict(self) -> dict[str, Any]:
        """The ``fit`` section of the rig file."""
        return {
            "fitted_on": self.objects,
            "method": "calibrate-rig (synthetic.rig_fit), staged",
            "steps": self.steps,
            "residuals": self.residuals(),
            **(
                {
                    "soft_fitted_on": sorted(self.soft),
                    "soft_residuals": self.soft,
                }
                if self.soft
                else {}
            ),
            "simulation": {
                "copies": self.plan.copies,
                "grasps": self.plan.grasps,
                "image_size": list(self.plan.image_size),
                "seed": self.plan.seed,
                "evaluations": self.evaluations,
            },
        }

    def format(self) -> str:
        """The fit and its residuals as text."""
        lines = [
            "Rig fitted on "
            + ", ".join(f"{name} ({n} grasps)" for name, n in self.objects.items())
            + f" ({self.evaluations} simulations):"
        ]
        for step in self.steps:
            lines.append(f"  {step['field']:<26} {step['value']}  <- {step['fitted_on']}")
        lines.append(f"  {'statistic':<20} {'real':>10} {'generator':>10} {'residual':>10}")
        for key, row in self.residuals().items():
            lines.append(
                f"  {key:<20} {row['real']:10.4g} {row['simulated']:10.4g} {row['residual']:+10.3g}"
            )
        if self.soft:
            lines.append(
                f"  {'soft reference':<20} {'statistic':<16} {'real':>8} {'before':>8} {'after':>8}"
            )
            for name, rows in self.soft.items():
                for key, value in rows["real"].items():
                    lines.append(
                        f"  {name:<20} {key:<16} {value:8.4g} {rows['before'][key]:8.4g} "
                        f"{rows['after'][key]:8.4g}"
                    )
        return "\n".join(lines)


def _rounded(value: float, digits: int = 3) -> float:
    """``value`` to ``digits`` significant digits (what the rig file keeps)."""
    return float(f"{value:.{digits}g}")


def _root_log10(
    func: Callable[[float], float], bounds: tuple[float, float], what: str
) -> tuple[float, bool]:
    """``x`` in ``bounds`` where ``func(x) = 0`` (searched in log10 x), and whether the root
    is inside; a bound when ``func`` keeps its sign (False)."""
    from scipy.optimize import brentq

    lo, hi = math.log10(bounds[0]), math.log10(bounds[1])
    f_lo, f_hi = func(10**lo), func(10**hi)
    if not (np.isfinite(f_lo) and np.isfinite(f_hi)):
        raise RigFitError(f"{what}: the simulation gave no value at the search bounds")
    if f_lo * f_hi > 0:
        return (10**lo if abs(f_lo) < abs(f_hi) else 10**hi), False
    return 10 ** brentq(lambda x: func(10**x), lo, hi, xtol=0.004), True


def fit_rig(
    observations: Sequence[GraspObservation],
    *,
    plan: SimulationPlan = SimulationPlan(),
    fit_lights: bool = False,
    progress: Callable[[str], None] | None = None,
) -> RigFit:
    """Fit a rig to recordings of rigid spheres (the module docstring's five steps).

    Args:
        observations: :func:`read_rigid_grasps`.
        plan: how the generator simulates the spheres for each candidate rig.
        fit_lights: also fit ``light_balance`` (default: (1, 1, 1); docs/synthetic.md,
            "The lights", says what either costs on the Wedge).
        progress: called with one line per step.

    Returns:
        A :class:`RigFit`; its rig's fields rounded to 3 significant digits.

    Raises:
        RigFitError: too few usable grasps, or a statistic the simulation cannot give.
    """
    say = progress or (lambda _line: None)
    real = mean_statistics(observations)
    if not np.isfinite(real["stiffness_n_per_mm"]):
        raise RigFitError("no grasp has 3 distinct widths: the closure cannot be measured")
    spheres = {o.object_name: o.radius_mm for o in observations}
    objects: dict[str, int] = {}
    for o in observations:
        objects[o.object_name] = objects.get(o.object_name, 0) + 1
    count = [0]

    def simulate(rig: GripperRig) -> dict[str, float]:
        count[0] += 1
        return mean_statistics(simulate_rigid_grasps(rig, spheres, plan))

    steps: list[dict[str, Any]] = []
    # 1. The controller: the press force.
    peak = (_rounded(real["peak_force_n"]), _rounded(max(real["peak_force_sd_n"], PEAK_SD_FLOOR_N)))
    rig = replace(DATASET_RIG, peak_force_n=peak, edge_glow_grey_per_mm=(0.0, 0.0))
    steps.append(
        {
            "field": "peak_force_n",
            "value": list(peak),
            "fitted_on": f"the grasps' peak forces (sd floored at {PEAK_SD_FLOOR_N} N)",
        }
    )
    say(f"peak force {peak[0]} +- {peak[1]} N")
    # 2. The lights (optional): each channel's p99, twice (the balance moves the others).
    if fit_lights:
        balance = np.ones(3)
        for _ in range(2):
            sim = simulate(rig)
            # light_balance is (G, R, B); the statistics are per channel R, G, B.
            ratio = np.array([real[k] / sim[k] for k in ("p99_g", "p99_r", "p99_b")])
            balance = balance * ratio
            rig = replace(rig, light_balance=tuple(_rounded(b) for b in balance))
        steps.append(
            {
                "field": "light_balance",
                "value": list(rig.light_balance),
                "fitted_on": "p99 |difference| of R, G, B at the third frame",
            }
        )
        say(f"light balance {rig.light_balance}")
    # 3. The gel: the contact share at the three frames.
    from scipy.optimize import minimize_scalar

    share_keys = ("contact_share_1", "contact_share_2", "contact_share_3")

    def share_error(log_e: float) -> float:
        sim = simulate(replace(rig, gel_modulus_pa=10**log_e))
        return float(np.mean([(sim[k] - real[k]) ** 2 for k in share_keys]))

    bounds = (math.log10(GEL_BOUNDS_PA[0]), math.log10(GEL_BOUNDS_PA[1]))
    best = minimize_scalar(share_error, bounds=bounds, method="bounded", options={"xatol": 0.01})
    gel = _rounded(10 ** float(best.x))
    rig = replace(rig, gel_modulus_pa=gel)
    steps.append(
        {
            "field": "gel_modulus_pa",
            "value": gel,
            "fitted_on": "the contact share of the three selected frames (squared error "
            f"{float(best.fun):.3g})",
        }
    )
    say(f"gel {gel:.3g} Pa")
    # 4. The finger and mount: the closure's slope.
    spread = math.sqrt(STIFFNESS_SPREAD)

    def stiffness_gap(k: float) -> float:
        sim = simulate(replace(rig, finger_stiffness_n_per_m=(k / spread, k * spread)))
        return math.log(sim["stiffness_n_per_mm"] / real["stiffness_n_per_mm"])

    k, inside = _root_log10(stiffness_gap, STIFFNESS_BOUNDS_N_PER_M, "finger stiffness")
    k = _rounded(k)
    rig = replace(rig, finger_stiffness_n_per_m=(_rounded(k / spread), _rounded(k * spread)))
    steps.append(
        {
            "field": "finger_stiffness_n_per_m",
            "value": list(rig.finger_stiffness_n_per_m),
            "fitted_on": "the slope of force against width over the selected frames, "
            f"K_f = {k:.3g} N/m x/ {STIFFNESS_SPREAD**0.5:.3g}"
            + ("" if inside else " (at the search bound: the closure is not matched)"),
        }
    )
    say(f"finger stiffness {k:.3g} N/m")
    # 5. The edge glow.
    if real["edge_glow_grey"] < MIN_GLOW_GREY:
        glow_range = (0.0, 0.0)
        how = f"no glow (real G - R {real['edge_glow_grey']:.1f} < {MIN_GLOW_GREY} grey levels)"
    else:

        def glow_gap(gain: float) -> float:
            sim = simulate(replace(rig, edge_glow_grey_per_mm=(gain, gain)))
            return sim["edge_glow_grey"] - real["edge_glow_grey"]

        gain, inside = _root_log10(glow_gap, GLOW_BOUNDS, "edge glow")
        gain = _rounded(gain)
        glow_range = (_rounded(gain / GLOW_SPREAD), _rounded(gain * GLOW_SPREAD))
        how = f"G - R at the left edge, gain {gain:.3g} x/ {GLOW_SPREAD:g}" + (
            "" if inside else " (at the search bound)"
        )
    rig = replace(rig, edge_glow_grey_per_mm=glow_range)
    steps.append({"field": "edge_glow_grey_per_mm", "value": list(glow_range), "fitted_on": how})
    say(f"edge glow {glow_range}")
    if not fit_lights:
        steps.append(
            {
                "field": "light_balance",
                "value": list(rig.light_balance),
                "fitted_on": "not fitted (--fit-lights fits it)",
            }
        )
    simulated = simulate(rig)
    return RigFit(
        rig=rig,
        steps=steps,
        real=real,
        simulated=simulated,
        objects=objects,
        evaluations=count[0],
        plan=plan,
    )
