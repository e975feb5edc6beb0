"""Top10NN: the baseline of Burgess et al., a small CNN trained from scratch, and the
fusion head. Architecture: docs/models.md, "Top10NN".
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any, ClassVar

import torch
from torch import Tensor, nn

from tactile_compliance.data.inputs import InputStrategy
from tactile_compliance.models.backbones import load_weights_file
from tactile_compliance.models.base import (
    NUM_FRAMES,
    FusionModel,
    check_dropout,
    check_positive_int,
)
from tactile_compliance.models.dropout import use_fast_dropout
from tactile_compliance.models.frame_rules import TOP10_KERNELS, TOP10_MIN_INPUT_PX, TOP10_STRIDE
from tactile_compliance.models.registry import register_model
from tactile_compliance.models.settings import DROPOUT_CHOICES, POW2_32_512, SearchDimension

__all__ = ["TOP10_BACKBONE", "Top10Encoder", "Top10NN"]

#: The name of Top10NN's per-frame CNN as a backbone (``pretrain --backbone``).
TOP10_BACKBONE = "top10nn-cnn"

_CHANNELS = (32, 64, 128, 256, 512)
_KERNELS = TOP10_KERNELS
_STRIDE = TOP10_STRIDE


class Top10Encoder(nn.Module):
    """The per-frame CNN of Top10NN: ``(N, 3, H, W) -> (N, img_feature_size)``, for frames
    of at least ``min_input_size`` (65) px a side (five unpadded stride-2 convolutions)."""

    min_input_size: int = TOP10_MIN_INPUT_PX

    def __init__(self, img_feature_size: int = 128, dropout: float = 0.3) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        in_channels = 3
        for channels, kernel in zip(_CHANNELS, _KERNELS, strict=True):
            # No conv bias: the following BatchNorm removes any constant offset anyway.
            layers += [
                nn.Conv2d(in_channels, channels, kernel, stride=_STRIDE, padding=0, bias=False),
                nn.BatchNorm2d(channels),
                nn.ReLU(inplace=True),
            ]
            in_channels = channels
        self.conv = nn.Sequential(*layers)
        self.fc = nn.Sequential(
            nn.Dropout(dropout),
            nn.Linear(_CHANNELS[-1], 1024),
            nn.ELU(),
            nn.Dropout(dropout),
            nn.Linear(1024, img_feature_size),
        )
        self.feature_dim: int = img_feature_size

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.fc(self.conv(x).mean(dim=(2, 3)))


@register_model("top10nn")
class Top10NN(FusionModel):
    """Top10NN baseline (Burgess et al.), trained from scratch (defaults: the paper's).

    Args:
        img_feature_size: per-frame image feature size.
        fwe_size: output size of the force and width towers, Linear(3, fwe_size) each.
        decoder_output_size: raw decoder outputs fed to the estimation decoder with E;
            unused without E (the decoder then emits one logit).
        backbone_weights: "none" (random init, the paper) or a path to a
            :class:`Top10Encoder` state dict (``pretrain --backbone top10nn-cnn``); there
            are no ImageNet weights.
    """

    hparam_checks = FusionModel.extend_checks(
        img_feature_size=check_positive_int, image_dropout=check_dropout
    )
    default_training: ClassVar[dict[str, Any]] = {"lr": 3e-6, "batch_size": 32, "gamma": None}
    pretrained_backbone: ClassVar[bool] = True
    display_name: ClassVar[str] = "Top10NN"
    display_order: ClassVar[int] = 0
    pretrain_backbones: ClassVar[tuple[str, ...]] = (TOP10_BACKBONE,)
    hpo_space: ClassVar[tuple[SearchDimension, ...]] = (
        *FusionModel.hpo_space,
        SearchDimension.hparam("image_dropout", DROPOUT_CHOICES),
        SearchDimension.hparam("img_feature_size", POW2_32_512),
    )

    def __init__(
        self,
        inputs: InputStrategy | str = "ALL",
        img_feature_size: int = 128,
        image_dropout: float = 0.3,
        fwe_size: int = 32,
        decoder_sizes: Sequence[int] = (512, 512, 128),
        decoder_dropout: float = 0.3,
        decoder_output_size: int = 3,
        estimation_sizes: Sequence[int] = (64, 64, 32),
        estimation_dropout: float = 0.3,
        backbone_weights: str | os.PathLike[str] = "none",
    ) -> None:
        # locals() holds exactly the constructor's arguments at this point.
        super().__init__(inputs, self.check_hparams(locals()))
        hp = self.hparams
        self.backbone = Top10Encoder(hp["img_feature_size"], hp["image_dropout"])
        weights = os.fspath(backbone_weights)
        if weights.strip().lower() == "imagenet":
            raise ValueError("top10nn has no ImageNet weights: use 'none' or a weights file")
        if weights.strip().lower() != "none":
            load_weights_file(self.backbone, TOP10_BACKBONE, weights)
        self.backbone_weights = weights
        self._build_fusion_head(NUM_FRAMES * hp["img_feature_size"])
        use_fast_dropout(self)

    def _image_vector(self, features: Tensor) -> Tensor:
        return features.flatten(1)
