"""VGG-LSTM (LRCN): VGG16 fc7 features per frame, an LSTM cell over the three frames.
Architecture and ``lstm_dropout_mode``: docs/models.md, "VGG-LSTM".
"""

from __future__ import annotations

import os
from typing import Any, ClassVar

import torch
from torch import Tensor, nn

from tactile_compliance.data.inputs import InputStrategy
from tactile_compliance.models.backbones import create_backbone
from tactile_compliance.models.base import (
    NUM_FRAMES,
    TactileModel,
    check_dropout,
    check_positive_int,
)
from tactile_compliance.models.dropout import use_fast_dropout
from tactile_compliance.models.frame_rules import RECOMMENDED_FRAME_SIZE
from tactile_compliance.models.registry import register_model
from tactile_compliance.models.settings import (
    DROPOUT_CHOICES,
    POW2_32_512,
    SCALAR_DIM_CHOICES,
    SearchDimension,
)

__all__ = ["VggLstm", "project_steps"]

#: Where VGG-LSTM's dropout acts: "recurrent" (the published code: the dropped-out hidden
#: state also feeds the next step) or "output" (only the per-step output path).
LSTM_DROPOUT_MODES = ("recurrent", "output")


def check_lstm_dropout_mode(name: str, value: Any) -> str:
    """Validate ``lstm_dropout_mode``: one of :data:`LSTM_DROPOUT_MODES`."""
    if not isinstance(value, str) or value not in LSTM_DROPOUT_MODES:
        raise ValueError(
            f"hyperparameter {name} must be one of {', '.join(LSTM_DROPOUT_MODES)}, got {value!r}"
        )
    return value


class _ProjectSteps(torch.autograd.Function):
    """``linear(cat([image, scalars], -1), weight, bias)`` whose backward computes the
    input gradient only for the inputs that need it (docs/models.md, "CPU speed-ups in
    the heads"). Slicing the weight instead makes autograd build a full-size weight
    gradient per slice (slower still).
    """

    @staticmethod
    def forward(  # type: ignore[override]
        ctx: Any,
        image: torch.Tensor,
        scalars: torch.Tensor,
        weight: torch.Tensor,
        bias: torch.Tensor | None,
    ) -> torch.Tensor:
        device = image.device.type
        dtype = torch.get_autocast_dtype(device) if torch.is_autocast_enabled(device) else None
        ctx.dtypes = (image.dtype, scalars.dtype, weight.dtype)
        ctx.image_dim = image.shape[-1]
        ctx.has_bias = bias is not None
        steps = torch.cat([image, scalars.to(image.dtype)], dim=-1)
        if dtype is not None:
            # Cast once, as autocast would, and keep the casts for the backward products.
            steps, weight = steps.to(dtype), weight.to(dtype)
            bias = None if bias is None else bias.to(dtype)
        ctx.save_for_backward(steps, weight)
        with torch.autocast(device, enabled=False):
            return nn.functional.linear(steps, weight, bias)

    @staticmethod
    def backward(ctx: Any, grad: torch.Tensor) -> tuple[torch.Tensor | None, ...]:  # type: ignore[override]
        steps, weight = ctx.saved_tensors
        image_dtype, scalars_dtype, weight_dtype = ctx.dtypes
        flat_grad = grad.reshape(-1, grad.shape[-1]).to(weight.dtype)
        lead = grad.shape[:-1]
        grad_image = grad_scalars = grad_weight = grad_bias = None
        if ctx.needs_input_grad[0]:
            grad_image = (flat_grad @ weight[:, : ctx.image_dim]).reshape(*lead, -1)
            grad_image = grad_image.to(image_dtype)
        if ctx.needs_input_grad[1]:
            grad_scalars = (flat_grad @ weight[:, ctx.image_dim :]).reshape(*lead, -1)
            grad_scalars = grad_scalars.to(scalars_dtype)
        if ctx.needs_input_grad[2]:
            grad_weight = (flat_grad.t() @ steps.reshape(-1, steps.shape[-1])).to(weight_dtype)
        if ctx.has_bias and ctx.needs_input_grad[3]:
            grad_bias = flat_grad.sum(dim=0).to(weight_dtype)
        return grad_image, grad_scalars, grad_weight, grad_bias


