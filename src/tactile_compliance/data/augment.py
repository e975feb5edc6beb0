"""Training augmentation of grasp batches: one set of flips and colour jitter per sample,
shared by its three frames, plus per-pixel noise; the identity in eval mode.

See docs/protocol.md, "5. Augmentation (training only)".
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Any

import kornia.augmentation as kaug
import torch
from torch import nn

__all__ = ["GraspAugmentation"]


# kornia's colour jitter makes about a dozen temporaries of its input's size. On a whole
# batch of full-size frames (32 x 3 x 250 x 350) those are 100 MB each: 1.1 s and +1.1 GB
# per batch, and glibc keeps much of it after the batch. In chunks of at most this many
# pixels the temporaries stay in cache: 0.55 s and +0.2 GB (benchmarks/bench_training.py).
_CHUNK_PIXELS = 2**18


def _chunk_samples(frames: torch.Tensor) -> int:
    """How many samples of ``frames`` (B, T, C, H, W) to augment per kornia call."""
    pixels_per_sample = frames.shape[1] * frames.shape[3] * frames.shape[4]
    return max(1, _CHUNK_PIXELS // pixels_per_sample)


class GraspAugmentation(nn.Module):
    """Augment a batch of grasps ``(B, T frames, 3, H, W)`` with values in [0, 1].

    Args:
        probability: per-sample probability of applying the whole pipeline (paper 0.9);
            the flip probabilities apply given that.
        brightness, contrast, saturation, hue: ``ColorJitter`` ranges (torchvision semantics).
        noise_std: sigma of the additive Gaussian noise, image units (15/255 = 15 grey levels).
        seed: seed of the module's own generator (same seed -> same augmented batches;
            the global torch RNG is neither used nor disturbed); None uses the global
            torch RNG.
    """

    def __init__(
        self,
        probability: float = 0.9,
        hflip: float = 0.5,
        vflip: float = 0.5,
        brightness: float = 0.4,
        contrast: float = 0.4,
        saturation: float = 0.5,
        hue: float = 0.3,
        noise_std: float = 15 / 255,
        seed: int | None = None,
    ) -> None:
        super().__init__()
        if not 0.0 <= probability <= 1.0:
            raise ValueError(f"probability must be in [0, 1], got {probability}")
        if noise_std < 0:
            raise ValueError(f"noise_std must be >= 0, got {noise_std}")
        self.probability = float(probability)
        self.noise_std = float(noise_std)
        augmentations: list[nn.Module] = []
        if hflip > 0:
            augmentations.append(kaug.RandomHorizontalFlip(p=hflip))
        if vflip > 0:
            augmentations.append(kaug.RandomVerticalFlip(p=vflip))
        if max(brightness, contrast, saturation, hue) > 0:
            augmentations.append(
                kaug.ColorJitter(
                    brightness=brightness, contrast=contrast, saturation=saturation, hue=hue, p=1.0
                )
            )
        # same_on_frame=True: one parameter set per sample, shared by its frames.
        self.frames_pipeline = (
            kaug.VideoSequential(*augmentations, data_format="BTCHW", same_on_frame=True)
            if augmentations
            else None
        )
        #: The generator of the random parameters (None: torch's global one). A resumed
        #: run restores its state to draw the same augmentations as an uninterrupted run.
        self.generator = None if seed is None else torch.Generator().manual_seed(int(seed))

    @classmethod
    def from_config(cls, cfg: Any, seed: int | None = None) -> GraspAugmentation:
        """Build from an ``AugmentationConfig`` (probability forced to 0 when disabled)."""
        return cls(
            probability=cfg.probability if cfg.enabled else 0.0,
            hflip=cfg.hflip,
            vflip=cfg.vflip,
            brightness=cfg.brightness,
            contrast=cfg.contrast,
            saturation=cfg.saturation,
            hue=cfg.hue,
            noise_std=cfg.noise_std,
            seed=seed,
        )

    @contextlib.contextmanager
    def _rng(self, device: torch.device) -> Iterator[None]:
        if self.generator is None:
            yield
            return
        call_seed = int(torch.randint(0, 2**62, (1,), generator=self.generator))
        devices = [device.index or 0] if device.type == "cuda" else []
        with torch.random.fork_rng(devices=devices):
            torch.manual_seed(call_seed)
            yield

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        """Augmented copy of ``frames`` (B, T, 3, H, W); the identity in eval mode."""
        if frames.ndim != 5 or frames.shape[2] != 3:
            raise ValueError(f"expected frames of shape (B, T, 3, H, W), got {tuple(frames.shape)}")
        if not self.training or self.probability == 0.0 or frames.shape[0] == 0:
            return frames
        with self._rng(frames.device):
            apply = torch.rand(frames.shape[0], device=frames.device) < self.probability
            if not bool(apply.any()):
                return frames
            out = frames.clone()
            chosen = apply.nonzero().flatten()
            step = _chunk_samples(frames)
            for start in range(0, len(chosen), step):
                index = chosen[start : start + step]
                chunk = frames[index]
                if self.frames_pipeline is not None:
                    chunk = self.frames_pipeline(chunk)
                if self.noise_std > 0:
                    chunk = chunk + torch.randn_like(chunk).mul_(self.noise_std)
                    chunk.clamp_(0.0, 1.0)
                out[index] = chunk.to(out.dtype)
        return out

    def extra_repr(self) -> str:
        return f"probability={self.probability}, noise_std={self.noise_std:.4f}"
