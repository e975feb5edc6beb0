"""Res-Tf: ResNet features per frame, a Transformer encoder over the three frames, and
the fusion head. Architecture: docs/models.md, "Res-Tf".
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from typing import Any, ClassVar

import torch
from torch import Tensor, nn

from tactile_compliance.data.inputs import InputStrategy
from tactile_compliance.models.backbones import create_backbone
from tactile_compliance.models.base import (
    NUM_FRAMES,
    FusionModel,
    check_dropout,
    check_positive_int,
)
from tactile_compliance.models.dropout import use_fast_dropout
from tactile_compliance.models.registry import register_model
from tactile_compliance.models.settings import DIM_CHOICES, DROPOUT_CHOICES, SearchDimension

__all__ = ["ResTf", "sinusoidal_positional_encoding"]

_RESNETS = ("resnet18", "resnet34", "resnet50")


def sinusoidal_positional_encoding(length: int, dim: int) -> torch.Tensor:
    """The fixed encoding of Vaswani et al.: sin on even, cos on odd channels, ``(length, dim)``."""
    position = torch.arange(length, dtype=torch.float32).unsqueeze(1)
    frequencies = torch.exp(
        torch.arange(0, dim, 2, dtype=torch.float32) * (-math.log(10000.0) / dim)
    )
    encoding = torch.zeros(length, dim)
    encoding[:, 0::2] = torch.sin(position * frequencies)
    # For odd dim there is one cosine channel fewer than sine channels.
    encoding[:, 1::2] = torch.cos(position * frequencies)[:, : dim // 2]
    return encoding


def _check_resnet(name: str, value: Any) -> str:
    """Validate the ``backbone`` hyperparameter (a ResNet name, any case)."""
    backbone = str(value).strip().lower()
    if backbone not in _RESNETS:
        raise ValueError(
            f"hyperparameter {name} must be one of {', '.join(_RESNETS)}, got {value!r}"
        )
    return backbone


@register_model("res_tf")
class ResTf(FusionModel):
    """Res-Tf, the ResNet + Transformer model of the paper (defaults: its tuned ALL config).

    Args:
        backbone: "resnet18" (paper), "resnet34" or "resnet50".
        num_heads: attention heads; must divide ``embedding_dim`` (the token size).
        output_dim: size of the image output after the Transformer.
        video_dropout: dropout before the image output layer.
        fwe_size: output size of the force and width towers Linear(3, fwe_size).
        decoder_output_size: raw decoder outputs combined with the estimates (with E only).
        backbone_weights: "none", "imagenet" or a path to a torchvision ResNet state dict;
            recorded in ``self.backbone_weights``, not in ``hparams``.
    """

    hparam_checks = FusionModel.extend_checks(
        backbone=_check_resnet,
        num_layers=check_positive_int,
        num_heads=check_positive_int,
        embedding_dim=check_positive_int,
        output_dim=check_positive_int,
        video_dropout=check_dropout,
        transformer_dropout=check_dropout,
        dim_feedforward=check_positive_int,
    )
    # The constructor defaults and these settings are the paper's tuned ALL configuration.
    default_training: ClassVar[dict[str, Any]] = {"lr": 1.1e-4, "batch_size": 24, "gamma": 0.977}
    # The paper's other tuned configuration (only the values that differ from the above
    # are listed: presets and HPO read these through models.settings.paper_settings).
    tuned_configs: ClassVar[dict[str, dict[str, dict[str, Any]]]] = {
        "Image": {
            "model": {
                "num_layers": 5,
                "num_heads": 4,
                "embedding_dim": 256,
                "output_dim": 1024,
                "decoder_sizes": [256],
            },
            "training": {"lr": 8e-5, "batch_size": 40, "gamma": 0.962},
        },
    }
    hpo_space: ClassVar[tuple[SearchDimension, ...]] = (
        *FusionModel.hpo_space,
        SearchDimension.hparam("video_dropout", DROPOUT_CHOICES),
        SearchDimension.hparam("num_layers", (2, 3, 4, 5, 6)),
        SearchDimension.hparam("num_heads", (1, 2, 4, 8, 16)),
        SearchDimension.hparam("embedding_dim", DIM_CHOICES),
        SearchDimension.hparam("output_dim", DIM_CHOICES),
    )
    pretrained_backbone: ClassVar[bool] = True
    display_name: ClassVar[str] = "Res-Tf"
    display_order: ClassVar[int] = 2
    pretrain_backbones: ClassVar[tuple[str, ...]] = ("resnet18", "resnet34", "resnet50")

    def __init__(
        self,
        inputs: InputStrategy | str = "ALL",
        backbone: str = "resnet18",
        num_layers: int = 4,
        num_heads: int = 2,
        embedding_dim: int = 256,
        output_dim: int = 512,
        video_dropout: float = 0.1,
        transformer_dropout: float = 0.1,
        dim_feedforward: int = 2048,
        fwe_size: int = 32,
        decoder_sizes: Sequence[int] = (512,),
        decoder_dropout: float = 0.3,
        decoder_output_size: int = 3,
        estimation_sizes: Sequence[int] = (64,),
        estimation_dropout: float = 0.1,
        backbone_weights: str | os.PathLike[str] = "none",
    ) -> None:
        # locals() holds exactly the constructor's arguments at this point.
        hparams = self.check_hparams(locals())
        if hparams["embedding_dim"] % hparams["num_heads"]:
            raise ValueError(
                f"embedding_dim ({embedding_dim}) must be divisible by num_heads ({num_heads})"
            )
        super().__init__(inputs, hparams)
        hp = self.hparams
        self.backbone = create_backbone(hp["backbone"], backbone_weights)
        self.backbone_weights = os.fspath(backbone_weights)

        self.token_projection = nn.Linear(self.backbone.feature_dim, hp["embedding_dim"])
        # Fixed, not learned, and not saved: it is a function of the shape only.
        self.register_buffer(
            "positional_encoding",
            sinusoidal_positional_encoding(NUM_FRAMES, hp["embedding_dim"]),
            persistent=False,
        )
        layer = nn.TransformerEncoderLayer(
            d_model=hp["embedding_dim"],
            nhead=hp["num_heads"],
            dim_feedforward=hp["dim_feedforward"],
            dropout=hp["transformer_dropout"],
            batch_first=True,
        )
        # Nested tensors only matter for padded sequences; three tokens never are.
        self.transformer = nn.TransformerEncoder(
            layer, num_layers=hp["num_layers"], enable_nested_tensor=False
        )
        self.video_dropout = nn.Dropout(hp["video_dropout"])
        self.image_output = nn.Linear(hp["embedding_dim"], hp["output_dim"])

        self._build_fusion_head(hp["output_dim"])
        use_fast_dropout(self)

    def _image_vector(self, features: Tensor) -> Tensor:
        tokens = self.token_projection(features) + self.positional_encoding.to(features.dtype)
        video = self.transformer(tokens).mean(dim=1)
        return self.image_output(self.video_dropout(video))
