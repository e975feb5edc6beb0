"""Metrics against hand-computed values; grouped metrics; reference predictors."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from tactile_compliance.data.normalisation import NormalisationConstants
from tactile_compliance.runs.metrics import (
    compute_metrics,
    grouped_metrics,
    log10_accuracy,
    mae_decades,
    nmse,
    r2,
    reference_predictions,
    scalar_features,
    scalar_reference,
    soft_hard_labels,
    within_half_decade,
)

# Errors in decades: +1, +2, 0, -1.
TRUE = np.array([1e3, 1e6, 1e9, 1e12])
PRED = np.array([1e4, 1e8, 1e9, 1e11])


def test_hand_computed_values():
    assert log10_accuracy(TRUE, PRED) == pytest.approx(3 / 4)  # |d| <= 1 for +1, 0, -1
    assert within_half_decade(TRUE, PRED) == pytest.approx(1 / 4)  # only the exact one
    assert mae_decades(TRUE, PRED) == pytest.approx((1 + 2 + 0 + 1) / 4)
    # N-MSE on y = (log10 E - 3) / 9: errors d / 9 -> (1 + 4 + 0 + 1) / 81 / 4.
    assert nmse(TRUE, PRED) == pytest.approx(6 / 324)
    # y = 0, 1/3, 2/3, 1; ss_tot = 5/9, ss_res = 6/81 -> R^2 = 1 - 2/15.
    assert r2(TRUE, PRED) == pytest.approx(13 / 15)
    m = compute_metrics(TRUE, PRED)
    assert m["n"] == 4
    assert m == {
        "n": 4,
        "log10_accuracy": pytest.approx(0.75),
        "nmse": pytest.approx(6 / 324),
        "r2": pytest.approx(13 / 15),
        "mae_decades": pytest.approx(1.0),
        "within_half_decade": pytest.approx(0.25),
    }


def test_nmse_uses_the_normalised_label():
    # Two decades of error: (2/9)^2 on [1e3, 1e12], (2/4)^2 on the Shore range [1e3, 1e7];
    # never 4 (the squared error in raw decades) nor anything in Pa.
    assert nmse([1e3], [1e5]) == pytest.approx((2 / 9) ** 2)
    shore = NormalisationConstants.for_shore_data()
    assert nmse([1e3], [1e5], shore) == pytest.approx(0.25)
    assert compute_metrics([1e3, 1e4], [1e5, 1e4], shore)["nmse"] == pytest.approx(0.125)


def test_exactly_one_decade_counts_as_inside():
    assert log10_accuracy([1e5, 2e5], [1e6, 2e4]) == 1.0
    assert log10_accuracy([1e5], [1.0001e6]) == 0.0
    assert within_half_decade([1e5], [10**5.5]) == 1.0


def test_r2_edge_cases():
    # Equal true labels leave nothing to explain: undefined, even for a perfect fit (and
    # never the -1e28 that float rounding of equal labels gave; issue 43).
    assert math.isnan(r2([1e5, 1e5], [1e5, 1e5]))
    assert math.isnan(r2([1e5, 1e5], [1e6, 1e5]))
    assert math.isnan(r2([1.3e5] * 5, [1.43e5] + [1.17e5] * 4))
    # R^2 does not depend on the label range (affine normalisation).
    shore = NormalisationConstants.for_shore_data()
    assert r2(TRUE, PRED, shore) == pytest.approx(r2(TRUE, PRED))
    # Predicting the mean label gives 0; worse than the mean is negative.
    assert r2([1e3, 1e5], [1e4, 1e4]) == pytest.approx(0.0)
    assert r2([1e3, 1e5], [1e5, 1e3]) < 0


def test_invalid_inputs():
    with pytest.raises(ValueError, match="length"):
        compute_metrics([1e3, 1e4], [1e3])
    with pytest.raises(ValueError, match="positive"):
        compute_metrics([1e3], [0.0])
    with pytest.raises(ValueError, match="finite"):
        compute_metrics([np.nan], [1e3])
    with pytest.raises(ValueError, match="no samples"):
        compute_metrics([], [])


def test_grouped_metrics_by_material_and_soft_hard():
    df = pd.DataFrame(
        {
            "modulus_pa": [1e4, 1e5, 1e9, 1e10],
            "pred_pa": [1e4, 1e7, 1e9, 1e12],  # errors 0, 2, 0, 2 decades
            "material": ["Rubber", "Rubber", "Metal", "Metal"],
        }
    )
    table = grouped_metrics(df, by=["material", "soft_hard"])
    assert table.iloc[0][["grouping", "group", "n"]].tolist() == ["all", "all", 4]
    rows = table.set_index(["grouping", "group"])
    assert rows.loc[("material", "Rubber"), "log10_accuracy"] == pytest.approx(0.5)
    assert rows.loc[("material", "Metal"), "mae_decades"] == pytest.approx(1.0)
    assert rows.loc[("material", "Metal"), "nmse"] == pytest.approx((4 / 81) / 2)
    # Soft/hard at the gel's 0.275 MPa: 1e4 and 1e5 are soft.
    assert rows.loc[("soft_hard", "soft"), "n"] == 2
    assert rows.loc[("soft_hard", "hard"), "n"] == 2
    assert list(table.columns[:3]) == ["grouping", "group", "n"]
    with pytest.raises(ValueError, match="shape"):
        grouped_metrics(df, by="shape")


def test_soft_hard_labels_boundary():
    assert soft_hard_labels([2.74e5, 2.75e5, 1e3]).tolist() == ["soft", "hard", "soft"]
    assert soft_hard_labels([5e7], threshold_pa=1e8).tolist() == ["soft"]


def test_reference_predictions():
    train = pd.DataFrame({"modulus_pa": [1e3, 1e5, 1e9, 1e11, 1e6]})
    test = pd.DataFrame(
        {
            "modulus_pa": [1e4, 1e5, 1e6, 1e7],
            "elastic_estimate_pa": [2e4, np.nan, np.nan, 1e16],
            "hertz_estimate_pa": [9e9, 3e5, np.nan, 1e5],
        }
    )
    preds = reference_predictions(train, test)
    np.testing.assert_allclose(preds["median"], [1e6] * 4)
    # elastic; hertz fallback; training median when both missing; clamp to 1e14.
    np.testing.assert_allclose(preds["analytical"], [2e4, 3e5, 1e6, 1e14])
    metrics = compute_metrics(test["modulus_pa"], preds["median"])
    assert metrics["log10_accuracy"] == pytest.approx(3 / 4)
    with pytest.raises(ValueError, match="empty"):
        reference_predictions(train.iloc[:0], test)


def _scalar_samples() -> pd.DataFrame:
    return pd.DataFrame(
        {
            "modulus_pa": [1e4, 1e6, 1e8, 1e10],
            **{f"force_n_{i}": [1.0 + i, 2.0, 3.0, 4.0] for i in range(3)},
            **{f"width_m_{i}": [0.05, 0.04 - 0.001 * i, 0.03, 0.02] for i in range(3)},
            "elastic_estimate_pa": [1e5, -3.0, np.nan, 1e16],
            "hertz_estimate_pa": [2e5, 1e7, 1e9, np.nan],
        }
    )


def test_scalar_features_per_strategy():
    samples = _scalar_samples()
    assert scalar_features(samples, "Image")[0].shape == (4, 0)
    x, names = scalar_features(samples, "ImageF")
    assert names == ("force_n_0", "force_n_1", "force_n_2")
    np.testing.assert_array_equal(x[:, 1], samples["force_n_1"])
    x, names = scalar_features(samples, "image_fw")  # the one vocabulary's spellings
    assert names[3:] == ("width_m_0", "width_m_1", "width_m_2") and x.shape == (4, 6)
    x, names = scalar_features(samples, "ALL")
    assert names[-2:] == ("elastic_estimate_pa", "hertz_estimate_pa")
    # log10 of the estimate clamped to [1e2, 1e14] Pa (as the models see it); NaN stays NaN.
    np.testing.assert_allclose(x[:, -2], [5.0, 2.0, np.nan, 14.0])
    np.testing.assert_allclose(x[:, -1], [np.log10(2e5), 7.0, 9.0, np.nan])
    assert np.isfinite(samples["elastic_estimate_pa"].iloc[0])  # the input is not modified
    with pytest.raises(ValueError, match="width_m_0"):
        scalar_features(samples.drop(columns="width_m_0"), "ALL")


def test_scalar_reference_predicts_moduli_in_pa():
    samples = _scalar_samples()
    assert scalar_reference(samples, samples, "Image") is None
    predicted = scalar_reference(samples, samples, "ALL", seed=1)
    assert predicted.shape == (4,) and np.all(np.isfinite(predicted)) and np.all(predicted > 0)
    # Four rows are fewer than a leaf's minimum: the fit is the mean normalised label,
    # i.e. the geometric mean of the training moduli.
    np.testing.assert_allclose(predicted, 1e7)
    with pytest.raises(ValueError, match="empty"):
        scalar_reference(samples.iloc[:0], samples, "ALL")
