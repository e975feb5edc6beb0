"""Is the synthetic dataset realistic, and hard in the way the real one is?

Frame statistics against the design targets, no label leakage through names or nuisance
parameters, and (slow) the baseline ladder of SYNTHETIC_DATA.md on a generated set.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tactile_compliance.synthetic import generate_burgess_tree
from tactile_compliance.synthetic.grasp import SimulationOptions, make_context, simulate_grasp
from tactile_compliance.synthetic.objects import default_objects

TARGET_MEAN = 0.496  # per channel, real difference images (DATA_FORMATS.md)


def _frame_moments(n_objects: int, size: tuple[int, int], seed: int) -> tuple[np.ndarray, ...]:
    """Per-channel (BGR) mean and std of the stored difference images, both fingers (the
    store holds both fingers as samples, so its normalisation statistics do too)."""
    options = SimulationOptions(image_size=size)
    total = np.zeros(3)
    squares = np.zeros(3)
    count = 0
    for spec in default_objects(n_objects, seed):
        ctx = make_context(spec, seed, options)
        for grasp in range(2):
            for sample in simulate_grasp(ctx, grasp).samples:
                for images in (sample.rgb, sample.rgb_markers):
                    x = images.reshape(-1, 3).astype(np.float64)
                    total += x.sum(axis=0)
                    squares += (x**2).sum(axis=0)
                    count += x.shape[0]
    mean = total / count
    return mean, np.sqrt(squares / count - mean**2)


def test_frame_statistics_small_set() -> None:
    mean, std = _frame_moments(8, (60, 80), seed=11)
    assert np.all(np.abs(mean - TARGET_MEAN) < 0.01), mean
    assert np.all((std > 0.025) & (std < 0.09)), std


@pytest.mark.slow
def test_frame_statistics_full_size() -> None:
    mean, std = _frame_moments(30, (250, 350), seed=1)
    assert np.all(np.abs(mean - TARGET_MEAN) < 0.006), mean
    assert np.all((std > 0.04) & (std < 0.075)), std


def test_no_label_in_names_or_nuisance_parameters() -> None:
    specs = default_objects(400, seed=5, grasps_per_object=5)
    assert all(s.name == f"obj_{s.index:04d}" for s in specs)
    log_label = np.log10([s.modulus_pa for s in specs])
    options = SimulationOptions()
    nuisance = {
        "size": [s.geometry.thickness_mm for s in specs],
        "texture_angle": [s.texture.angle_rad for s in specs],
        "session": [make_context(s, 5, options).session.gels[0].thickness_mm for s in specs[:120]],
    }
    for name, values in nuisance.items():
        values = np.asarray(values, dtype=float)
        r = np.corrcoef(log_label[: values.size], values)[0, 1]
        assert abs(r) < 0.2, (name, r)


@pytest.mark.slow
def test_baseline_ladder(tmp_path: Path) -> None:
    from tactile_compliance.data.burgess import import_burgess
    from tactile_compliance.data.store import GraspStore
    from tactile_compliance.synthetic.ladder import analytical_within_decade, baseline_ladder

    # The issue-17 calibration size: the real table's 286 objects (3 grasps each, the
    # cost of the 150 x 5-8 grasps this test used before, whose draw left the material
    # oracle at 0.800 and images + F/W 0.5 points under F/W; docs/synthetic.md).
    generate_burgess_tree(
        tmp_path / "tree",
        n_objects=286,
        grasps_per_object=3,
        seed=0,
        image_size=(64, 88),
        progress=False,
    )
    import_burgess(tmp_path / "tree", tmp_path / "store", progress=False)
    store = GraspStore.open(tmp_path / "store")
    keep = np.flatnonzero((store.samples["finger"] == "markerless").to_numpy())
    ladder = baseline_ladder(
        store.samples.iloc[keep].reset_index(drop=True), np.asarray(store.frames[keep])
    )
    # A single pixel carries no label information (no leakage through the sensor).
    assert ladder["one_pixel"] <= ladder["constant"] + 0.05, ladder
    # Force and width are informative, images add to force and width, and the material
    # would be a strong cue.
    assert ladder["force_width"] > ladder["constant"] + 0.05, ladder
    assert ladder["image_stats_fw"] > ladder["force_width"], ladder
    assert ladder["oracle_material"] > 0.8, ladder
    # The estimates saturate for hard objects: the raw estimates land within one decade
    # about as often as the real dataset's (Burgess et al.: 28.9 %; issue 17's 20-40 %),
    # and a kNN on them stays well below force and width plus the material. (The
    # design's "kNN on the estimates below 0.5" no longer holds since soft rubbers stop
    # bottoming out: 0.537 here; docs/synthetic.md, "Baseline ladder".)
    samples = store.samples.iloc[keep]
    assert 0.2 <= analytical_within_decade(samples)["either"] <= 0.4
    assert ladder["estimates"] < ladder["oracle_material"] - 0.25, ladder
