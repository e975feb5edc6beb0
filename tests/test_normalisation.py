"""Normalisation: hand-computed values, round trips, numpy/torch agreement, constants I/O."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from tactile_compliance.data.normalisation import (
    NormalisationConstants,
    denormalise_images,
    denormalise_modulus,
    normalise_estimates,
    normalise_force,
    normalise_images,
    normalise_modulus,
    normalise_width,
)

C = NormalisationConstants()
SHORE = NormalisationConstants.for_shore_data()


def test_label_hand_values():
    assert normalise_modulus(1e3) == pytest.approx(0.0)
    assert normalise_modulus(1e12) == pytest.approx(1.0)
    assert normalise_modulus(10**7.5) == pytest.approx(0.5)
    assert normalise_modulus(1e4, C) == pytest.approx(1 / 9)
    # Shore data: [1e3, 1e7] -> 1e5 is the middle, 1e4 a quarter.
    assert normalise_modulus(1e5, SHORE) == pytest.approx(0.5)
    assert normalise_modulus(1e4, SHORE) == pytest.approx(0.25)
    assert denormalise_modulus(0.5, SHORE) == pytest.approx(1e5)
    # Out of range is not clipped (stays invertible).
    assert normalise_modulus(1e2) == pytest.approx(-1 / 9)


@settings(max_examples=200, deadline=None)
@given(st.floats(-0.5, 1.5))
def test_label_roundtrip_from_normalised(y):
    for c in (C, SHORE):
        assert normalise_modulus(denormalise_modulus(y, c), c) == pytest.approx(y, abs=1e-12)


@settings(max_examples=200, deadline=None)
@given(st.floats(1.0, 15.0))
def test_label_roundtrip_from_modulus(log10_e):
    e = 10.0**log10_e
    assert denormalise_modulus(normalise_modulus(e)) == pytest.approx(e, rel=1e-12)


def test_arrays_and_tensors_agree():
    e = np.array([1e3, 3.3e5, 2e11])
    y_np = normalise_modulus(e)
    y_t = normalise_modulus(torch.tensor(e, dtype=torch.float64))
    assert isinstance(y_np, np.ndarray) and isinstance(y_t, torch.Tensor)
    np.testing.assert_allclose(y_t.numpy(), y_np, rtol=1e-12)
    back = denormalise_modulus(torch.tensor(y_np))
    np.testing.assert_allclose(back.numpy(), e, rtol=1e-12)


def test_non_positive_modulus_is_rejected():
    with pytest.raises(ValueError, match="positive"):
        normalise_modulus(np.array([1e5, 0.0]))
    assert math.isnan(normalise_modulus(float("nan")))


def test_estimates_clamp_and_scale():
    got = normalise_estimates(np.array([1e8, 1e1, 1e15, -5.0, np.nan, 1e2, 1e14]))
    np.testing.assert_allclose(got[:4], [0.5, 0.0, 1.0, 0.0])
    assert np.isnan(got[4])
    np.testing.assert_allclose(got[5:], [0.0, 1.0])
    t = normalise_estimates(torch.tensor([[1e8, 1e20]], dtype=torch.float64))
    np.testing.assert_allclose(t.numpy(), [[0.5, 1.0]])


def test_force_and_width():
    assert normalise_force(30.0) == pytest.approx(0.5)
    assert normalise_width(0.04) == pytest.approx(0.5)
    np.testing.assert_allclose(normalise_force(np.array([0.0, 60.0, 120.0])), [0, 1, 2])
    t = normalise_width(torch.tensor([0.08]))
    assert isinstance(t, torch.Tensor) and t.item() == pytest.approx(1.0)


def test_images_channels_last_numpy():
    mean = np.array(C.image_mean, dtype=np.float32)
    std = np.array(C.image_std, dtype=np.float32)
    x = np.broadcast_to(mean, (2, 3, 4, 5, 3)).copy()
    x[0, 0, 0, 0] = mean + std  # one pixel one std above the mean
    out = normalise_images(x)
    assert out.dtype == np.float32 and out.shape == x.shape
    np.testing.assert_allclose(out[0, 0, 0, 0], [1, 1, 1], rtol=1e-5)
    np.testing.assert_allclose(out[1], 0, atol=1e-5)
    np.testing.assert_allclose(denormalise_images(out), x, rtol=1e-6)


def test_images_channels_first_torch():
    x = torch.rand(2, 3, 3, 4, 5)
    out = normalise_images(x, C, channel_axis=-3)
    expected = (x[:, :, 1] - C.image_mean[1]) / C.image_std[1]  # green channel
    torch.testing.assert_close(out[:, :, 1], expected)
    torch.testing.assert_close(denormalise_images(out, C, channel_axis=-3), x)


def test_images_errors():
    with pytest.raises(ValueError, match="3 channels"):
        normalise_images(np.zeros((2, 4, 5, 3)), C, channel_axis=1)
    with pytest.raises(ValueError, match="uint8"):
        normalise_images(np.zeros((2, 4, 5, 3), dtype=np.uint8))


def test_constants_roundtrip_through_json():
    c = NormalisationConstants.from_label_range((1e3, 1e7), force_scale_n=50.0)
    restored = NormalisationConstants.from_dict(json.loads(json.dumps(c.to_dict())))
    assert restored == c
    assert restored.label_range_pa == pytest.approx((1e3, 1e7))
    assert restored.force_scale_n == 50.0
    assert SHORE.label_log10_min == 3.0 and SHORE.label_log10_max == 7.0


def test_constants_validation():
    with pytest.raises(ValueError, match="unknown"):
        NormalisationConstants.from_dict({"label_log10_min": 3.0, "bogus": 1})
    with pytest.raises(ValueError, match="exceed"):
        NormalisationConstants(label_log10_min=5.0, label_log10_max=5.0)
    with pytest.raises(ValueError, match="0 < min < max"):
        NormalisationConstants.from_label_range((1e7, 1e3))
    with pytest.raises(ValueError, match="positive"):
        NormalisationConstants(image_std=(0.1, 0.0, 0.1))
