"""``calibrate-rig --soft``: fit the rig's soft contact (``soft_contact_spread``,
``soft_edge_glow``) on grasps of compliant reference spheres of known modulus.

A rigid ball cannot measure how the rig renders a soft contact: its imprint is the gel's
alone. A lab's reference objects (spheres whose moduli it knows, recorded with ``record``)
can. After the rigid fit (``synthetic.rig_fit``), two more staged steps, each on the
statistic it drives, with the generator simulating the same spheres with their recorded
moduli (common random numbers, as ``rig_fit``):

6. the soft contact's footprint (``soft_contact_spread``): the squared error of the contact
   share of the three selected frames, per object, by a bounded 1-D search in log10;
7. the soft contact's edge glow (``soft_edge_glow``): the mean over objects of the log
   ratio of the simulated to the real edge glow, by root finding.

The moduli are labels: the fit uses them, so the objects it was fitted on are reference
objects, and scores on them are not scores on new objects (docs/results.md, "What was
fitted on what"). See docs/synthetic.md, "Soft contacts: calibrate-rig --soft".
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from tactile_compliance.data.object_table import read_object_table
from tactile_compliance.synthetic.rig import GripperRig
from tactile_compliance.synthetic.rig_fit import (
    GraspObservation,
    RigFitError,
    SimulationPlan,
    _observation,
    _rounded,
    grasp_statistics,
    object_grasps,
)

__all__ = ["SOFT_MAX_MODULUS_PA", "SoftReference", "fit_soft_contact", "read_soft_grasps"]

SOFT_MAX_MODULUS_PA = 1e7
"""Reference spheres at or above this modulus [Pa] are left out of the soft fit: the gel
takes (nearly) all of their indentation, so the soft contact does not change them, and
the rigid fit already matched them."""

SPREAD_BOUNDS = (0.3, 2.0)
"""The ``soft_contact_spread`` the search covers [-] (the rig's valid range is (0, 2])."""

SOFT_GLOW_BOUNDS = (0.0, 30.0)
"""The ``soft_edge_glow`` the root search covers [-]."""

SOFT_PLAN = SimulationPlan(copies=2, grasps=3)
"""Two simulated spheres per reference object (each its own session) x 3 grasps."""


class SoftReference:
    """The grasps of one compliant reference sphere and what the generator needs of it."""

    def __init__(
        self, name: str, radius_mm: float, modulus_pa: float, material: str, grasps: list
    ) -> None:
        self.name, self.radius_mm, self.modulus_pa = name, radius_mm, modulus_pa
        self.material = material
        self.grasps: list[GraspObservation] = grasps


def read_soft_grasps(
    datasets: Sequence[str | Path], radii_mm: dict[str, float] | None = None
) -> tuple[list[SoftReference], list[str]]:
    """The compliant spheres of the datasets (what ``record`` wrote, with an object table
    giving each object's shape, material and modulus) and what was left out, one line per
    object (not a sphere, no radius, no modulus, or at least :data:`SOFT_MAX_MODULUS_PA`).

    Raises:
        RigFitError: a dataset without an object table, or no compliant sphere at all.
    """
    radii = dict(radii_mm or {})
    references: list[SoftReference] = []
    skipped: list[str] = []
    for dataset in map(Path, datasets):
        table_path = dataset / "dataset_objects_and_compliance.csv"
        if not table_path.is_file():
            raise RigFitError(
                f"{dataset}: no dataset_objects_and_compliance.csv; --soft needs the moduli "
                "that `record --modulus` writes"
            )
        table = read_object_table(table_path)
        for name, row in table.iterrows():
            name = str(name)
            if not (dataset / name).is_dir():
                continue
            shape = str(row.get("shape", "")).strip().lower()
            modulus = float(row.get("modulus_pa", math.nan))
            radius_m = row.get("radius_m")
            radius = radii.get(name)
            if radius is None and radius_m is not None and np.isfinite(float(radius_m)):
                radius = float(radius_m) * 1e3
            if shape != "sphere":
                skipped.append(f"{name}: not a sphere ({row.get('shape')})")
            elif radius is None:
                skipped.append(f"{name}: no radius (give --radius {name}=MM)")
            elif not (math.isfinite(modulus) and modulus > 0):
                skipped.append(f"{name}: no modulus in the table")
            elif modulus >= SOFT_MAX_MODULUS_PA:
                skipped.append(f"{name}: rigid ({modulus:.3g} Pa), fitted by the rigid steps")
            else:
                mine = object_grasps(dataset / name, radius)
                material = str(row.get("material") or "Rubber")
                references.append(SoftReference(name, radius, modulus, material, mine))
    if not references:
        raise RigFitError(
            "--soft: no compliant sphere of known radius and modulus below "
            f"{SOFT_MAX_MODULUS_PA:.0e} Pa (" + "; ".join(skipped) + ")"
        )
    return references, skipped


def _simulate(
    rig: GripperRig, ref: SoftReference, index: int, plan: SimulationPlan
) -> list[GraspObservation]:
    from tactile_compliance.synthetic.grasp import SimulationOptions, make_context, simulate_grasp
    from tactile_compliance.synthetic.objects import reference_sphere

    options = SimulationOptions(image_size=plan.image_size, rig=rig)
    out = []
    for copy in range(plan.copies):
        spec = reference_sphere(
            f"{ref.name}-{copy}",
            ref.radius_mm,
            ref.modulus_pa,
            ref.material,
            plan.seed,
            plan.grasps,
            index=index,
        )
        ctx = make_context(spec, plan.seed, options)
        for grasp in range(plan.grasps):
            result = simulate_grasp(ctx, grasp)
            if result.samples:
                samples = [(s.forces, s.widths, s.rgb[..., ::-1]) for s in result.samples]
                out.append(_observation(ref.name, grasp, ref.radius_mm, samples))
    return out


SHARE_KEYS = ("contact_share_1", "contact_share_2", "contact_share_3")


def _means(grasps: Sequence[GraspObservation]) -> dict[str, float]:
    rows = [grasp_statistics(g) for g in grasps]
    keys = (*SHARE_KEYS, "edge_glow_grey")
    return {k: float(np.nanmean([r[k] for r in rows])) if rows else math.nan for k in keys}


def fit_soft_contact(
    rig: GripperRig,
    references: Sequence[SoftReference],
    *,
    plan: SimulationPlan = SOFT_PLAN,
    progress: Callable[[str], None] | None = None,
) -> tuple[GripperRig, list[dict[str, Any]], dict[str, dict[str, dict[str, float]]], int]:
    """Steps 6 and 7 (the module docstring) on top of a rigid fit's ``rig``.

    Returns:
        ``(rig, steps, per_object, evaluations)``: the rig with both fields (3 significant
        digits), each step as ``rig_fit`` records them, per object the real statistics and
        the generator's before (``rig`` as given) and after, and the simulations run.

    Raises:
        RigFitError: the generator's frame selection rejects every simulated grasp of
            an object.
    """
    say = progress or (lambda _line: None)
    real = {ref.name: _means(ref.grasps) for ref in references}
    count = [0]

    def simulate(candidate: GripperRig) -> dict[str, dict[str, float]]:
        count[0] += 1
        out = {}
        for i, ref in enumerate(references):
            grasps = _simulate(candidate, ref, i, plan)
            if not grasps:
                raise RigFitError(f"the generator's frame selection rejected every {ref.name}")
            out[ref.name] = _means(grasps)
        return out

    before = simulate(rig)
    from scipy.optimize import brentq, minimize_scalar

    def share_error(log_spread: float) -> float:
        sim = simulate(replace(rig, soft_contact_spread=10**log_spread))
        return float(np.mean([(sim[n][k] - real[n][k]) ** 2 for n in real for k in SHARE_KEYS]))

    bounds = (math.log10(SPREAD_BOUNDS[0]), math.log10(SPREAD_BOUNDS[1]))
    best = minimize_scalar(share_error, bounds=bounds, method="bounded", options={"xatol": 0.01})
    spread = _rounded(10 ** float(best.x))
    rig = replace(rig, soft_contact_spread=spread)
    steps = [
        {
            "field": "soft_contact_spread",
            "value": spread,
            "fitted_on": "the contact share of the three selected frames of the soft "
            f"reference spheres (squared error {float(best.fun):.3g})",
        }
    ]
    say(f"soft contact spread {spread}")

    def glow_gap(extra: float) -> float:
        sim = simulate(replace(rig, soft_edge_glow=extra))
        return float(
            np.mean(
                [
                    math.log(
                        max(sim[n]["edge_glow_grey"], 0.5) / max(real[n]["edge_glow_grey"], 0.5)
                    )
                    for n in real
                ]
            )
        )

    lo, hi = SOFT_GLOW_BOUNDS
    g_lo, g_hi = glow_gap(lo), glow_gap(hi)
    if g_lo * g_hi > 0:
        extra, note = (lo if abs(g_lo) < abs(g_hi) else hi), " (at the search bound)"
    else:
        extra, note = float(brentq(glow_gap, lo, hi, xtol=0.02)), ""
    extra = _rounded(extra) if extra > 0 else 0.0
    rig = replace(rig, soft_edge_glow=extra)
    steps.append(
        {
            "field": "soft_edge_glow",
            "value": extra,
            "fitted_on": "G - R at the left edge of the soft reference spheres (mean log ratio)"
            + note,
        }
    )
    say(f"soft edge glow {extra}")
    after = simulate(rig)
    per_object = {n: {"real": real[n], "before": before[n], "after": after[n]} for n in real}
    return rig, steps, per_object, count[0]
