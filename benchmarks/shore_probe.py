"""Do Shore-hardness press videos carry hardness? Trees on hand-made image features.

    python benchmarks/shore_probe.py STORE [--folds 5]

A research probe, not a benchmark: it tells "the images carry no information about
hardness" apart from "the network does not extract it". For every press of a Yuan-style
store (frames: first, midway, brightest) it takes the per-pixel max-channel
``|frame_k - frame_0|`` for k = 1, 2 and describes each by its area share above 3, 6,
12 and 24 grey levels, its mean and its maximum, plus the mean brightness of the three
frames (15 features). Gradient-boosted trees (scikit-learn) are scored by k-fold
cross-validation, once over random folds of presses (the paper's random split) and once
grouped by object, with the paper's N-MSE and R^2 on labels normalised over
[1e3, 1e7] Pa, next to the median predictor's N-MSE. Needs scikit-learn; reads the
whole store into memory (meant for a few hundred presses).
"""

from __future__ import annotations

import argparse

import numpy as np
from sklearn.ensemble import HistGradientBoostingRegressor
from sklearn.model_selection import GroupKFold, KFold

from tactile_compliance.data.normalisation import NormalisationConstants
from tactile_compliance.data.store import GraspStore
from tactile_compliance.runs.metrics import nmse, r2

THRESHOLDS = (3, 6, 12, 24)
"""Grey-level thresholds of the imprint's area shares [grey levels]."""


def press_features(frames: np.ndarray) -> np.ndarray:
    """Hand-made features (n, 15) of press frames (n, 3, H, W, C) uint8."""
    frames = frames.astype(np.float32)
    columns = []
    for k in (1, 2):
        change = np.abs(frames[:, k] - frames[:, 0]).max(axis=-1).reshape(len(frames), -1)
        columns += [(change > t).mean(axis=1) for t in THRESHOLDS]
        columns += [change.mean(axis=1), change.max(axis=1)]
    columns += [frames[:, k].reshape(len(frames), -1).mean(axis=1) for k in range(3)]
    return np.stack(columns, axis=1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("store", help="GraspStore imported with `tactile-compliance import yuan`")
    parser.add_argument("--folds", type=int, default=5)
    args = parser.parse_args()
    store = GraspStore.open(args.store)
    x = press_features(store.read_block(0, len(store)))
    modulus_pa = store.moduli_pa()
    constants = NormalisationConstants.for_shore_data()
    median_pa = np.full_like(modulus_pa, np.median(modulus_pa))
    print(f"{len(store)} presses, {store.samples['object'].nunique()} objects")
    print(f"median predictor: N-MSE {nmse(modulus_pa, median_pa, constants):.4f}")
    splits = (
        ("random folds of presses", KFold(args.folds, shuffle=True, random_state=0), None),
        ("folds grouped by object", GroupKFold(args.folds), store.samples["object"].to_numpy()),
    )
    target = np.log10(modulus_pa)
    for name, folds, groups in splits:
        predicted = np.zeros_like(target)
        for train, test in folds.split(x, target, groups):
            model = HistGradientBoostingRegressor(random_state=0, min_samples_leaf=5)
            predicted[test] = model.fit(x[train], target[train]).predict(x[test])
        predicted_pa = 10.0**predicted
        print(
            f"{name}: N-MSE {nmse(modulus_pa, predicted_pa, constants):.4f}, "
            f"R^2 {r2(modulus_pa, predicted_pa, constants):.3f}"
        )


if __name__ == "__main__":
    main()
