"""Metrics of the paper and cheap extras, overall and per group, plus reference predictors.

See docs/protocol.md, section 6 "Metrics", for the definitions and the reference predictors.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import pandas as pd

from tactile_compliance.data.inputs import InputStrategy
from tactile_compliance.data.normalisation import (
    NormalisationConstants,
    denormalise_modulus,
    normalise_modulus,
)
from tactile_compliance.physics.contact import DEFAULT_GEL_MODULUS_PA

__all__ = [
    "METRIC_NAMES",
    "REFERENCE_NAMES",
    "SCALAR_GBR_PARAMS",
    "compute_metrics",
    "grouped_metrics",
    "log10_accuracy",
    "mae_decades",
    "nmse",
    "r2",
    "reference_predictions",
    "scalar_features",
    "scalar_reference",
    "soft_hard_labels",
    "within_half_decade",
]

#: Keys of :func:`compute_metrics` (besides ``n``), in report order.
METRIC_NAMES: tuple[str, ...] = (
    "log10_accuracy",
    "nmse",
    "r2",
    "mae_decades",
    "within_half_decade",
)
_TOL_DECADES = 1e-9

#: Names of the reference predictors, in report order (``scalar_gbr`` only for strategies
#: with scalar inputs).
REFERENCE_NAMES: tuple[str, ...] = ("median", "analytical", "scalar_gbr")
#: Hyperparameters of the scalar reference: scikit-learn's defaults, written out so that a
#: new scikit-learn release cannot change the reference silently, with early stopping off
#: (docs/protocol.md, section 6).
SCALAR_GBR_PARAMS: dict[str, Any] = {
    "loss": "squared_error",
    "learning_rate": 0.1,
    "max_iter": 100,
    "max_leaf_nodes": 31,
    "min_samples_leaf": 20,
    "l2_regularization": 0.0,
    "max_bins": 255,
    "early_stopping": False,
}


def _pair(true_pa: Any, pred_pa: Any) -> tuple[np.ndarray, np.ndarray]:
    t = np.asarray(true_pa, dtype=np.float64).reshape(-1)
    p = np.asarray(pred_pa, dtype=np.float64).reshape(-1)
    if t.shape != p.shape:
        raise ValueError(f"true and predicted moduli differ in length: {t.size} vs {p.size}")
    if t.size == 0:
        raise ValueError("no samples to evaluate")
    for name, v in (("true", t), ("predicted", p)):
        if not np.all(np.isfinite(v)) or np.any(v <= 0):
            raise ValueError(f"{name} moduli must be finite and positive (Pa)")
    return t, p


def _log_error(true_pa: Any, pred_pa: Any) -> np.ndarray:
    t, p = _pair(true_pa, pred_pa)
    return np.log10(p) - np.log10(t)


def log10_accuracy(true_pa: Any, pred_pa: Any, tolerance_decades: float = 1.0) -> float:
    """Share of predictions within ``tolerance_decades`` of the truth (|d| <= 1 by default)."""
    d = np.abs(_log_error(true_pa, pred_pa))
    return float(np.mean(d <= tolerance_decades + _TOL_DECADES))


def within_half_decade(true_pa: Any, pred_pa: Any) -> float:
    """Share of predictions within half a decade (a factor of about 3.16)."""
    return log10_accuracy(true_pa, pred_pa, 0.5)


def mae_decades(true_pa: Any, pred_pa: Any) -> float:
    """Mean absolute error in decades: mean |log10 E_hat - log10 E|."""
    return float(np.mean(np.abs(_log_error(true_pa, pred_pa))))


def nmse(true_pa: Any, pred_pa: Any, c: NormalisationConstants | None = None) -> float:
    """Mean squared error of the *normalised* labels (the paper's N-MSE)."""
    t, p = _pair(true_pa, pred_pa)
    return float(np.mean((normalise_modulus(p, c) - normalise_modulus(t, c)) ** 2))


#: True labels whose normalised values spread less than this (standard deviation, on
#: the [0, 1] label scale: 1e-9 of the label range) are all equal: their R^2 is undefined.
_R2_MIN_STD = 1e-9


def r2(true_pa: Any, pred_pa: Any, c: NormalisationConstants | None = None) -> float:
    """Coefficient of determination on the normalised labels; NaN when the true moduli are
    all equal (nothing to explain: float rounding of equal labels would otherwise give
    values like -1.5e30)."""
    t, p = _pair(true_pa, pred_pa)
    y, y_hat = normalise_modulus(t, c), normalise_modulus(p, c)
    if float(np.std(y)) <= _R2_MIN_STD:
        return math.nan
    ss_res = float(np.sum((y_hat - y) ** 2))
    ss_tot = float(np.sum((y - y.mean()) ** 2))
    return 1.0 - ss_res / ss_tot


def compute_metrics(
    true_pa: Any, pred_pa: Any, c: NormalisationConstants | None = None
) -> dict[str, float]:
    """All metrics for one set of predictions: ``n`` plus :data:`METRIC_NAMES`."""
    t, p = _pair(true_pa, pred_pa)
    return {
        "n": int(t.size),
        "log10_accuracy": log10_accuracy(t, p),
        "nmse": nmse(t, p, c),
        "r2": r2(t, p, c),
        "mae_decades": mae_decades(t, p),
        "within_half_decade": within_half_decade(t, p),
    }


def soft_hard_labels(modulus_pa: Any, threshold_pa: float = DEFAULT_GEL_MODULUS_PA) -> np.ndarray:
    """``"soft"`` below ``threshold_pa`` (the gel's 0.275 MPa by default), else ``"hard"``."""
    e = np.asarray(modulus_pa, dtype=float)
    return np.where(e < threshold_pa, "soft", "hard")


def grouped_metrics(
    df: pd.DataFrame,
    by: str | Sequence[str] = ("material", "shape", "soft_hard"),
    c: NormalisationConstants | None = None,
    threshold_pa: float = DEFAULT_GEL_MODULUS_PA,
) -> pd.DataFrame:
    """Metrics overall and per group, one row per (grouping, group).

    Args:
        df: one row per prediction with ``modulus_pa`` and ``pred_pa`` and the grouping
            columns; ``soft_hard`` is derived from the true modulus when absent.
        by: grouping column(s), e.g. ``"material"``, ``"shape"``, ``"soft_hard"``.
        c: normalisation constants for N-MSE / R^2.
        threshold_pa: soft/hard boundary (Pa).

    Returns:
        Columns ``grouping, group, n`` and :data:`METRIC_NAMES`; the first row is
        ``("all", "all")``. Within a grouping, groups are sorted by name.
    """
    groupings = [by] if isinstance(by, str) else list(by)
    missing = [col for col in ("modulus_pa", "pred_pa") if col not in df.columns]
    if missing:
        raise ValueError(f"grouped_metrics needs column(s) {missing}; has {list(df.columns)}")
    data = df
    if "soft_hard" in groupings and "soft_hard" not in df.columns:
        data = df.assign(soft_hard=soft_hard_labels(df["modulus_pa"].to_numpy(), threshold_pa))
    overall = compute_metrics(data["modulus_pa"], data["pred_pa"], c)
    rows = [{"grouping": "all", "group": "all", **overall}]
    for grouping in groupings:
        if grouping not in data.columns:
            raise ValueError(f"cannot group by {grouping!r}: no such column")
        for group, part in data.groupby(grouping, sort=True):
            metrics = compute_metrics(part["modulus_pa"], part["pred_pa"], c)
            rows.append({"grouping": grouping, "group": str(group), **metrics})
    return pd.DataFrame(rows)


def scalar_features(
    samples: pd.DataFrame,
    inputs: InputStrategy | str,
    c: NormalisationConstants | None = None,
) -> tuple[np.ndarray, tuple[str, ...]]:
    """The scalar inputs of ``inputs`` as a feature matrix, and the column names.

    Each scalar input's store columns (``data.inputs.INPUTS``) in its physical unit (N,
    m), log10 of the clamped values for inputs that span decades (the estimates, Pa), as
    the strategy has them; NaN stays NaN. Image has no scalar inputs: an ``(n, 0)`` matrix.
    """
    c = c or NormalisationConstants()
    strategy = InputStrategy.parse(inputs)
    names = tuple(column for spec in strategy.scalars for column in spec.columns)
    in_decades = {column for spec in strategy.scalars if spec.decades for column in spec.columns}
    missing = [column for column in names if column not in samples.columns]
    if missing:
        raise ValueError(f"the {strategy} scalar reference needs column(s) {missing}")
    # A copy (np.array, not to_numpy): pandas may hand out a read-only view of its data.
    values = np.array(samples[list(names)], dtype=np.float64).reshape(len(samples), len(names))
    for index, column in enumerate(names):
        if column in in_decades:
            lo, hi = c.estimate_clamp_pa
            values[:, index] = np.log10(np.clip(values[:, index], lo, hi))  # NaN stays NaN
    return values, names


def scalar_reference(
    train_samples: pd.DataFrame,
    test_samples: pd.DataFrame,
    inputs: InputStrategy | str,
    c: NormalisationConstants | None = None,
    seed: int = 0,
) -> np.ndarray | None:
    """Gradient-boosted trees on the scalar inputs only: predictions (Pa) for ``test_samples``.

    A ``HistGradientBoostingRegressor`` (:data:`SCALAR_GBR_PARAMS`, ``random_state=seed``)
    fitted on ``train_samples`` alone, target the normalised label; None for Image.
    """
    c = c or NormalisationConstants()
    strategy = InputStrategy.parse(inputs)
    if not strategy.scalars:
        return None
    if len(train_samples) == 0:
        raise ValueError("the training set is empty; nothing to fit the scalar reference on")
    from sklearn.ensemble import HistGradientBoostingRegressor
    from threadpoolctl import threadpool_limits

    x_train, _ = scalar_features(train_samples, strategy, c)
    x_test, _ = scalar_features(test_samples, strategy, c)
    y_train = normalise_modulus(train_samples["modulus_pa"].to_numpy(dtype=np.float64), c)
    model = HistGradientBoostingRegressor(**SCALAR_GBR_PARAMS, random_state=int(seed))
    # One OpenMP thread: grid workers already run one torch thread per core, and a
    # few thousand rows take well under a second single-threaded.
    with threadpool_limits(limits=1, user_api="openmp"):
        model.fit(x_train, y_train)
        predicted = model.predict(x_test) if len(test_samples) else np.empty(0)
    return np.asarray(denormalise_modulus(predicted.astype(np.float64), c), dtype=np.float64)


def reference_predictions(
    train_samples: pd.DataFrame,
    test_samples: pd.DataFrame,
    c: NormalisationConstants | None = None,
    *,
    inputs: InputStrategy | str | None = None,
    seed: int = 0,
) -> dict[str, np.ndarray]:
    """Predictions (Pa) of the reference predictors for ``test_samples``, in row order.

    ``median``, ``analytical`` and, with ``inputs`` given and not Image, ``scalar_gbr``;
    only ``train_samples`` are fitted on, and no test label is read (docs/protocol.md, 6).
    """
    c = c or NormalisationConstants()
    if len(train_samples) == 0:
        raise ValueError("the training set is empty; no median to predict")
    median = float(np.median(train_samples["modulus_pa"].to_numpy(dtype=float)))
    n = len(test_samples)
    analytical = np.full(n, np.nan)
    for column in ("hertz_estimate_pa", "elastic_estimate_pa"):  # later wins: elastic first
        if column in test_samples.columns:
            values = test_samples[column].to_numpy(dtype=float)
            ok = np.isfinite(values)
            analytical[ok] = values[ok]
    analytical[~np.isfinite(analytical)] = median
    lo, hi = c.estimate_clamp_pa
    out = {"median": np.full(n, median), "analytical": np.clip(analytical, lo, hi)}
    if inputs is not None:
        scalar = scalar_reference(train_samples, test_samples, inputs, c, seed)
        if scalar is not None:
            out["scalar_gbr"] = scalar
    return out
