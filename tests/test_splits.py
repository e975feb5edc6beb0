"""Splits: protocol properties (no leakage, sizes), determinism, persistence, subsets."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tactile_compliance.data.splits import (
    Split,
    grasp_keys,
    make_split,
    make_split_from_config,
    rolling_windows,
    select_subset,
    summarise_split,
)
from tactile_compliance.physics.contact import DEFAULT_GEL_MODULUS_PA

MATERIALS = ("Rubber", "Metal", "Plastic", "Wood")
SHAPES = ("Sphere", "Cylinder", "Irregular")


def make_samples(
    structure: list[tuple[int, int]], n_fingers: int = 2, seed: int = 0
) -> pd.DataFrame:
    """One object per ``(n_grasps, n_augmentations)`` entry; moduli log-uniform 1e3-1e12."""
    rng = np.random.default_rng(seed)
    fingers = ("markerless", "markers")[:n_fingers]
    rows = []
    for o, (n_grasps, n_augs) in enumerate(structure):
        modulus = 10 ** rng.uniform(3.0, 12.0)
        for g in range(n_grasps):
            for a in range(n_augs):
                for f in fingers:
                    rows.append(
                        {
                            "object": f"obj_{o:03d}",
                            "grasp": g,
                            "augmentation": a,
                            "finger": f,
                            "material": MATERIALS[o % len(MATERIALS)],
                            "shape": SHAPES[o % len(SHAPES)],
                            "modulus_pa": modulus,
                        }
                    )
    df = pd.DataFrame(rows)
    df.insert(0, "sample_id", np.arange(len(df)))
    return df


structures = st.lists(st.tuples(st.integers(1, 4), st.integers(1, 3)), min_size=3, max_size=25)
fractions = st.floats(0.05, 0.5)


def _check_partition(samples: pd.DataFrame, split: Split) -> None:
    assert np.array_equal(split.all_ids, np.sort(samples["sample_id"].to_numpy()))


def _group_sizes(samples: pd.DataFrame, keys: pd.Series) -> int:
    return int(keys.value_counts().max())


@settings(max_examples=60, deadline=None)
@given(structures, st.integers(1, 2), st.integers(0, 2**31), fractions, fractions)
def test_unseen_no_object_in_two_splits_and_sizes(structure, n_fingers, seed, f_test, f_val):
    samples = make_samples(structure, n_fingers, seed % 1000)
    split = make_split(samples, "unseen", seed=seed, test_fraction=f_test, val_fraction=f_val)
    _check_partition(samples, split)
    parts = split.frames(samples)
    objects = {name: set(df["object"]) for name, df in parts.items()}
    assert not objects["train"] & objects["test"]
    assert not objects["train"] & objects["val"]
    assert not objects["val"] & objects["test"]
    # Sizes within one group (the largest object) of the targets.
    biggest = _group_sizes(samples, samples["object"])
    n = len(samples)
    n_test, n_val = len(split.test_ids), len(split.val_ids)
    assert abs(n_test - f_test * n) <= biggest
    assert abs(n_val - f_val * (n - n_test)) <= biggest
    assert len(split.train_ids) > 0 and n_test > 0 and n_val > 0


@settings(max_examples=60, deadline=None)
@given(structures, st.integers(1, 2), st.integers(0, 2**31), fractions, fractions)
def test_seen_no_grasp_in_two_splits_and_sizes(structure, n_fingers, seed, f_test, f_val):
    samples = make_samples(structure, n_fingers, seed % 1000)
    split = make_split(samples, "seen", "grasp", seed, f_test, f_val)
    _check_partition(samples, split)
    parts = split.frames(samples)
    grasps = {name: set(grasp_keys(df)) if len(df) else set() for name, df in parts.items()}
    assert not grasps["train"] & grasps["test"]
    assert not grasps["train"] & grasps["val"]
    assert not grasps["val"] & grasps["test"]
    biggest = _group_sizes(samples, grasp_keys(samples))
    n = len(samples)
    n_test, n_val = len(split.test_ids), len(split.val_ids)
    assert abs(n_test - f_test * n) <= biggest
    assert abs(n_val - f_val * (n - n_test)) <= biggest


@settings(max_examples=30, deadline=None)
@given(structures, st.integers(0, 2**31))
def test_per_sample_sizes_within_one_sample(structure, seed):
    samples = make_samples(structure)
    split = make_split(samples, "seen", "per_sample", seed)
    n = len(samples)
    assert abs(len(split.test_ids) - 0.2 * n) <= 1
    assert abs(len(split.val_ids) - 0.2 * (n - len(split.test_ids))) <= 1
    _check_partition(samples, split)


def test_seen_grasp_grouping_keeps_fingers_and_time_shifts_together():
    samples = make_samples([(5, 5)] * 8)  # 5 grasps x 5 shifts x 2 fingers per object
    split = make_split(samples, "seen", "grasp", seed=1)
    where = pd.Series("train", index=samples["sample_id"])
    where[split.val_ids] = "val"
    where[split.test_ids] = "test"
    per_grasp = where.groupby(grasp_keys(samples).to_numpy()).nunique()
    assert (per_grasp == 1).all()
    # Objects do recur across splits under "seen" (that is the point of the condition).
    parts = split.frames(samples)
    assert set(parts["train"]["object"]) & set(parts["test"]["object"])


def test_per_sample_grouping_leaks_grasps():
    """The paper's protocol: copies of a test grasp end up in training."""
    samples = make_samples([(5, 5)] * 8)
    split = make_split(samples, "seen", "per_sample", seed=1)
    summary = summarise_split(samples, split)
    assert summary.leakage["grasps_train_test"] > 0


