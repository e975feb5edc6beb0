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

from tactile_compliance.data.inputs import (
    INPUTS,
    MIN_FRAME_SIDE_PX,
    NUM_FRAMES,
    InputSpec,
    InputStrategy,
)
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

#: One scalar input (``(B, n)``); None when not given.
Scalar = Tensor | None

#: Validates one hyperparameter: ``check(name, value)`` returns the value to store.
HparamCheck = Callable[[str, Any], Any]


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
    #: Whether the model reads an image input (frames or depth maps) through a backbone;
    #: False for a model of the scalars alone, which refuses strategies with images.
    takes_images: ClassVar[bool] = True
    #: The scalar inputs (``data.inputs.INPUTS`` names) its head can take; None: any.
    scalar_inputs: ClassVar[frozenset[str] | None] = frozenset({"force", "width", "estimates"})

    backbone: nn.Module

    def __init__(self, inputs: InputStrategy | str, hparams: dict[str, Any]) -> None:
        super().__init__()
        self.inputs: InputStrategy = InputStrategy.parse(inputs)
        problem = self.strategy_problem(self.inputs)
        if problem:
            raise ValueError(problem)
        try:
            # Round-trip so the stored dict is exactly what a checkpoint will give back.
            self.hparams: dict[str, Any] = json.loads(json.dumps(hparams))
        except TypeError as exc:
            raise ValueError(f"hyperparameters must be JSON-serialisable: {exc}") from exc
        # What the backbone was initialised from, for reports; not part of hparams because
        # a checkpoint must rebuild the architecture without downloading anything.
        self.backbone_weights: str = "none"

    @classmethod
    def strategy_problem(cls, strategy: InputStrategy | str) -> str | None:
        """Why this model cannot take ``strategy``'s inputs (one line), or None."""
        strategy = InputStrategy.parse(strategy)
        name = cls.model_name or cls.__name__
        if cls.takes_images and strategy.image is None:
            return (
                f"model {name} reads frames or depth maps, but inputs={strategy.value} has "
                f"none; a frame-free strategy trains model scalar_mlp (the default for it)"
            )
        if not cls.takes_images and strategy.image is not None:
            return (
                f"model {name} takes no images, but inputs={strategy.value} includes "
                f"{strategy.image.name}; use a frame-free strategy (FW, FWE)"
            )
        allowed = cls.scalar_inputs
        extra = [n for n in strategy.scalar_names if allowed is not None and n not in allowed]
        if extra:
            return f"model {name} cannot take input(s) {', '.join(extra)} (inputs={strategy.value})"
        return None

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
        """Smallest image height/width [px] the model is trained on: the input rule's
        ``data.inputs.MIN_FRAME_SIDE_PX`` or the backbone's own minimum, the larger."""
        return max(MIN_FRAME_SIDE_PX, int(getattr(self.backbone, "min_input_size", 1)))

    # ------------------------------------------------------------------ forward
    def encode_frames(self, frames: Tensor) -> Tensor:
        """Run the backbone on every image: ``(B, 3, 3, H, W) -> (B, 3, feature_dim)``, what
        a feature cache stores. The images are the strategy's image input as
        ``runs.forward.prepare_images`` gives them: RGB frames, or depth maps repeated on
        the three channels."""
        if not isinstance(frames, Tensor) or frames.dim() != 5:
            shape = tuple(frames.shape) if isinstance(frames, Tensor) else type(frames)
            raise ValueError(
                f"frames (the image input) must be a tensor of shape (B, {NUM_FRAMES}, 3, H, W), "
                f"got {shape}"
            )
        batch, n_frames, channels, height, width = frames.shape
        if n_frames != NUM_FRAMES or channels != 3:
            raise ValueError(
                f"frames (the image input) must have shape (B, {NUM_FRAMES}, 3, H, W) "
                f"({NUM_FRAMES} frames of 3 channels), got {tuple(frames.shape)}"
            )
        if min(height, width) < self.min_image_size:
            raise ValueError(
                f"{type(self).__name__} needs images of at least "
                f"{self.min_image_size}x{self.min_image_size} pixels, got {height}x{width}"
            )
        if not frames.is_floating_point():
            raise ValueError(
                f"frames must be float (normalised), got dtype {frames.dtype}; convert and "
                f"normalise uint8 frames in the data pipeline"
            )
        features = self.backbone(frames.reshape(batch * n_frames, channels, height, width))
        return features.reshape(batch, n_frames, -1)

    def forward(self, frames: Tensor | None = None, **scalars: Scalar) -> Tensor:
        """Predict the normalised log10 modulus ``(B,)`` from the strategy's image input
        ``frames`` (prepared RGB frames or depth maps, see :meth:`encode_frames`; None for
        a frame-free model) and its scalar inputs, normalised, by name (``force=``,
        ``width=``, ``estimates=``); inputs the strategy does not use are ignored, unknown
        names refused.

        The output is a sigmoid, in (0, 1). It is exactly
        ``forward_features(encode_frames(frames), ...)``, so cached features give the same
        result. A scalar input the strategy uses that is missing or of the wrong shape is a
        ValueError naming it, its meaning and the shape expected.
        """
        features = None if self.inputs.image is None else self.encode_frames(frames)
        return self.forward_features(features, **scalars)

    def forward_features(self, features: Tensor | None, **scalars: Scalar) -> Tensor:
        """Same as :meth:`forward` but from cached features ``(B, 3, feature_dim)``."""
        unknown = sorted(set(scalars) - set(INPUTS))
        if unknown:
            raise ValueError(f"unknown input(s) {unknown}; inputs are {', '.join(INPUTS)}")
        if self.inputs.image is None:
            if features is not None:
                raise ValueError(f"{type(self).__name__} takes no images or image features")
            given = [v for n, v in scalars.items() if self.inputs.uses(n) and v is not None]
            batch = int(given[0].shape[0]) if given and isinstance(given[0], Tensor) else 0
            dtype = next(self.parameters()).dtype
        else:
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
            batch, dtype = features.shape[0], features.dtype
        # Only the strategy's inputs reach the head, checked, in table order.
        checked = {
            spec.name: self._check_scalar(spec, scalars.get(spec.name), batch, dtype)
            for spec in self.inputs.scalars
        }
        logits = self._head(features, checked)
        # reshape(-1), not (batch): an ONNX trace must keep the batch size dynamic.
        return torch.sigmoid(logits.reshape(-1))

    def _check_scalar(
        self, spec: InputSpec, tensor: Scalar, batch: int, dtype: torch.dtype
    ) -> Tensor:
        if tensor is None:
            raise ValueError(
                f"{type(self).__name__} with inputs={self.inputs.value} needs `{spec.name}` "
                f"({spec.meaning}, normalised, shape (B, {spec.size})), got None"
            )
        if not isinstance(tensor, Tensor) or tuple(tensor.shape) != (batch, spec.size):
            shape = tuple(tensor.shape) if isinstance(tensor, Tensor) else type(tensor)
            raise ValueError(
                f"`{spec.name}` ({spec.meaning}) must have shape ({batch}, {spec.size}), "
                f"got {shape}"
            )
        # Data pipelines often hand over float64 (numpy); match the features instead of
        # failing inside a Linear layer.
        return tensor.to(dtype=dtype)

    def _head(self, features: Tensor | None, scalars: dict[str, Tensor]) -> Tensor:
        """Map image features (None for a frame-free model) and the strategy's scalar
        inputs (name -> normalised ``(B, size)``, in table order) to ``(B,)`` logits."""
        raise NotImplementedError

    def extra_repr(self) -> str:
        return f"inputs={self.inputs.value}"


