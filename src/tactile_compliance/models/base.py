"""Shared interface of the compliance models: backbone + head, input checks, metadata.

Input shapes, normalisation and the backbone/head split: docs/models.md, "Common interface".
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from types import MappingProxyType
from typing import Any, ClassVar

import torch
from torch import Tensor, nn

from tactile_compliance.models.inputs import InputStrategy
from tactile_compliance.models.settings import (
    DROPOUT_CHOICES,
    FWE_CHOICES,
    SIZES_CHOICES,
    TRAINING_SPACE,
    SearchDimension,
)

__all__ = [
    "NUM_FRAMES",
    "FusionModel",
    "HparamCheck",
    "Scalar",
    "TactileModel",
    "check_dropout",
    "check_positive_int",
    "check_sizes",
    "make_mlp",
]

#: Frames per sample (start, middle, end of the grasp).
NUM_FRAMES = 3

#: One scalar input (force, width or estimates, ``(B, n)``); None when not given, and
#: always None in the head when the input strategy disables it.
Scalar = Tensor | None

#: Validates one hyperparameter: ``check(name, value)`` returns the value to store.
HparamCheck = Callable[[str, Any], Any]

_SCALAR_INPUTS: dict[str, tuple[int, str]] = {
    "force": (NUM_FRAMES, "normal force F, normalised F / 60 N"),
    "width": (NUM_FRAMES, "gripper width W, normalised W / 0.08 m"),
    "estimates": (2, "analytical estimates E (elastic, Hertz), normalised log10"),
}


def make_mlp(
    in_features: int, hidden_sizes: Sequence[int], out_features: int, dropout: float
) -> nn.Sequential:
    """Linear -> ELU -> Dropout for every hidden size, then a plain Linear (logits, or the
    raw values the estimation decoder combines with the estimates)."""
    layers: list[nn.Module] = []
    previous = in_features
    for size in hidden_sizes:
        layers += [nn.Linear(previous, size), nn.ELU(), nn.Dropout(dropout)]
        previous = size
    layers.append(nn.Linear(previous, out_features))
    return nn.Sequential(*layers)


def check_positive_int(name: str, value: Any) -> int:
    """Validate a size hyperparameter (clear message instead of a deep torch error)."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"hyperparameter {name} must be a positive integer, got {value!r}")
    return int(value)


def check_sizes(name: str, value: Any) -> list[int]:
    """Validate a list of layer sizes (may be empty); returned as a list so hparams stay
    JSON-friendly."""
    if isinstance(value, (int, str)) or not isinstance(value, Sequence):
        raise ValueError(f"hyperparameter {name} must be a list of integers, got {value!r}")
    return [check_positive_int(f"{name}[{i}]", v) for i, v in enumerate(value)]


