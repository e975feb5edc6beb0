"""Augmentation: same parameters on all frames, probability, eval identity, seeding."""

from __future__ import annotations

import math

import pytest
import torch

from tactile_compliance.config import AugmentationConfig
from tactile_compliance.data import augment
from tactile_compliance.data.augment import GraspAugmentation


def repeated_frames(batch: int = 8, h: int = 12, w: int = 16, seed: int = 0) -> torch.Tensor:
    """A batch whose three frames are identical copies (B, 3, 3, H, W) in [0, 1]."""
    g = torch.Generator().manual_seed(seed)
    one = torch.rand(batch, 1, 3, h, w, generator=g)
    return one.repeat(1, 3, 1, 1, 1)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_identical_frames_stay_identical(seed):
    # Without pixel noise every random parameter (flips, jitter) is shared by the frames.
    aug = GraspAugmentation(probability=1.0, noise_std=0.0, seed=seed)
    x = repeated_frames(seed=seed)
    y = aug(x)
    assert y.shape == x.shape
    assert not torch.equal(y, x)  # something happened
    torch.testing.assert_close(y[:, 0], y[:, 1], rtol=0, atol=0)
    torch.testing.assert_close(y[:, 0], y[:, 2], rtol=0, atol=0)
    # ... while different samples of the batch got different parameters.
    assert not torch.allclose(y[0] - x[0], y[1] - x[1])


def test_noise_is_independent_per_frame_with_sigma_15_over_255():
    aug = GraspAugmentation(
        probability=1.0, hflip=0, vflip=0, brightness=0, contrast=0, saturation=0, hue=0, seed=0
    )
    x = torch.full((4, 3, 3, 32, 32), 0.5)
    y = aug(x)
    sigma = 15 / 255
    assert (y - x).std().item() == pytest.approx(sigma, rel=0.05)
    # Difference of two frames: independent noise -> std sqrt(2) sigma (not 0).
    assert (y[:, 0] - y[:, 1]).std().item() == pytest.approx(math.sqrt(2) * sigma, rel=0.05)


def test_flip_only_pipeline_flips_all_frames_the_same_way():
    aug = GraspAugmentation(
        probability=1.0,
        hflip=1.0,
        vflip=0,
        brightness=0,
        contrast=0,
        saturation=0,
        hue=0,
        noise_std=0.0,
    )
    x = torch.rand(2, 3, 3, 5, 7)  # frames differ: the flip must act on each frame
    torch.testing.assert_close(aug(x), torch.flip(x, dims=[-1]), rtol=0, atol=0)


def test_probability_zero_and_eval_mode_are_identity():
    x = torch.rand(4, 3, 3, 8, 8)
    assert torch.equal(GraspAugmentation(probability=0.0, seed=0)(x), x)
    aug = GraspAugmentation(probability=1.0, seed=0)
    aug.eval()
    assert torch.equal(aug(x), x)
    disabled = GraspAugmentation.from_config(AugmentationConfig(enabled=False))
    assert torch.equal(disabled(x), x)


def test_pipeline_applied_with_probability_per_sample():
    aug = GraspAugmentation(probability=0.9, seed=3)
    x = torch.rand(300, 3, 3, 4, 4)
    y = aug(x)
    changed = (y != x).flatten(1).any(dim=1)
    # Binomial(300, 0.9): mean 270, sd 5.2.
    assert 250 <= int(changed.sum()) <= 290
    assert ((y >= 0) & (y <= 1)).all()


def test_seeded_and_does_not_touch_the_global_rng():
    x = torch.rand(6, 3, 3, 8, 8)
    torch.manual_seed(123)
    a = GraspAugmentation(seed=5)(x)
    after_a = torch.rand(1)
    torch.manual_seed(123)
    b = GraspAugmentation(seed=5)(x)
    after_b = torch.rand(1)
    torch.manual_seed(123)
    expected_next = torch.rand(1)
    torch.testing.assert_close(a, b, rtol=0, atol=0)
    assert after_a == after_b == expected_next
    c = GraspAugmentation(seed=6)(x)
    assert not torch.equal(a, c)
    # Successive calls of one module draw new parameters.
    aug = GraspAugmentation(seed=5)
    assert not torch.equal(aug(x), aug(x))


@pytest.mark.parametrize("chunk_pixels", [1, 3 * 12 * 16 * 3])
def test_chunked_augmentation_keeps_per_sample_parameters(monkeypatch, chunk_pixels):
    # Full-size frames are augmented a few samples at a time (1 and 3 per chunk here):
    # frames of a sample still share their parameters, samples still differ, and the
    # samples the probability skipped come back untouched.
    monkeypatch.setattr(augment, "_CHUNK_PIXELS", chunk_pixels)
    x = repeated_frames(batch=40, seed=4)
    aug = GraspAugmentation(probability=0.5, noise_std=0.0, seed=4)
    y = aug(x)
    assert augment._chunk_samples(x) == max(1, chunk_pixels // (3 * 12 * 16))
    torch.testing.assert_close(y[:, 0], y[:, 2], rtol=0, atol=0)
    changed = (y != x).flatten(1).any(dim=1)
    assert 8 <= int(changed.sum()) <= 32
    assert torch.equal(y[~changed], x[~changed])
    moved = (y - x)[changed].flatten(1)
    assert len({tuple(row[:20].tolist()) for row in moved}) == len(moved)
    # Same seed, same batches, whatever the chunking.
    torch.testing.assert_close(GraspAugmentation(probability=0.5, noise_std=0.0, seed=4)(x), y)


def test_rejects_wrong_layout():
    with pytest.raises(ValueError, match=r"\(B, T, 3, H, W\)"):
        GraspAugmentation()(torch.rand(2, 3, 8, 8, 3))
    with pytest.raises(ValueError, match="probability"):
        GraspAugmentation(probability=1.5)
