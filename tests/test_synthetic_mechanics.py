"""Physics limits of the synthetic generator's contact mechanics."""

from __future__ import annotations

import numpy as np
import pytest

from tactile_compliance.physics.contact import hertz_force_n
from tactile_compliance.synthetic.geometry import (
    NO_SURFACE,
    PadGrid,
    Pose,
    ShapeSpec,
    sag_map,
    sample_pose,
    sample_shape,
)
from tactile_compliance.synthetic.materials import MATERIALS, SOLID_ELASTOMER_MAX_STRAIN
from tactile_compliance.synthetic.mechanics import (
    GelModel,
    ObjectMechanics,
    contact_curve,
    force_curve,
    gel_compression,
    gel_compression_fields,
    shell_stiffness_n_per_m,
)
from tactile_compliance.synthetic.rng import stream

CENTRED = Pose((0.0, 0.0), 0.0, (0.0, 0.0))
# Linear-elastic limit: no thin-layer effect, no saturation.
HALF_SPACE_GEL = GelModel(thickness_mm=1e6, max_strain=1e6)


def _effective_modulus(e_obj: float, nu_obj: float, gel: GelModel) -> float:
    return 1.0 / ((1 - gel.poisson**2) / gel.modulus_pa + (1 - nu_obj**2) / e_obj)


@pytest.mark.parametrize("depth_mm", [0.05, 0.1, 0.2])
def test_small_sphere_matches_hertz_within_ten_percent(depth_mm: float) -> None:
    grid = PadGrid(0.05)
    radius_mm = 5.0
    sag = sag_map(ShapeSpec("Sphere", {"radius_mm": radius_mm}, 10.0), grid, CENTRED)
    obj = ObjectMechanics(1e6, 0.45, size_mm=1e7, max_strain=1e6)
    curve = contact_curve(sag, HALF_SPACE_GEL, obj, grid, np.array([depth_mm]))
    expected = hertz_force_n(
        depth_mm * 1e-3, radius_mm * 1e-3, _effective_modulus(1e6, 0.45, HALF_SPACE_GEL)
    )
    assert curve.forces_n[0] == pytest.approx(expected, rel=0.10)


def test_flat_punch_matches_boussinesq() -> None:
    grid = PadGrid(0.05)
    xx, yy = grid.coords()
    radius_mm = 2.0
    sag = np.where(xx**2 + yy**2 < radius_mm**2, 0.0, NO_SURFACE).astype(np.float32)
    obj = ObjectMechanics(1e6, 0.45, size_mm=1e7, max_strain=1e6)
    curve = contact_curve(sag, HALF_SPACE_GEL, obj, grid, np.array([0.01]))
    e_star = _effective_modulus(1e6, 0.45, HALF_SPACE_GEL)
    assert curve.forces_n[0] == pytest.approx(2 * radius_mm * 1e-3 * e_star * 0.01e-3, rel=0.06)


def test_calibration_rigid_sphere_and_flat() -> None:
    grid = PadGrid(0.5)
    gel = GelModel(thickness_mm=5.0)
    rigid = ObjectMechanics(1e12, 0.3, size_mm=50.0)
    sphere = sag_map(ShapeSpec("Sphere", {"radius_mm": 25.0}, 50.0), grid, CENTRED)
    flat = sag_map(
        ShapeSpec("Rectangular", {"face_u_mm": 60, "face_v_mm": 60, "edge_radius_mm": 1}, 30.0),
        grid,
        CENTRED,
    )
    sphere_depth = float(force_curve(sphere, gel, rigid, grid).approach_at(60.0))
    flat_depth = float(force_curve(flat, gel, rigid, grid).approach_at(60.0))
    assert 1.1 <= sphere_depth <= 2.5
    assert flat_depth <= 0.2
    assert flat_depth < sphere_depth


REGULAR = ("Sphere", "Cylinder", "Rectangular", "Hex")


@pytest.mark.parametrize("modulus_pa", [1e4, 1e6, 1e8, 2e11])
@pytest.mark.parametrize("kind", REGULAR)
def test_force_approach_curves_are_monotone(kind: str, modulus_pa: float) -> None:
    grid = PadGrid(0.5)
    for i in range(3):
        rng = stream(7, kind, i)
        spec = sample_shape(kind, rng)
        sag = sag_map(spec, grid, sample_pose(rng, kind))
        obj = ObjectMechanics(modulus_pa, 0.45, spec.thickness_mm, 0.5)
        curve = force_curve(sag, GelModel(), obj, grid)
        forces = curve.forces_n
        # Above the pixel scale (a few cells in contact) the raw curve increases strictly.
        relevant = forces[:-1] > 0.05
        assert np.all(np.diff(forces)[relevant] > 0), (kind, modulus_pa, forces)
        assert forces[-1] >= 90.0
        # The inversion is consistent with the curve.
        probe = np.array([5.0, 30.0, 60.0])
        back = np.exp(
            np.interp(np.log(curve.approach_at(probe)), np.log(curve.approaches_mm), np.log(forces))
        )
        np.testing.assert_allclose(back, probe, rtol=0.02)