def project_steps(
    image: torch.Tensor,
    scalars: torch.Tensor | None,
    weight: torch.Tensor,
    bias: torch.Tensor | None,
) -> torch.Tensor:
    """``linear(cat([image, scalars], -1), weight, bias)`` over ``(..., features)`` inputs;
    when training, the image part's gradient is only computed if ``image`` needs one."""
    if scalars is None or not torch.is_grad_enabled():
        steps = image if scalars is None else torch.cat([image, scalars], dim=-1)
        return nn.functional.linear(steps, weight, bias)
    return _ProjectSteps.apply(image, scalars, weight, bias)


@register_model("vgg_lstm")
class VggLstm(TactileModel):
    """VGG-LSTM, the LRCN model of the paper (defaults: its tuned settings).

    Args:
        lstm_dropout: dropout probability on the LSTM hidden state.
        lstm_dropout_mode: "recurrent" (the published code: the dropped-out hidden state
            also feeds the next step) or "output" (only the per-step linear sees it).
        force_dim, width_dim, elastic_dim, hertz_dim: sizes of the Linear(1, d)
            embeddings of F_t, W_t, E_elastic and E_hertz.
        backbone_weights: "none", "imagenet" or a path to a VGG16 state dict; recorded
            in ``self.backbone_weights``, not in ``hparams``.
    """

    hparam_checks = TactileModel.extend_checks(
        hidden_size=check_positive_int,
        lstm_dropout=check_dropout,
        lstm_dropout_mode=check_lstm_dropout_mode,
        force_dim=check_positive_int,
        width_dim=check_positive_int,
        elastic_dim=check_positive_int,
        hertz_dim=check_positive_int,
    )
    default_training: ClassVar[dict[str, Any]] = {"lr": 3e-4, "batch_size": 16, "gamma": 0.97974}
    # Each scalar embedding is searched only when the strategy uses its input.
    hpo_space: ClassVar[tuple[SearchDimension, ...]] = (
        *TactileModel.hpo_space,
        SearchDimension.hparam("lstm_dropout", DROPOUT_CHOICES),
        SearchDimension.hparam("hidden_size", POW2_32_512),
        SearchDimension.hparam("force_dim", SCALAR_DIM_CHOICES, needs=("force",)),
        SearchDimension.hparam("width_dim", SCALAR_DIM_CHOICES, needs=("width",)),
        SearchDimension.hparam("elastic_dim", SCALAR_DIM_CHOICES, needs=("estimates",)),
        SearchDimension.hparam("hertz_dim", SCALAR_DIM_CHOICES, needs=("estimates",)),
    )
    recommended_image_size: ClassVar[tuple[int, int] | None] = RECOMMENDED_FRAME_SIZE["vgg_lstm"]
    pretrained_backbone: ClassVar[bool] = True
    display_name: ClassVar[str] = "VGG-LSTM"
    display_order: ClassVar[int] = 1
    pretrain_backbones: ClassVar[tuple[str, ...]] = ("vgg16",)

    def __init__(
        self,
        inputs: InputStrategy | str = "ALL",
        hidden_size: int = 256,
        lstm_dropout: float = 0.2,
        lstm_dropout_mode: str = "recurrent",
        force_dim: int = 32,
        width_dim: int = 32,
        elastic_dim: int = 32,
        hertz_dim: int = 32,
        backbone_weights: str | os.PathLike[str] = "none",
    ) -> None:
        # locals() holds exactly the constructor's arguments at this point.
        super().__init__(inputs, self.check_hparams(locals()))
        hp = self.hparams
        self.backbone = create_backbone("vgg16", backbone_weights)
        self.backbone_weights = os.fspath(backbone_weights)

        step_in = self.backbone.feature_dim
        # Embeddings exist only for enabled inputs: a disabled input has no weights.
        if self.inputs.uses("force"):
            self.force_encoder = nn.Linear(1, hp["force_dim"])
            step_in += hp["force_dim"]
        if self.inputs.uses("width"):
            self.width_encoder = nn.Linear(1, hp["width_dim"])
            step_in += hp["width_dim"]
        if self.inputs.uses("estimates"):
            self.estimate_encoder = nn.ModuleDict(
                {
                    "elastic": nn.Linear(1, hp["elastic_dim"]),
                    "hertz": nn.Linear(1, hp["hertz_dim"]),
                }
            )
            step_in += hp["elastic_dim"] + hp["hertz_dim"]
        self.lstm = nn.LSTMCell(step_in, hp["hidden_size"])
        self.dropout = nn.Dropout(hp["lstm_dropout"])
        self.recurrent_dropout = hp["lstm_dropout_mode"] == "recurrent"
        self.output = nn.Linear(hp["hidden_size"], 1)
        # Learnable weights of the three steps' outputs; ones -> a plain mean at init.
        self.step_weights = nn.Parameter(torch.ones(NUM_FRAMES))
        use_fast_dropout(self)

    def _head(self, features: Tensor | None, scalars: dict[str, Tensor]) -> Tensor:
        assert features is not None  # takes_images: the base class encoded them
        force, width, estimates = (scalars.get(n) for n in ("force", "width", "estimates"))
        batch = features.shape[0]
        constant: list[torch.Tensor] = []
        if estimates is not None:
            # The estimates describe the whole grasp, so every step sees the same embedding.
            constant.append(self.estimate_encoder["elastic"](estimates[:, 0:1]))
            constant.append(self.estimate_encoder["hertz"](estimates[:, 1:2]))
        scalar_steps = []
        for t in range(NUM_FRAMES):
            parts = []
            if force is not None:
                parts.append(self.force_encoder(force[:, t : t + 1]))
            if width is not None:
                parts.append(self.width_encoder(width[:, t : t + 1]))
            if parts or constant:
                scalar_steps.append(torch.cat(parts + constant, dim=1))
        # The LSTMCell's input projection of all three steps as one matrix product: its
        # weight (4 x hidden x ~4.4k) dominates the head, and one (3B x 4.4k) GEMM in the
        # forward and backward pass is much faster on a CPU than three small ones. The
        # recurrence below is exactly nn.LSTMCell's (gate order i, f, g, o).
        input_gates = project_steps(
            features,
            torch.stack(scalar_steps, dim=1) if scalar_steps else None,
            self.lstm.weight_ih,
            self.lstm.bias_ih,
        )  # (B, 3, 4 x hidden)
        hidden = features.new_zeros(batch, self.lstm.hidden_size)
        cell = features.new_zeros(batch, self.lstm.hidden_size)
        step_outputs = []
        for t in range(NUM_FRAMES):
            gates = input_gates[:, t] + nn.functional.linear(
                hidden, self.lstm.weight_hh, self.lstm.bias_hh
            )
            in_gate, forget_gate, cell_gate, out_gate = gates.chunk(4, dim=1)
            cell = torch.sigmoid(forget_gate) * cell + torch.sigmoid(in_gate) * torch.tanh(
                cell_gate
            )
            hidden = torch.sigmoid(out_gate) * torch.tanh(cell)
            dropped = self.dropout(hidden)
            if self.recurrent_dropout:
                # As published: the dropped-out state is also the next step's h (c is not).
                hidden = dropped
            step_outputs.append(self.output(dropped))
        outputs = torch.cat(step_outputs, dim=1)  # (B, 3)
        return outputs @ torch.softmax(self.step_weights, dim=0)
