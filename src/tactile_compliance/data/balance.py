"""The paper's "Balanced" strategy: oversample rare modulus bins of train and validation,
spreading the copies over each bin's objects; test is never touched.

See docs/protocol.md, "4. Balanced strategy".
"""

from __future__ import annotations

import heapq
from collections.abc import Sequence
from typing import Any

import numpy as np
import pandas as pd

from tactile_compliance.data.normalisation import NormalisationConstants, normalise_modulus
from tactile_compliance.data.preprocess import require_columns

__all__ = ["balance_indices", "balance_split", "balance_summary", "label_bins"]


def label_bins(
    modulus_pa: Any, n_bins: int = 9, label_constants: NormalisationConstants | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Bin index of every label and the bin edges (normalised label units).

    Bins are uniform between the labels' own min and max; the maximum belongs to the last
    bin (as in ``np.histogram``). When all labels are equal everything is in bin 0.
    """
    if n_bins < 1:
        raise ValueError(f"n_bins must be >= 1, got {n_bins}")
    y = np.asarray(normalise_modulus(np.asarray(modulus_pa, dtype=float), label_constants))
    if y.size == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(n_bins + 1)
    if not np.all(np.isfinite(y)):
        raise ValueError("labels must be finite and positive to be binned")
    lo, hi = float(y.min()), float(y.max())
    edges = np.linspace(lo, hi, n_bins + 1)
    if hi == lo:
        return np.zeros(len(y), dtype=np.int64), edges
    idx = np.floor((y - lo) / (hi - lo) * n_bins).astype(np.int64)
    return np.clip(idx, 0, n_bins - 1), edges


def balance_indices(
    samples_subset: pd.DataFrame,
    t_balance: float,
    n_bins: int = 9,
    seed: int | Sequence[int] = 0,
    label_constants: NormalisationConstants | None = None,
) -> np.ndarray:
    """Sample ids of ``samples_subset`` plus the duplicates that balance its label bins.

    Args:
        samples_subset: rows of one split (train or validation), with ``sample_id``,
            ``object`` and ``modulus_pa`` (Pa).
        t_balance: in [0, 1]; bins are raised to ``int(t_balance * largest bin count)``.
        n_bins: number of uniform bins on the normalised label (paper: 9).
        seed: seed of the tie-breaking and of the draws (same seed -> same ids).
        label_constants: label normalisation (its range does not change the bins).

    Returns:
        int64 array: every original id once (input order), then the duplicates. Only
        existing samples are copied, spread over each bin's objects (the object with the
        fewest samples in the bin first); no bin shrinks, empty bins stay empty and every
        other bin ends with at least the threshold.
    """
    if not 0.0 <= t_balance <= 1.0:
        raise ValueError(f"t_balance must be in [0, 1], got {t_balance}")
    require_columns(samples_subset, ("sample_id", "object", "modulus_pa"), "balancing")
    ids = samples_subset["sample_id"].to_numpy(dtype=np.int64)
    if len(ids) == 0:
        return ids
    objects = samples_subset["object"].astype(str).to_numpy()
    bins, _ = label_bins(samples_subset["modulus_pa"].to_numpy(), n_bins, label_constants)
    counts = np.bincount(bins, minlength=n_bins)
    thresh = int(t_balance * counts.max())

    rng = np.random.default_rng(seed)
    extra: list[np.ndarray] = []
    for b in range(n_bins):
        count = int(counts[b])
        if count == 0 or count >= thresh:
            continue  # empty bins stay empty (nothing to copy); full bins are untouched
        in_bin = np.flatnonzero(bins == b)
        bin_objects, member_of = np.unique(objects[in_bin], return_inverse=True)
        members = [in_bin[member_of == k] for k in range(len(bin_objects))]
        tiebreak = rng.permutation(len(bin_objects))
        heap = [(len(m), int(tiebreak[k]), k) for k, m in enumerate(members)]
        heapq.heapify(heap)
        drawn = np.empty(thresh - count, dtype=np.int64)
        for i in range(thresh - count):
            n_obj, tie, k = heapq.heappop(heap)  # the object with the fewest samples so far
            drawn[i] = ids[members[k][rng.integers(len(members[k]))]]
            heapq.heappush(heap, (n_obj + 1, tie, k))
        extra.append(drawn)
    return np.concatenate([ids, *extra]) if extra else ids


def balance_split(
    samples: pd.DataFrame,
    split: Any,
    t_balance: float,
    seed: int = 0,
    n_bins: int = 9,
    label_constants: NormalisationConstants | None = None,
    balance_validation: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """Balanced training and validation ids of ``split``; the test ids are never touched.

    Returns ``(train_ids, val_ids)`` with duplicates. The test set is deliberately not an
    argument of the output: evaluation must use ``split.test_ids`` unchanged.
    """
    indexed = samples.set_index("sample_id", drop=False)
    out = []
    for k, name in enumerate(("train", "val")):
        ids = np.asarray(getattr(split, f"{name}_ids"))
        missing = np.setdiff1d(ids, indexed.index.to_numpy())
        if len(missing):
            raise ValueError(f"{len(missing)} {name} id(s) not in the samples table")
        if name == "val" and not balance_validation:
            out.append(ids.astype(np.int64))
            continue
        rows = indexed.loc[ids]
        out.append(balance_indices(rows, t_balance, n_bins, [seed, k], label_constants))
    train_ids, val_ids = out
    test_ids = np.asarray(split.test_ids)
    # Defensive: a Split already guarantees disjointness; a hand-made one might not.
    if np.isin(train_ids, test_ids).any() or np.isin(val_ids, test_ids).any():
        raise ValueError("train/validation ids overlap the test ids; refusing to balance")
    return train_ids, val_ids


def balance_summary(
    samples_subset: pd.DataFrame,
    balanced_ids: np.ndarray,
    n_bins: int = 9,
    label_constants: NormalisationConstants | None = None,
) -> pd.DataFrame:
    """Per bin: modulus range (Pa), samples before and after balancing, distinct objects."""
    c = label_constants or NormalisationConstants()
    bins, edges = label_bins(samples_subset["modulus_pa"].to_numpy(), n_bins, c)
    bin_of = pd.Series(bins, index=samples_subset["sample_id"].to_numpy())
    before = np.bincount(bins, minlength=n_bins)
    after = np.bincount(bin_of.loc[np.asarray(balanced_ids)].to_numpy(), minlength=n_bins)
    objects = [samples_subset["object"].to_numpy()[bins == b] for b in range(n_bins)]
    span = c.label_log10_max - c.label_log10_min
    return pd.DataFrame(
        {
            "lo_pa": 10.0 ** (edges[:-1] * span + c.label_log10_min),
            "hi_pa": 10.0 ** (edges[1:] * span + c.label_log10_min),
            "before": before,
            "after": after,
            "objects": [len(set(o)) for o in objects],
        }
    )