def _state_at_60n(modulus_pa: float, spec: ShapeSpec, grid: PadGrid) -> tuple[float, float, float]:
    """(approach per side [mm], max gel depth [mm], contact area [mm^2]) at 60 N."""
    gel = GelModel(thickness_mm=5.0)
    obj = ObjectMechanics(modulus_pa, 0.45, spec.thickness_mm, max_strain=0.75)
    sag = sag_map(spec, grid, CENTRED)
    approach = float(force_curve(sag, gel, obj, grid).approach_at(60.0))
    state = contact_curve(sag, gel, obj, grid, np.array([approach]), fields=True)
    assert state.gel_depth_mm is not None
    gel_depth = float(state.gel_depth_mm.max())
    area = float((state.gel_depth_mm[0] > 0.1).sum() * grid.cell_mm**2)
    return approach, gel_depth, area


SATURATION_SHAPES = [
    ShapeSpec("Sphere", {"radius_mm": 25.0}, 50.0),
    ShapeSpec("Cylinder", {"radius_mm": 8.0, "length_mm": 60.0}, 16.0),
]


@pytest.mark.parametrize("spec", SATURATION_SHAPES, ids=lambda s: s.kind)
def test_hard_objects_saturate(spec: ShapeSpec) -> None:
    grid = PadGrid(0.5)
    states = np.array([_state_at_60n(e, spec, grid) for e in (1e8, 1e9, 1e10, 2e11)])
    spread = (states.max(axis=0) - states.min(axis=0)) / states.max(axis=0)
    assert np.all(spread < 0.05), states


@pytest.mark.parametrize("spec", SATURATION_SHAPES, ids=lambda s: s.kind)
def test_soft_objects_are_monotone_in_modulus(spec: ShapeSpec) -> None:
    grid = PadGrid(0.5)
    moduli = [1e4, 3e4, 1e5, 3e5, 1e6, 3e6, 1e7]
    states = np.array([_state_at_60n(e, spec, grid) for e in moduli])
    approach, gel_depth, area = states.T
    # The width change falls with E over the whole soft range ...
    assert np.all(np.diff(approach) < 0), approach
    assert approach[0] > 2.0 * approach[-1]
    # ... while the gel's share (depth) rises and the thresholded contact area shrinks
    # from 1e5 Pa up. Softer still, the object densifies and the gel barely reaches the
    # 0.1 mm contact threshold, so those two turn over (docs/synthetic.md).
    upper = np.asarray(moduli) >= 1e5
    assert np.all(np.diff(gel_depth[upper]) > 0), gel_depth
    assert np.all(np.diff(area[upper]) < 0), area
    assert gel_depth[-1] > 1.2 * gel_depth[upper][0]


@pytest.mark.parametrize(
    ("radius_mm", "soft_pa", "firm_pa"), [(10.0, 1e5, 1e6), (20.0, 10**4.5, 10**5.5)]
)
def test_soft_solid_rubber_keeps_giving_way_after_the_first_frame(
    radius_mm: float, soft_pa: float, firm_pa: float
) -> None:
    # A solid elastomer flows sideways instead of densifying (SOLID_ELASTOMER_MAX_STRAIN),
    # so between the first stored frame (~16 N) and the 60 N peak a softer rubber ball
    # still closes the gripper further than one a decade firmer, and its total closure
    # is at least 1.6x. With the foam-like cap of 0.5 that rubber had before, the softer
    # ball had bottomed out by 16 N (1.18 vs 1.23 mm and 1.32 vs 1.72 mm late closure;
    # total ratios 1.4 and 1.54), and every sub-1e5 Pa object looked alike.
    grid = PadGrid(0.5)
    spec = ShapeSpec("Sphere", {"radius_mm": radius_mm}, 2.0 * radius_mm)
    sag = sag_map(spec, grid, CENTRED)
    rubber = MATERIALS["Rubber"]
    assert rubber.max_strain == MATERIALS["Food"].max_strain == SOLID_ELASTOMER_MAX_STRAIN

    def closure_mm(modulus_pa: float) -> tuple[float, float]:
        obj = ObjectMechanics(modulus_pa, 0.49, spec.thickness_mm, rubber.max_strain)
        at16, at60 = force_curve(sag, GelModel(), obj, grid).approach_at([16.0, 60.0])
        return float(at60 - at16), float(at60)

    soft_late, soft_total = closure_mm(soft_pa)
    firm_late, firm_total = closure_mm(firm_pa)
    assert soft_late > 1.15 * firm_late, (soft_late, firm_late)
    assert soft_total > 1.6 * firm_total, (soft_total, firm_total)
    # The fingers never meet: the cap keeps a tenth of the object between them.
    assert 2.0 * closure_mm(1e3)[1] < 0.9 * spec.thickness_mm + 1e-6


def test_shell_stiffness_formula() -> None:
    # k = 4 E t^2 / (R sqrt(3 (1 - nu^2))), t = 1 mm, R = 20 mm, E = 2 GPa, nu = 0.4
    expected = 4 * 2e9 * 1e-6 / (0.02 * np.sqrt(3 * (1 - 0.16)))
    assert shell_stiffness_n_per_m(2e9, 0.4, 1.0, 20.0) == pytest.approx(expected)


