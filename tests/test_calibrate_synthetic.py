"""benchmarks/calibrate_synthetic.py: the probes scored on another store's grasps."""

from __future__ import annotations

from pathlib import Path

import numpy as np

import calibrate_synthetic
from tactile_compliance.data.burgess import import_burgess
from tactile_compliance.data.store import GraspStore
from tactile_compliance.synthetic import generate_burgess_tree


def _store(path: Path, seed: int, objects: int) -> GraspStore:
    generate_burgess_tree(
        path / "raw",
        n_objects=objects,
        grasps_per_object=2,
        seed=seed,
        image_size=(48, 64),
        progress=False,
        workers=1,
        rig="wedge-2023",
    )
    import_burgess(path / "raw", path / "store", progress=False)
    return GraspStore.open(path / "store")


def test_real_transfer_probes_score_each_grasp_of_the_other_store(tmp_path: Path) -> None:
    train_samples, train_frames = calibrate_synthetic._rows(
        _store(tmp_path / "train", seed=1, objects=12), "markerless"
    )
    real_samples, real_frames = calibrate_synthetic._rows(
        _store(tmp_path / "real", seed=2, objects=3), "markerless"
    )
    result = calibrate_synthetic.real_transfer_probes(
        train_samples,
        calibrate_synthetic.image_features(train_frames),
        real_samples,
        calibrate_synthetic.image_features(real_frames),
    )
    assert set(result) == {"image features", "F, W", "F, W, log10 E", "F, W, E + image features"}
    grasps = real_samples[["object", "grasp"]].drop_duplicates()
    labels = np.log10(train_samples["modulus_pa"].to_numpy())
    for probe in result.values():
        assert probe["score"]["n_grasps"] == len(grasps) and probe["score"]["n_missing"] == 0
        assert {row["object"] for row in probe["objects"]} == set(real_samples["object"])
        for row in probe["objects"]:
            # Trees do not extrapolate: a prediction stays inside the training labels.
            assert labels.min() - 1e-9 <= np.log10(row["probe_pa"]) <= labels.max() + 1e-9
    table = calibrate_synthetic.format_real_transfer(result)
    assert table.count("\n") == 2 + len(result) and "F, W |" in table
