"""ScalarMLP: the frame-free model, an MLP over a strategy's scalar inputs (FW, FWE).
See docs/models.md, "ScalarMLP".
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar

import torch
from torch import Tensor

from tactile_compliance.data.inputs import InputStrategy
from tactile_compliance.models.base import TactileModel, check_dropout, check_sizes, make_mlp
from tactile_compliance.models.registry import register_model
from tactile_compliance.models.settings import DROPOUT_CHOICES, SIZES_CHOICES, SearchDimension


@register_model("scalar_mlp")
class ScalarMLP(TactileModel):
    """Linear -> ELU -> Dropout layers over the concatenated normalised scalar inputs (any
    of ``data.inputs.INPUTS``' scalars, in table order), then one logit. No backbone and
    no image input: the default model of a frame-free strategy (``model.name: auto``)."""

    takes_images: ClassVar[bool] = False
    scalar_inputs: ClassVar[frozenset[str] | None] = None
    hparam_checks = TactileModel.extend_checks(hidden_sizes=check_sizes, dropout=check_dropout)
    default_training: ClassVar[dict[str, Any]] = {"lr": 1e-3, "batch_size": 32, "gamma": None}
    hpo_space: ClassVar[tuple[SearchDimension, ...]] = (
        *TactileModel.hpo_space,
        SearchDimension.hparam("hidden_sizes", SIZES_CHOICES),
        SearchDimension.hparam("dropout", DROPOUT_CHOICES),
    )
    display_name: ClassVar[str] = "Scalar MLP"
    display_order: ClassVar[int] = 3

    def __init__(
        self,
        inputs: InputStrategy | str = "FW",
        hidden_sizes: Sequence[int] = (64, 64),
        dropout: float = 0.1,
    ) -> None:
        # locals() holds exactly the constructor's arguments at this point.
        super().__init__(inputs, self.check_hparams(locals()))
        width = sum(spec.size for spec in self.inputs.scalars)
        self.mlp = make_mlp(width, self.hparams["hidden_sizes"], 1, self.hparams["dropout"])

    def _head(self, features: Tensor | None, scalars: dict[str, Tensor]) -> Tensor:
        return self.mlp(torch.cat(list(scalars.values()), dim=1)).squeeze(1)