def check_dropout(name: str, value: Any) -> float:
    """Validate a dropout probability in [0, 1)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value < 1:
        raise ValueError(f"hyperparameter {name} must be a probability in [0, 1), got {value!r}")
    return float(value)


class TactileModel(nn.Module):
    """Base class: input checks, the backbone/head split and self-describing metadata.

    Subclasses set ``self.backbone`` and implement :meth:`_head`; the class attributes
    are described in docs/models.md, "Common interface".
    """

    model_name: ClassVar[str] = ""
    hparam_checks: ClassVar[Mapping[str, HparamCheck]] = MappingProxyType({})
    default_training: ClassVar[dict[str, Any]] = {}
    tuned_configs: ClassVar[dict[str, dict[str, dict[str, Any]]]] = {}
    hpo_space: ClassVar[tuple[SearchDimension, ...]] = TRAINING_SPACE
    recommended_image_size: ClassVar[tuple[int, int] | None] = None
    pretrained_backbone: ClassVar[bool] = False
    display_name: ClassVar[str] = ""
    display_order: ClassVar[int] = 1_000_000
    pretrain_backbones: ClassVar[tuple[str, ...]] = ()

    backbone: nn.Module

    def __init__(self, inputs: InputStrategy | str, hparams: dict[str, Any]) -> None:
        super().__init__()
        self.inputs: InputStrategy = InputStrategy.parse(inputs)
        try:
            # Round-trip so the stored dict is exactly what a checkpoint will give back.
            self.hparams: dict[str, Any] = json.loads(json.dumps(hparams))
        except TypeError as exc:
            raise ValueError(f"hyperparameters must be JSON-serialisable: {exc}") from exc
        # What the backbone was initialised from, for reports; not part of hparams because
        # a checkpoint must rebuild the architecture without downloading anything.
        self.backbone_weights: str = "none"

    @classmethod
    def extend_checks(cls, **checks: HparamCheck) -> Mapping[str, HparamCheck]:
        """``checks`` followed by this class's ``hparam_checks``: a subclass's table
        (read-only, as class data shared by every instance must be)."""
        return MappingProxyType({**checks, **cls.hparam_checks})

    @classmethod
    def check_hparams(cls, arguments: Mapping[str, Any]) -> dict[str, Any]:
        """The hyperparameters among a constructor's ``arguments`` (its ``locals()``),
        each validated by its ``hparam_checks`` entry, in that order."""
        return {name: check(name, arguments[name]) for name, check in cls.hparam_checks.items()}

    # ------------------------------------------------------------------ metadata
    @property
    def feature_dim(self) -> int:
        """Size of one frame's backbone feature vector."""
        return int(self.backbone.feature_dim)

    @property
    def min_image_size(self) -> int:
        """Smallest frame height/width the backbone accepts."""
        return int(getattr(self.backbone, "min_input_size", 1))

    # ------------------------------------------------------------------ forward
    def encode_frames(self, frames: Tensor) -> Tensor:
        """Run the backbone on every frame: ``(B, 3, 3, H, W) -> (B, 3, feature_dim)``, what
        a feature cache stores."""
        if not isinstance(frames, Tensor) or frames.dim() != 5:
            shape = tuple(frames.shape) if isinstance(frames, Tensor) else type(frames)
            raise ValueError(
                f"frames must be a tensor of shape (B, {NUM_FRAMES}, 3, H, W), got {shape}"
            )
        batch, n_frames, channels, height, width = frames.shape
        if n_frames != NUM_FRAMES or channels != 3:
            raise ValueError(
                f"frames must have shape (B, {NUM_FRAMES}, 3, H, W) "
                f"({NUM_FRAMES} RGB frames), got {tuple(frames.shape)}"
            )
        if min(height, width) < self.min_image_size:
            raise ValueError(
                f"{type(self).__name__} needs frames of at least "
                f"{self.min_image_size}x{self.min_image_size} pixels, got {height}x{width}"
            )
        if not frames.is_floating_point():
            raise ValueError(
                f"frames must be float (normalised), got dtype {frames.dtype}; convert and "
                f"normalise uint8 frames in the data pipeline"
            )
        features = self.backbone(frames.reshape(batch * n_frames, channels, height, width))
        return features.reshape(batch, n_frames, -1)

    def forward(
        self, frames: Tensor, force: Scalar = None, width: Scalar = None, estimates: Scalar = None
    ) -> Tensor:
        """Predict the normalised log10 modulus ``(B,)``; disabled inputs are ignored."""
        return self.forward_features(self.encode_frames(frames), force, width, estimates)

    def forward_features(
        self, features: Tensor, force: Scalar = None, width: Scalar = None, estimates: Scalar = None
    ) -> Tensor:
        """Same as :meth:`forward` but from cached features ``(B, 3, feature_dim)``."""
        if (
            not isinstance(features, Tensor)
            or features.dim() != 3
            or features.shape[1] != NUM_FRAMES
            or features.shape[2] != self.feature_dim
        ):
            shape = tuple(features.shape) if isinstance(features, Tensor) else features
            raise ValueError(
                f"features must have shape (B, {NUM_FRAMES}, {self.feature_dim}), got {shape}"
            )
        batch = features.shape[0]
        given = {"force": force, "width": width, "estimates": estimates}
        # Disabled inputs become None here, so they never reach the head.
        scalars = {
            name: self._check_scalar(name, tensor, batch, features.dtype)
            if name in self.inputs.needs
            else None
            for name, tensor in given.items()
        }
        logits = self._head(features, scalars["force"], scalars["width"], scalars["estimates"])
        return torch.sigmoid(logits.reshape(batch))

    def _check_scalar(self, name: str, tensor: Scalar, batch: int, dtype: torch.dtype) -> Tensor:
        size, meaning = _SCALAR_INPUTS[name]
        if tensor is None:
            raise ValueError(
                f"{type(self).__name__} with inputs={self.inputs.value} needs `{name}` "
                f"({meaning}, shape (B, {size})), got None"
            )
        if not isinstance(tensor, Tensor) or tuple(tensor.shape) != (batch, size):
            shape = tuple(tensor.shape) if isinstance(tensor, Tensor) else type(tensor)
            raise ValueError(f"`{name}` ({meaning}) must have shape ({batch}, {size}), got {shape}")
        # Data pipelines often hand over float64 (numpy); match the features instead of
        # failing inside a Linear layer.
        return tensor.to(dtype=dtype)

    def _head(self, features: Tensor, force: Scalar, width: Scalar, estimates: Scalar) -> Tensor:
        """Map features and the enabled inputs (others are None) to ``(B,)`` logits."""
        raise NotImplementedError

    def extra_repr(self) -> str:
        return f"inputs={self.inputs.value}"