def _fields_at_60n(modulus_pa: float, spec: ShapeSpec) -> tuple[np.ndarray, np.ndarray, float]:
    """(rendered gel field, unconformed field [mm], approach [mm]) at 60 N, 0.25 mm grid."""
    grid = PadGrid(0.25)
    gel = GelModel(thickness_mm=5.0)
    obj = ObjectMechanics(modulus_pa, 0.45, spec.thickness_mm, max_strain=0.5)
    sag = sag_map(spec, grid, CENTRED)
    approach = float(force_curve(sag, gel, obj, grid).approach_at(60.0))
    delta = np.array([approach])
    conformed = gel_compression_fields(sag, gel, obj, grid, delta)[0]
    local = gel_compression_fields(sag, gel, obj, grid, delta, conformity=False)[0]
    return conformed, local, approach


def _max_slope(field: np.ndarray, cell_mm: float = 0.25) -> float:
    gy, gx = np.gradient(field, cell_mm)
    return float(np.hypot(gx, gy).max())


BOX = ShapeSpec("Rectangular", {"face_u_mm": 12.0, "face_v_mm": 12.0, "edge_radius_mm": 0.5}, 20.0)


def test_hard_objects_print_their_geometry() -> None:
    # A rigid object: the gel takes the whole interference, edges included.
    for spec in (BOX, ShapeSpec("Sphere", {"radius_mm": 10.0}, 20.0)):
        conformed, local, approach = _fields_at_60n(1e9, spec)
        np.testing.assert_allclose(conformed, local, atol=0.005 * float(local.max()))
        sag = sag_map(spec, PadGrid(0.25), CENTRED)
        inside = sag < approach
        interference = approach - sag[inside]
        assert np.abs(conformed[inside] - interference).max() < 0.02 * approach


def test_soft_objects_press_soft_edged_imprints() -> None:
    # Same 60 N on the same box: a compliant object's smooth pressure gives a dished,
    # soft-edged imprint; the rigid box prints sharp walls.
    hard, _, _ = _fields_at_60n(1e9, BOX)
    rows, cols = hard.shape
    near_edge = (rows // 2, cols // 2 + round(5.8 / 0.25))  # 0.2 mm inside the face edge
    ratios = {}
    for modulus in (1e5, 1e6, 1e7, 1e9):
        field, _, _ = _fields_at_60n(modulus, BOX)
        ratios[modulus] = field[near_edge] / field[rows // 2, cols // 2]
        # The same load: the imprint keeps its volume.
        assert field.sum() == pytest.approx(_fields_at_60n(modulus, BOX)[1].sum(), rel=1e-3)
    assert ratios[1e5] < ratios[1e6] < ratios[1e7] <= ratios[1e9] + 1e-6, ratios
    soft, _, _ = _fields_at_60n(1e5, BOX)
    assert _max_slope(soft) < 0.7 * _max_slope(hard)


def test_soft_objects_conform_into_large_contacts() -> None:
    # A curved object: the softer it is, the larger the contact at the same force.
    sphere = ShapeSpec("Sphere", {"radius_mm": 10.0}, 20.0)
    areas = []
    for modulus in (1e5, 1e6, 1e9):
        field, _, _ = _fields_at_60n(modulus, sphere)
        areas.append(float((field > 0).sum()) * 0.25**2)
    assert areas[0] > areas[1] > areas[2], areas
    assert areas[0] > 1.5 * areas[2]


def test_the_soft_contact_spread_narrows_compliant_imprints_and_keeps_their_volume() -> None:
    # The rig's soft_contact_spread: a soft sphere's imprint shrinks (and deepens) by
    # 1 - c_o (1 - spread) in radius at the same load; a rigid one keeps its footprint.
    sphere = ShapeSpec("Sphere", {"radius_mm": 10.0}, 20.0)
    grid, gel = PadGrid(0.25), GelModel(thickness_mm=5.0)
    sag = sag_map(sphere, grid, CENTRED)
    for modulus, narrows in ((1e5, True), (1e9, False)):
        obj = ObjectMechanics(modulus, 0.45, sphere.thickness_mm, max_strain=0.5)
        delta = np.array([float(force_curve(sag, gel, obj, grid).approach_at(60.0))])
        plain, shares = gel_compression(sag, gel, obj, grid, delta)
        narrow, _ = gel_compression(sag, gel, obj, grid, delta, spread=0.6)
        np.testing.assert_array_equal(
            plain[0], gel_compression_fields(sag, gel, obj, grid, delta)[0]
        )
        assert narrow.sum() == pytest.approx(plain.sum(), rel=1e-3)
        area_plain, area_narrow = (plain[0] > 0).sum(), (narrow[0] > 0).sum()
        if narrows:
            assert shares[0] > 0.5
            expected = (1 - shares[0] * 0.4) ** 2
            assert area_narrow / area_plain == pytest.approx(expected, rel=0.15)
            assert narrow.max() > 1.5 * plain.max()
        else:
            assert shares[0] < 0.01
            assert abs(area_narrow / area_plain - 1) < 0.03