class FusionModel(TactileModel):
    """A model with the Burgess-style fusion head (Top10NN, Res-Tf; docs/models.md): it
    takes any scalar input of the table (a tower each, the estimates through the
    estimation decoder). Towers exist only for the strategy's inputs, so an input it does
    not use has no weights.

    Subclasses extend ``hparam_checks`` (:meth:`extend_checks`), call
    :meth:`_build_fusion_head` and implement :meth:`_image_vector`.
    """

    scalar_inputs: ClassVar[frozenset[str] | None] = None
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
        # One tower per scalar input but the estimates (``<name>_encoder``, built in table
        # order: force, width), whose output joins the image vector in the decoder.
        for spec in self.inputs.scalars:
            if spec.name != "estimates":
                setattr(self, f"{spec.name}_encoder", nn.Linear(spec.size, hp["fwe_size"]))
                decoder_in += hp["fwe_size"]
        uses_estimates = self.inputs.uses("estimates")
        decoder_out = hp["decoder_output_size"] if uses_estimates else 1
        self.decoder = make_mlp(decoder_in, hp["decoder_sizes"], decoder_out, hp["decoder_dropout"])
        if uses_estimates:
            self.estimation_decoder = make_mlp(
                decoder_out + 2, hp["estimation_sizes"], 1, hp["estimation_dropout"]
            )

    def _image_vector(self, features: Tensor) -> Tensor:
        """The image part of the fusion input, ``(B, 3, feature_dim) -> (B, image_dim)``."""
        raise NotImplementedError

    def _head(self, features: Tensor | None, scalars: dict[str, Tensor]) -> Tensor:
        parts = [self._image_vector(features)]
        parts += [getattr(self, f"{n}_encoder")(v) for n, v in scalars.items() if n != "estimates"]
        out = self.decoder(torch.cat(parts, dim=1))
        if "estimates" in scalars:
            out = self.estimation_decoder(torch.cat([out, scalars["estimates"]], dim=1))
        return out.squeeze(1)
