"""Balanced oversampling: bins never shrink, reach the threshold, test is never touched."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tactile_compliance.data.balance import (
    balance_indices,
    balance_split,
    balance_summary,
    label_bins,
)
from tactile_compliance.data.splits import Split


def frame(objects: list[str], log10_moduli: list[float], start_id: int = 0) -> pd.DataFrame:
    return pd.DataFrame(
        {
            "sample_id": np.arange(start_id, start_id + len(objects)),
            "object": objects,
            "modulus_pa": 10.0 ** np.asarray(log10_moduli, dtype=float),
        }
    )


# Objects with a modulus and a sample count; labels cluster like the real data (few values).
subsets = st.lists(
    st.tuples(st.floats(3.0, 12.0), st.integers(1, 12)), min_size=1, max_size=15
).map(
    lambda objs: frame(
        [f"o{i}" for i, (_, n) in enumerate(objs) for _ in range(n)],
        [m for m, n in objs for _ in range(n)],
    )
)


@settings(max_examples=150, deadline=None)
@given(subsets, st.floats(0.0, 1.0), st.integers(1, 12), st.integers(0, 2**31))
def test_balancing_properties(subset, t_balance, n_bins, seed):
    ids = balance_indices(subset, t_balance, n_bins, seed)
    original = subset["sample_id"].to_numpy()
    # Originals first, each exactly once; the rest only duplicates existing samples.
    assert np.array_equal(ids[: len(original)], original)
    assert np.isin(ids[len(original) :], original).all()

    bins, _ = label_bins(subset["modulus_pa"], n_bins)
    bin_of = dict(zip(original, bins, strict=True))
    before = np.bincount(bins, minlength=n_bins)
    after = np.bincount([bin_of[i] for i in ids], minlength=n_bins)
    thresh = int(t_balance * before.max())
    assert (after >= before).all()  # never reduces a bin
    assert (after[before == 0] == 0).all()  # nothing to copy into empty bins
    nonempty = before > 0
    assert (after[nonempty] >= thresh).all()  # every non-empty bin reaches the threshold
    # Bins at or above the threshold are untouched, the others end exactly at it.
    assert np.array_equal(after[before >= thresh], before[before >= thresh])
    low = nonempty & (before < thresh)
    assert (after[low] == thresh).all()
    # Same seed, same result.
    assert np.array_equal(ids, balance_indices(subset, t_balance, n_bins, seed))


def test_worked_example_from_the_docs():
    # 9 bins over log10 E in [3, 12] (one decade each): counts [40, 10, 0, 4, 0, 0, 0, 0, 1].
    logs = [3.0] * 40 + [4.5] * 10 + [6.5] * 4 + [12.0]
    objects = [f"o{i % 5}" for i in range(len(logs))]
    subset = frame(objects, logs)
    ids = balance_indices(subset, t_balance=0.5, n_bins=9, seed=0)
    summary = balance_summary(subset, ids, n_bins=9)
    assert summary["before"].tolist() == [40, 10, 0, 4, 0, 0, 0, 0, 1]
    # thresh = int(0.5 * 40) = 20: +10, +16 and +19 copies.
    assert summary["after"].tolist() == [40, 20, 0, 20, 0, 0, 0, 0, 20]
    assert len(ids) == 55 + 10 + 16 + 19
    assert summary["lo_pa"].iloc[0] == pytest.approx(1e3)
    assert summary["hi_pa"].iloc[-1] == pytest.approx(1e12)


@pytest.mark.parametrize("seed", range(5))
def test_copies_go_to_the_object_with_the_fewest_samples(seed):
    # One bin (all labels equal) is the only bin: add a second, larger bin so thresh = 12.
    # Bin 0: object A has 1 sample, object B has 5. thresh - 6 = 6 copies:
    # A gets 4 (reaching 5 = B), then one each: A 6, B 6 -> copies A 5, B 1.
    objects = ["A"] + ["B"] * 5 + ["C"] * 12
    logs = [4.0] * 6 + [11.0] * 12
    subset = frame(objects, logs)
    ids = balance_indices(subset, t_balance=1.0, n_bins=2, seed=seed)
    copies = ids[len(subset) :]
    copied_objects = subset.set_index("sample_id").loc[copies, "object"]
    assert copied_objects.value_counts().to_dict() == {"A": 5, "B": 1}


def test_draws_are_with_replacement_and_seeded():
    subset = frame(["A", "A", "B"] + ["C"] * 20, [4.0, 4.0, 4.0] + [11.0] * 20)
    a = balance_indices(subset, 1.0, 2, seed=1)
    b = balance_indices(subset, 1.0, 2, seed=2)
    copies = a[len(subset) :]
    assert len(copies) == 17
    # 17 copies from 3 originals: duplicates of duplicates are unavoidable (with replacement).
    assert len(np.unique(copies)) <= 3
    assert not np.array_equal(a, b)


def test_t_balance_zero_changes_nothing_and_invalid_values_fail():
    subset = frame(["A", "B", "B"], [3.0, 8.0, 8.0])
    assert np.array_equal(balance_indices(subset, 0.0), subset["sample_id"].to_numpy())
    with pytest.raises(ValueError, match="t_balance"):
        balance_indices(subset, 1.5)
    with pytest.raises(ValueError, match="t_balance"):
        balance_indices(subset, -0.1)


def test_balance_split_never_touches_test():
    train = frame(["A"] * 2 + ["B"] * 20, [4.0] * 2 + [11.0] * 20, start_id=0)
    val = frame(["C"] * 1 + ["D"] * 9, [4.0] + [11.0] * 9, start_id=100)
    test = frame(["E"] * 1 + ["F"] * 30, [4.0] + [11.0] * 30, start_id=200)
    samples = pd.concat([train, val, test], ignore_index=True)
    split = Split(train["sample_id"], val["sample_id"], test["sample_id"])
    train_ids, val_ids = balance_split(samples, split, t_balance=1.0, seed=0, n_bins=2)
    assert np.isin(train_ids, train["sample_id"]).all() and len(train_ids) == 22 + 18
    assert np.isin(val_ids, val["sample_id"]).all() and len(val_ids) == 10 + 8
    assert not np.isin(np.concatenate([train_ids, val_ids]), test["sample_id"]).any()
    # The split itself is unchanged (test ids included).
    assert np.array_equal(split.test_ids, test["sample_id"].to_numpy())
    # Validation can be left unbalanced.
    _, val_plain = balance_split(samples, split, 1.0, n_bins=2, balance_validation=False)
    assert np.array_equal(np.sort(val_plain), val["sample_id"].to_numpy())


def test_balance_split_refuses_overlap_with_test():
    samples = frame(["A", "B", "C", "D"], [4.0, 5.0, 6.0, 7.0])
    leaky = SimpleNamespace(
        train_ids=np.array([0, 1]), val_ids=np.array([2]), test_ids=np.array([1, 3])
    )
    with pytest.raises(ValueError, match="test"):
        balance_split(samples, leaky, 1.0)


def test_label_bins_edges():
    bins, edges = label_bins([1e3, 1e12, 10**7.5], n_bins=9)
    assert bins.tolist() == [0, 8, 4]
    assert edges[0] == 0.0 and edges[-1] == pytest.approx(1.0)
    same, _ = label_bins([1e5, 1e5], n_bins=9)
    assert same.tolist() == [0, 0]
