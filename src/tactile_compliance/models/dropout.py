"""Dropout with a faster random mask on the CPU: four 15-bit lanes per 64-bit random
number; same distribution up to ``p`` rounded to a multiple of 2^-15. See docs/models.md,
"CPU speed-ups in the heads".
"""

from __future__ import annotations

import torch
from torch import nn

__all__ = ["Dropout", "keep_mask", "keep_probability", "use_fast_dropout"]

_LANE_BITS = 15
_LANES = 2**_LANE_BITS


def keep_mask(shape: torch.Size | tuple[int, ...], p: float, dtype: torch.dtype) -> torch.Tensor:
    """A 0/1 mask of ``shape`` (CPU, ``dtype``) whose elements are 0 with probability
    ``round(p * 2^15) / 2^15``, independently; see :func:`keep_probability`."""
    numel = 1
    for size in shape:
        numel *= int(size)
    threshold = round(p * _LANES)
    # random_() on int64 fills [0, 2^63); every int16 lane masked to 15 bits is uniform
    # on [0, 2^15). (lane - threshold) >> 15 is -1 below the threshold (drop), else 0.
    words = torch.empty((numel + 3) // 4, dtype=torch.int64).random_()
    lanes = words.view(torch.int16)[:numel].view(shape)
    drop = ((lanes & (_LANES - 1)) - threshold) >> _LANE_BITS
    return drop.add_(1).to(dtype)


def keep_probability(p: float) -> float:
    """The probability that :func:`keep_mask` keeps an element: ``1 - round(p * 2^15) / 2^15``."""
    return 1.0 - round(p * _LANES) / _LANES


class Dropout(nn.Dropout):
    """``nn.Dropout`` with :func:`keep_mask` on the CPU; elsewhere, in eval mode and
    ``inplace``, ``nn.Dropout`` itself.

    The output is rescaled by the rounded keep probability, so its mean is exact. The
    mask comes from torch's global generator (``torch.manual_seed`` fixes it), and the
    layer has no parameters: swapping it in leaves a model's ``state_dict`` unchanged.
    """

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not self.training or self.p == 0.0 or self.inplace or x.device.type != "cpu":
            return super().forward(x)
        keep = keep_probability(self.p)
        if keep == 0.0:
            return x * 0.0
        # Scaling after the mask keeps the scale in float even for bfloat16 activations.
        return x * keep_mask(x.shape, self.p, x.dtype) * (1.0 / keep)


def use_fast_dropout(module: nn.Module) -> nn.Module:
    """Replace every plain ``nn.Dropout`` inside ``module`` by :class:`Dropout`, in place
    (also those that PyTorch's own layers create, e.g. ``nn.TransformerEncoderLayer``);
    the ``state_dict`` is unchanged."""
    for parent in module.modules():
        for name, child in list(parent.named_children()):
            if type(child) is nn.Dropout:
                setattr(parent, name, Dropout(child.p, inplace=child.inplace))
    return module
