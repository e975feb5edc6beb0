"""benchmarks/real_vs_synthetic.py: the generator held against the real Wedge rig.

The helpers are checked on made-up data; the rig check reads the real object table and
the real grasps (``../shared/reference-data``) and skips when they are absent.
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

import real_vs_synthetic
from helpers import wedge_calibration
from tactile_compliance.data.burgess import import_burgess
from tactile_compliance.data.store import GraspStore
from tactile_compliance.synthetic import generate_burgess_tree


def test_closure_stats_read_stiffness_and_contact_above_the_baseline() -> None:
    # 0.4 N unzeroed baseline, contact at frame 10 (1.5 N), then 2 N/mm for 10 mm, a hold.
    closure_mm = np.concatenate([np.zeros(10), np.linspace(0.0, 10.0, 41), np.full(10, 10.0)])
    force_n = 0.4 + np.where(np.arange(closure_mm.size) < 10, 0.0, 2.0 * closure_mm + 1.5)
    width_m = 0.05 - closure_mm * 1e-3
    stats = real_vs_synthetic.closure_stats(force_n, width_m)
    assert stats["stiffness_n_per_mm"] == pytest.approx(2.0, rel=1e-6)
    assert stats["F_peak_n"] == pytest.approx(21.9)
    assert stats["contact_width_mm"] == pytest.approx(50.0)  # 1 N above the baseline
    assert stats["closure_peak_mm"] == pytest.approx(10.0)


def test_edge_glow_reads_green_over_red_at_the_left_edge_only() -> None:
    diff = np.zeros((2, 50, 100, 3), dtype=np.float32)  # RGB differences, 0 = no change
    diff[..., :6, 1] = 20 / 255  # the left 6 %: green up by 20 grey levels
    diff[..., :6, 0] = -10 / 255  # red down by 10
    assert real_vs_synthetic.edge_glow_grey(diff) == pytest.approx(30.0, rel=1e-5)
    diff[..., 50:, 1] = 8 / 255  # a contact's colour elsewhere is subtracted
    assert real_vs_synthetic.edge_glow_grey(diff) == pytest.approx(30.0 - 8.0 * 50 / 89, rel=1e-5)


def test_image_stats_see_the_contact(tmp_path: Path) -> None:
    generate_burgess_tree(
        tmp_path / "raw",
        n_objects=3,
        grasps_per_object=1,
        seed=1,
        image_size=(48, 64),
        progress=False,
        workers=1,
        rig="wedge-2023",
    )
    import_burgess(tmp_path / "raw", tmp_path / "store", progress=False)
    stats = real_vs_synthetic.image_stats(tmp_path / "store")
    assert stats
    for row in stats.values():
        assert 0.0 <= row["contact_share"] <= 1.0 and len(row["contact_share_by_frame"]) == 3
        assert row["force_by_frame_n"][0] <= row["force_by_frame_n"][2] < 35.0
        assert 0.0 < row["outside_median"] < row["p99_B"] + row["p99_G"] + row["p99_R"]
        assert np.isfinite(row["edge_glow_grey"])
    # The estimates: the geometric mean over the object's chosen samples, from the store.
    samples = GraspStore.open(tmp_path / "store").samples
    for label, row in stats.items():
        chosen = samples[
            (samples.object == label)
            & (samples.augmentation == 0)
            & (samples.finger == "markerless")
        ]
        for name in ("elastic", "hertz"):
            expected = np.exp(np.log(chosen[f"{name}_estimate_pa"]).mean())
            # (NaN where no fit succeeded: the estimators need larger frames than these.)
            assert row[f"{name}_pa"] == pytest.approx(expected, rel=1e-9, nan_ok=True)


def test_the_wedge_rig_closes_like_the_real_rig_on_the_golf_ball(
    object_table_csv: Path, reference_data_dir: Path
) -> None:
    real_folder = reference_data_dir / "real" / "wedge-grasps" / "2023-12-06"
    if not real_folder.is_dir():
        pytest.skip(f"{real_folder} is not present")
    real = real_vs_synthetic.real_grasps(real_folder)["golf_ball"]
    from tactile_compliance.synthetic.timeseries import RIGS

    simulated = real_vs_synthetic.simulated_grasps(
        object_table_csv, 0, RIGS["wedge-2023"], labels=["golf_ball"]
    )
    assert list(simulated) == ["golf_ball"]
    k_real = np.mean([g["stiffness_n_per_mm"] for g in real])
    k_wedge = np.mean([g["stiffness_n_per_mm"] for g in simulated["golf_ball"]])
    # Fitted on these grasps (docs/synthetic.md): within 25 %; the dataset rig is ~5x stiffer.
    assert k_wedge == pytest.approx(k_real, rel=0.25)


def test_background_stats_read_vignetting_and_fine_noise() -> None:
    h, w = 100, 140
    yy, xx = np.mgrid[0:h, 0:w]
    falloff = ((xx - w / 2) / w) ** 2 + ((yy - h / 2) / h) ** 2  # 0 at the centre
    frame = np.empty((h, w, 3), dtype=np.float32)
    frame[...] = (140.0, 120.0, 100.0)  # BGR
    frame -= 80.0 * falloff[..., None]
    noise = np.random.default_rng(0).normal(0.0, 2.0, (h, w, 3))
    stats = real_vs_synthetic.background_stats(np.clip(frame + noise, 0, 255).astype(np.uint8))
    assert stats["mean"][2] > stats["mean"][1] > stats["mean"][0]  # RGB order: blue largest
    assert all(v > 25.0 for v in stats["vignetting"])  # corners ~40 grey levels darker
    assert all(1.5 < v < 2.5 for v in stats["fine_noise"])
    assert len(stats["columns"]) == 3 and len(stats["columns"][0]) == w


def test_contact_curves_read_the_loading_part_at_fixed_forces() -> None:
    diff = np.zeros((3, 4, 5, 3), dtype=np.float32)
    diff[1, :2, :, 0] = 20 / 255  # half the frame past the 15-grey-level rule
    diff[2, :, :, 2] = -16 / 255  # all of it
    np.testing.assert_allclose(real_vs_synthetic.contact_share(diff), [0.0, 0.5, 1.0])
    # Loading to 20 N, then unloading: the unloading part is not read.
    force = np.array([0.0, 10.0, 20.0, 10.0, 0.0])
    share = np.array([0.0, 0.2, 0.4, 0.9, 0.9])
    at = real_vs_synthetic.at_forces(force, share)
    np.testing.assert_allclose(at, [0.1, 0.2, 0.3, 0.4])
    assert np.isnan(real_vs_synthetic.at_forces(force / 4, share)[2])  # never 15 N


def test_real_contact_curves_replay_the_videos_through_their_calibration(
    reference_data_dir: Path, tmp_path: Path
) -> None:
    """The golf ball's grasps (the one set that starts without contact): the contact grows
    with the force, as the frames `record` keeps show it (docs/synthetic.md)."""

    session = reference_data_dir / "real" / "wedge-grasps" / "2023-12-06"
    if not session.is_dir():
        pytest.skip(f"{session} is not present")
    folder, calibrations = tmp_path / "videos", tmp_path / "calibrations"
    folder.mkdir()
    calibrations.mkdir()
    for suffix in (".avi", "_readings.csv"):  # one grasp, linked (nothing copied)
        (folder / f"golf_ball_1{suffix}").symlink_to(session / f"golf_ball_1{suffix}")
    wedge_calibration(tmp_path, folder / "golf_ball_1.avi").rename(
        calibrations / "golf_ball_1.json"
    )
    curves = real_vs_synthetic.real_contact_curves(folder, calibrations)
    (grasp,) = curves["golf_ball"]
    assert len(grasp["force_above_n"]) == len(grasp["contact_share"]) > 50
    at = grasp["contact_share_at_forces"]
    assert at[0] < at[1] < at[2] < at[3] and 0.3 < at[3] < 0.6
    depth = grasp["depth_peak_mm_at_forces"]  # the heuristic depth deepens with the force
    assert depth[0] < depth[3] and 1.0 < depth[3] < 3.0


def test_gel_mechanics_contact_grows_with_force_and_without_the_layer_limits(
    capsys: pytest.CaptureFixture[str],
) -> None:
    shares = real_vs_synthetic.print_gel_mechanics()
    assert set(shares) == set(real_vs_synthetic.GEL_VARIANTS)
    for values in shares.values():
        assert all(0.0 < a < b < 1.0 for a, b in itertools.pairwise(values))
    # The thin layer's confinement and the strain saturation both stiffen the gel.
    assert shares["neither"][3] > shares["no saturation"][3] > shares["wedge-2023 gel"][3]
    assert "20/5 N" in capsys.readouterr().out


def test_outer_radius_takes_in_a_textured_contact_whole_and_leaves_out_the_glow() -> None:
    diff = np.full((250, 350, 3), 0.5, dtype=np.float32)
    assert np.isnan(real_vs_synthetic.outer_radius_mm(diff))
    yy, xx = np.mgrid[:250, :350]
    r = np.hypot(yy - 125, xx - 200)
    # A dimpled contact of 60 px (5.25 mm): texture on cells, flat (no change) between them.
    texture = (r < 60) & ((yy // 12 + xx // 12) % 2 == 0)
    diff[texture, 1] += 30 / 255
    diff[:, :40, 1] += 60 / 255  # a strong glow along the left edge, larger than the contact
    radius = real_vs_synthetic.outer_radius_mm(diff)
    assert 60 * 0.0875 - 0.7 < radius < 60 * 0.0875 + 0.7
