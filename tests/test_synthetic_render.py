"""Rendering and photometric depth reconstruction of the synthetic generator."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from tactile_compliance.data.photometric import reconstruct_depth
from tactile_compliance.synthetic.geometry import PadGrid
from tactile_compliance.synthetic.render import (
    difference_images,
    gel_height_maps,
    pixel_size_mm,
    reference_frame,
    render_frames,
    sample_edge_glow,
    sample_sensor_look,
)
from tactile_compliance.synthetic.rng import stream

SIZE = (120, 168)


def _bowl(size: tuple[int, int], depth_mm: float, radius_mm: float = 5.0) -> np.ndarray:
    """A spherical-cap imprint (paraboloid) centred in the image [mm]."""
    h, w = size
    px = pixel_size_mm(size)
    yy, xx = np.mgrid[0:h, 0:w]
    r2 = ((xx - w / 2) * px) ** 2 + ((yy - h / 2) * px) ** 2
    return (depth_mm * np.clip(1.0 - r2 / radius_mm**2, 0.0, None)).astype(np.float32)


def _render_diff(depth: np.ndarray, markers: bool, seed: int = 0) -> np.ndarray:
    look = sample_sensor_look(stream(seed, "look", markers), markers=markers)
    look.jpeg_quality = 0
    rng = stream(seed, "noise")
    reference = reference_frame(look, depth.shape[1:], rng)  # type: ignore[arg-type]
    return difference_images(render_frames(depth, look, rng), reference)


def test_difference_images_are_quantised_like_the_real_pipeline() -> None:
    diff = _render_diff(_bowl(SIZE, 1.0)[None], markers=False)
    assert diff.dtype == np.float32
    levels = (diff.astype(np.float64) - 0.5) * 255.0
    np.testing.assert_allclose(levels, np.round(levels), atol=1e-3)
    # Contact-free areas stay near 0.5; the imprint moves every channel.
    assert abs(float(np.median(diff)) - 0.5) < 3 / 255
    assert np.abs(diff - 0.5).max() > 20 / 255


@pytest.mark.parametrize("markers", [False, True])
def test_photometric_depth_recovers_the_imprint(markers: bool) -> None:
    true = np.stack([_bowl(SIZE, d) for d in (0.3, 0.8, 1.5)])
    depth = reconstruct_depth(_render_diff(true, markers), markers=markers)
    for k in range(3):
        corr = np.corrcoef(depth[k].ravel(), true[k].ravel())[0, 1]
        assert corr > 0.9, (k, corr)
        # Right sign and order of magnitude; the optics' gains and saturation make the
        # real inversion over- or under-shoot (docs/synthetic.md).
        assert 0.6 * true[k].max() < depth[k].max() < 2.5 * true[k].max()
    assert depth[0].max() < depth[1].max() < depth[2].max()


def test_half_resolution_solve_matches_full_solve() -> None:
    diff = _render_diff(_bowl(SIZE, 1.0)[None], markers=False)
    full = reconstruct_depth(diff)
    half = reconstruct_depth(diff, solve_scale=0.5)
    assert abs(float(half.max()) - float(full.max())) < 0.1 * float(full.max())


def test_skirt_keeps_the_core_and_drapes_around_it() -> None:
    grid = PadGrid(0.25)
    xx, yy = grid.coords()
    field = np.where(xx**2 + yy**2 < 9.0, 1.0, 0.0).astype(np.float32)[None]  # 3 mm flat punch
    depth, contact = gel_height_maps(field, grid, SIZE, gel_thickness_mm=5.0)
    h, w = SIZE
    assert depth[0, h // 2, w // 2] == pytest.approx(1.0, abs=0.02)
    px = pixel_size_mm(SIZE)
    ring = depth[0, h // 2, int(w / 2 + 4.5 / px)]  # 1.5 mm outside the punch edge
    assert 0.05 < ring < 0.9
    assert contact[0, h // 2, w // 2] == pytest.approx(1.0)
    assert contact[0, 2, 2] == 0.0


def test_parametric_background_has_the_wedge_layout() -> None:
    look = sample_sensor_look(stream(3, "bg"), markers=False)
    look.jpeg_quality = 0
    frame = reference_frame(look, (150, 210), stream(3, "n")).astype(float)
    blue, green, red = frame[..., 0], frame[..., 1], frame[..., 2]
    assert blue[-10:].mean() > blue[60:90].mean() + 20  # blue band at the bottom
    assert red[:10].mean() > red[60:90].mean() + 5  # red tint at the top
    chroma = green - (blue + red) / 2  # green tint at the left edge
    assert chroma[:, :5].mean() > chroma[:, 100:110].mean() + 3


def test_texture_finer_than_a_pixel_is_averaged_away() -> None:
    from tactile_compliance.synthetic.materials import TextureSpec
    from tactile_compliance.synthetic.textures import resolved_fraction, texture_canvas

    fine = TextureSpec("machined", amplitude_mm=0.005, scale_mm=0.1, angle_rad=0.3)
    coarse = TextureSpec("knurled", amplitude_mm=0.03, scale_mm=1.0, angle_rad=0.3)
    for size in ((250, 350), (48, 64)):
        px = pixel_size_mm(size)
        for spec in (fine, coarse):
            canvas = texture_canvas(spec, size, px, stream(0, "tex", spec.kind))
            expected = spec.amplitude_mm * resolved_fraction(spec.scale_mm, px)
            assert float(canvas.std()) == pytest.approx(expected, rel=0.02)
    # Full size resolves a 1 mm knurl completely; 48 x 64 px (0.48 mm) keeps a tenth
    # of a 0.1 mm machining lay.
    assert resolved_fraction(1.0, pixel_size_mm((250, 350))) == 1.0
    assert resolved_fraction(0.1, pixel_size_mm((48, 64))) < 0.15


def test_open_pores_print_on_soft_foam() -> None:
    from tactile_compliance.synthetic.materials import (
        PORE_PRINT_SHARE,
        elastic_share,
        pore_imprint_gain,
    )

    # The renderer scales textures by the elastic share (~0.03 for a 1e4 Pa foam); the
    # pores' canvas gain makes them print with at least PORE_PRINT_SHARE.
    for modulus in (1e4, 1e5, 1e7):
        share = elastic_share(modulus, 0.2)
        printed = share * pore_imprint_gain(modulus, 0.2)
        assert printed == pytest.approx(max(share, PORE_PRINT_SHARE))
    assert elastic_share(1e4, 0.2) < 0.05


def test_contact_grows_across_the_three_frames() -> None:
    from tactile_compliance.synthetic.grasp import SimulationOptions, make_context, simulate_grasp
    from tactile_compliance.synthetic.objects import default_objects

    options = SimulationOptions(image_size=(60, 80))
    grown = []
    for spec in default_objects(5, seed=6):
        for sample in simulate_grasp(make_context(spec, 6, options), 0).samples[:1]:
            deviation = np.abs(sample.rgb - 0.5).max(axis=-1) * 255.0  # (3, H, W)
            area = (deviation > 5.0).reshape(3, -1).mean(axis=1)
            depth = sample.depth.reshape(3, -1).max(axis=1)
            assert depth[0] <= depth[2] + 0.05, (spec.name, depth)
            grown.append(area[2] - area[0])
    assert len(grown) >= 4 and np.mean(grown) > 0, grown


def test_edge_glow_lights_the_left_edge_green_with_the_imprint_there() -> None:
    look = sample_sensor_look(stream(5, "look"), markers=False)
    look.jpeg_quality = 0
    look.read_noise = 0.0
    look.drift = (0.0, 0.0)
    glowing = replace(look, edge_glow=sample_edge_glow(stream(5, "glow"), (2000.0, 2000.0)))
    assert glowing.edge_glow[0] == pytest.approx(2000.0)
    # A flat, uniform 20 um compression: no slopes, so only the glow (and the membrane's
    # uniform darkening) differ between the two looks.
    depth = np.full((1, *SIZE), 0.02, dtype=np.float32)
    plain = render_frames(depth, look, stream(0, "n")).astype(float)[0]
    lit = render_frames(depth, glowing, stream(0, "n")).astype(float)[0]
    change = lit - plain  # BGR
    w = SIZE[1]
    left, right = change[:, : w // 20], change[:, w // 2 :]
    assert left[..., 1].mean() > 10.0  # green up at the left edge
    assert left[..., 2].mean() < -5.0  # red down
    assert np.abs(right).max() <= 1.0  # nothing away from the edge
    # No imprint at the edge, no glow.
    empty = np.zeros((1, *SIZE), dtype=np.float32)
    np.testing.assert_array_equal(
        render_frames(empty, look, stream(0, "n")), render_frames(empty, glowing, stream(0, "n"))
    )


def test_edge_glow_saturates_so_frames_stay_difference_images() -> None:
    look = sample_sensor_look(stream(6, "look"), markers=False)
    look.jpeg_quality = 0
    glowing = replace(look, edge_glow=(3600.0, 0.6, 0.18, 0.07))
    # 0.5 mm of imprint at the edge: linear in the gain it would be 1800 grey levels.
    depth = np.full((1, *SIZE), 0.5, dtype=np.float32)
    rng = stream(6, "n")
    reference = reference_frame(glowing, SIZE, rng)
    diff = difference_images(render_frames(depth, glowing, rng), reference)
    assert np.abs(diff - 0.5).max() < 0.5  # within the plausible [0, 1]


def test_the_glow_scale_multiplies_each_frames_glow() -> None:
    # The rig's soft_edge_glow reaches the renderer as a per-frame factor on the gain.
    look = sample_sensor_look(stream(7, "look"), markers=False)
    look.jpeg_quality = 0
    look.read_noise = 0.0
    look.drift = (0.0, 0.0)
    glowing = replace(look, edge_glow=(200.0, 0.6, 0.18, 0.07))
    depth = np.full((2, *SIZE), 0.02, dtype=np.float32)  # weak: far from saturation
    plain = render_frames(depth, look, stream(0, "n")).astype(float)
    one = render_frames(depth, glowing, stream(0, "n")).astype(float) - plain
    scaled = render_frames(depth, glowing, stream(0, "n"), glow_scale=np.array([1.0, 3.0]))
    scaled = scaled.astype(float) - plain
    w = SIZE[1] // 20
    np.testing.assert_array_equal(scaled[0], one[0])
    assert scaled[1][:, :w, 1].mean() == pytest.approx(3 * one[1][:, :w, 1].mean(), rel=0.1)