def test_split_is_deterministic_and_independent_of_row_order():
    samples = make_samples([(3, 2)] * 20, seed=4)
    a = make_split(samples, "unseen", seed=3)
    b = make_split(samples, "unseen", seed=3)
    shuffled = samples.sample(frac=1.0, random_state=0)
    c = make_split(shuffled, "unseen", seed=3)
    d = make_split(samples, "unseen", seed=4)
    assert a == b
    assert np.array_equal(a.test_ids, c.test_ids) and np.array_equal(a.val_ids, c.val_ids)
    assert not np.array_equal(a.test_ids, d.test_ids)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**31))
def test_stratified_split_takes_the_same_share_of_every_stratum(seed):
    # 4 strata x 10 equally sized objects: 20 % test = exactly 2 objects per stratum.
    rows = []
    for stratum, (shape, material) in enumerate(
        [("Sphere", "Rubber"), ("Sphere", "Metal"), ("Cylinder", "Rubber"), ("Cylinder", "Wood")]
    ):
        for o in range(10):
            for g in range(2):
                rows.append(
                    {
                        "object": f"s{stratum}_o{o}",
                        "grasp": g,
                        "shape": shape,
                        "material": material,
                        "modulus_pa": 1e6,
                    }
                )
    samples = pd.DataFrame(rows)
    samples.insert(0, "sample_id", np.arange(len(samples)))
    split = make_split(samples, "unseen", seed=seed, stratify=True)
    test = split.frames(samples)["test"]
    per_stratum = test.groupby(["shape", "material"])["object"].nunique()
    assert len(per_stratum) == 4 and (per_stratum == 2).all()


def test_split_errors():
    samples = make_samples([(2, 1)] * 5)
    with pytest.raises(ValueError, match="per_sample"):
        make_split(samples, "unseen", "per_sample")
    with pytest.raises(ValueError, match="group"):
        make_split(make_samples([(2, 1)] * 2), "unseen")
    with pytest.raises(ValueError, match="test_fraction"):
        make_split(samples, "unseen", test_fraction=1.0)
    with pytest.raises(ValueError, match="condition"):
        make_split(samples, "sideways")


def test_split_save_load_roundtrip(tmp_path):
    samples = make_samples([(3, 2)] * 12)
    split = make_split(samples, "unseen", seed=3, stratify=True, subset="Sphere")
    path = split.save(tmp_path / "sub" / "split.json")
    data = json.loads(path.read_text())
    assert data["condition"] == "unseen" and data["seed"] == 3
    assert data["counts"]["test"] == len(split.test_ids)
    loaded = Split.load(path)
    assert loaded == split
    assert loaded.subset == "Sphere" and loaded.stratify
    assert isinstance(loaded.train_ids, np.ndarray) and loaded.train_ids.dtype == np.int64


def test_split_load_rejects_other_json(tmp_path):
    bad = tmp_path / "x.json"
    bad.write_text(json.dumps({"train_ids": [1]}))
    with pytest.raises(ValueError, match="not a split file"):
        Split.load(bad)
    bad.write_text("{nope")
    with pytest.raises(ValueError, match="not valid JSON"):
        Split.load(bad)


def test_split_rejects_overlapping_ids():
    with pytest.raises(ValueError, match="train and test"):
        Split(train_ids=[1, 2], val_ids=[3], test_ids=[2])


def test_split_frames_reports_ids_missing_from_table():
    samples = make_samples([(2, 1)] * 5)
    split = Split(train_ids=[0, 1], val_ids=[2], test_ids=[999])
    with pytest.raises(ValueError, match="not in the samples table"):
        split.frames(samples)