class FusionModel(TactileModel):
    """A model with the Burgess-style fusion head (Top10NN, Res-Tf; docs/models.md).

    Subclasses extend ``hparam_checks`` (:meth:`extend_checks`), call
    :meth:`_build_fusion_head` and implement :meth:`_image_vector`.
    """

    hparam_checks = TactileModel.extend_checks(
        fwe_size=check_positive_int,
        decoder_sizes=check_sizes,
        decoder_dropout=check_dropout,
        decoder_output_size=check_positive_int,
        estimation_sizes=check_sizes,
        estimation_dropout=check_dropout,
    )
    hpo_space: ClassVar[tuple[SearchDimension, ...]] = (
        *TactileModel.hpo_space,
        SearchDimension.hparam("decoder_dropout", DROPOUT_CHOICES),
        SearchDimension.hparam("decoder_sizes", SIZES_CHOICES),
        SearchDimension.hparam("estimation_sizes", SIZES_CHOICES, needs=("estimates",)),
        SearchDimension.hparam("decoder_output_size", range(1, 9), needs=("estimates",)),
        SearchDimension.hparam("estimation_dropout", DROPOUT_CHOICES, needs=("estimates",)),
        SearchDimension.hparam("fwe_size", FWE_CHOICES, needs=("force", "width")),
    )

    def _build_fusion_head(self, image_dim: int) -> None:
        """The towers and decoders, from ``self.hparams``."""
        hp = self.hparams
        decoder_in = image_dim
        if self.inputs.uses_force:
            self.force_encoder = nn.Linear(NUM_FRAMES, hp["fwe_size"])
            decoder_in += hp["fwe_size"]
        if self.inputs.uses_width:
            self.width_encoder = nn.Linear(NUM_FRAMES, hp["fwe_size"])
            decoder_in += hp["fwe_size"]
        decoder_out = hp["decoder_output_size"] if self.inputs.uses_estimates else 1
        self.decoder = make_mlp(decoder_in, hp["decoder_sizes"], decoder_out, hp["decoder_dropout"])
        if self.inputs.uses_estimates:
            self.estimation_decoder = make_mlp(
                decoder_out + 2, hp["estimation_sizes"], 1, hp["estimation_dropout"]
            )

    def _image_vector(self, features: Tensor) -> Tensor:
        """The image part of the fusion input, ``(B, 3, feature_dim) -> (B, image_dim)``."""
        raise NotImplementedError

    def _head(self, features: Tensor, force: Scalar, width: Scalar, estimates: Scalar) -> Tensor:
        parts = [self._image_vector(features)]
        if force is not None:
            parts.append(self.force_encoder(force))
        if width is not None:
            parts.append(self.width_encoder(width))
        out = self.decoder(torch.cat(parts, dim=1))
        if estimates is not None:
            out = self.estimation_decoder(torch.cat([out, estimates], dim=1))
        return out.squeeze(1)