def test_summarise_split_counts():
    samples = make_samples([(2, 1)] * 4, n_fingers=2)  # 4 objects x 2 grasps x 2 fingers
    # objects 0, 1 train; object 2 val; object 3 test (each object 4 samples).
    split = Split(
        train_ids=np.arange(0, 8),
        val_ids=np.arange(8, 12),
        test_ids=np.arange(12, 16),
        condition="unseen",
        grouping="object",
    )
    summary = summarise_split(samples, split)
    ov = summary.overview
    assert ov.loc["train", "samples"] == 8 and ov.loc["train", "grasps"] == 4
    assert ov.loc["train", "objects"] == 2 and ov.loc["test", "objects"] == 1
    assert ov.loc["test", "fraction"] == pytest.approx(0.25)
    assert summary.leakage == {
        "objects_train_test": 0,
        "objects_train_val": 0,
        "grasps_train_test": 0,
        "grasps_train_val": 0,
    }
    assert summary.by_material.loc["Rubber", "train"] == 4  # object 0
    text = str(summary)
    assert "condition=unseen" in text and "Samples per shape" in text
    json.dumps(summary.to_dict(), default=float)


def test_rolling_windows_are_three_decades():
    windows = rolling_windows()
    assert len(windows) == 7
    assert windows[0] == (1e3, 1e6) and windows[-1] == (1e9, 1e12)
    for lo, hi in windows:
        assert hi / lo == pytest.approx(1e3)


def test_rolling_window_subsets_have_equal_size_and_stay_in_range():
    rng = np.random.default_rng(0)
    moduli = 10 ** rng.uniform(3.0, 12.0, 600)
    samples = pd.DataFrame({"sample_id": np.arange(600), "modulus_pa": moduli})
    sizes = []
    for k, (lo, hi) in enumerate(rolling_windows()):
        sub = select_subset(samples, k, seed=1)
        assert sub["modulus_pa"].between(lo, hi, inclusive="right").all()
        sizes.append(len(sub))
    in_window = [
        samples["modulus_pa"].between(lo, hi, inclusive="right").sum()
        for lo, hi in rolling_windows()
    ]
    assert sizes == [min(in_window)] * 7
    # Seeded undersampling: same seed same rows, other seed other rows.
    a, b = select_subset(samples, 3, seed=1), select_subset(samples, 3, seed=2)
    assert a.equals(select_subset(samples, 3, seed=1)) and not a.equals(b)


def test_rolling_windows_exclude_the_lower_bound_and_include_the_upper():
    # The published code keeps 1e3 * 10**k < E <= 1e6 * 10**k. Labels sitting exactly on
    # a decade (handbook grades) belong to the three windows ending at or above them, never
    # to the one that starts at their value. With (lo, hi] these four labels put exactly
    # one sample into each window, so no undersampling happens and every window's rows are
    # known; including both ends would add 1e3 to window 0, 1e6 to window 3 and 1e9 to
    # window 6, and those windows would then be undersampled to one random row.
    samples = pd.DataFrame({"sample_id": [0, 1, 2, 3], "modulus_pa": [1e3, 1e6, 1e9, 1e12]})
    expected = {0: [1], 1: [1], 2: [1], 3: [2], 4: [2], 5: [2], 6: [3]}
    for seed in range(10):
        chosen = {k: select_subset(samples, k, seed=seed)["sample_id"].tolist() for k in range(7)}
        assert chosen == expected, seed  # 1e3 Pa (sample 0) is in no window


def test_rolling_window_without_samples_is_an_error():
    samples = pd.DataFrame({"sample_id": [0, 1], "modulus_pa": [1e4, 2e4]})
    with pytest.raises(ValueError, match="no samples"):
        select_subset(samples, 0)
    with pytest.raises(ValueError, match="0-6"):
        select_subset(samples, 7)


def test_soft_hard_and_shape_subsets():
    samples = pd.DataFrame(
        {
            "sample_id": [0, 1, 2, 3],
            "modulus_pa": [1e4, DEFAULT_GEL_MODULUS_PA, 1e9, 2e5],
            "shape": ["Sphere", "Cylinder", "sphere", "Hex"],
        }
    )
    assert DEFAULT_GEL_MODULUS_PA == 2.75e5
    assert select_subset(samples, "soft")["sample_id"].tolist() == [0, 3]
    assert select_subset(samples, "hard")["sample_id"].tolist() == [1, 2]
    assert select_subset(samples, "Sphere")["sample_id"].tolist() == [0, 2]
    assert select_subset(samples, None) is samples
    with pytest.raises(ValueError, match="Cylinder"):
        select_subset(samples, "Cube")


def test_make_split_from_config_uses_subset_and_seed():
    samples = make_samples([(2, 1)] * 30)
    split_cfg = SimpleNamespace(
        condition="unseen",
        grouping="grasp",
        test_fraction=0.2,
        val_fraction=0.2,
        stratify=False,
        subset="Sphere",
        seed=None,
    )
    split = make_split_from_config(samples, SimpleNamespace(split=split_cfg, seed=5))
    assert split.seed == 5 and split.subset == "Sphere"
    used = samples.set_index("sample_id").loc[split.all_ids]
    assert (used["shape"] == "Sphere").all() and len(used) == (samples["shape"] == "Sphere").sum()
