"""The CPU dropout: same distribution and gradient as nn.Dropout, seeded, swappable."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from tactile_compliance.models import create_model
from tactile_compliance.models.dropout import (
    Dropout,
    keep_mask,
    keep_probability,
    use_fast_dropout,
)


@pytest.mark.parametrize("p", [0.1, 0.3, 0.5])
def test_mask_drops_with_probability_p_independently(p: float) -> None:
    torch.manual_seed(0)
    mask = keep_mask((1000, 1001), p, torch.float32)  # odd size: a partly used last word
    assert set(mask.unique().tolist()) <= {0.0, 1.0}
    kept = mask.mean().item()
    assert kept == pytest.approx(1 - p, abs=0.003)  # binomial sd ~ 0.0005
    # Neighbouring elements come from the lanes of one 64-bit word: still independent.
    both = (mask[:, :-1] * mask[:, 1:]).mean().item()
    assert both == pytest.approx((1 - p) ** 2, abs=0.004)
    rows = mask.mean(dim=1)
    assert rows.std().item() == pytest.approx(((1 - p) * p / 1001) ** 0.5, rel=0.15)
    assert abs(keep_probability(p) - (1 - p)) < 2**-15


def test_output_and_gradient_are_inverted_dropout() -> None:
    torch.manual_seed(1)
    layer = Dropout(0.3).train()
    x = torch.randn(512, 256, requires_grad=True)
    y = layer(x)
    kept = y != 0
    scale = 1 / keep_probability(0.3)
    assert torch.allclose(y[kept], x[kept] * scale)
    assert y.mean().item() == pytest.approx(x.mean().item(), abs=0.01)
    y.sum().backward()
    assert torch.allclose(x.grad, kept.float() * scale)


def test_seeded_eval_identity_and_edge_probabilities() -> None:
    x = torch.randn(64, 64)
    torch.manual_seed(5)
    a = Dropout(0.2)(x)
    torch.manual_seed(5)
    b = Dropout(0.2)(x)
    assert torch.equal(a, b)
    assert not torch.equal(a, Dropout(0.2)(x))
    assert torch.equal(Dropout(0.2).eval()(x), x)
    assert torch.equal(Dropout(0.0)(x), x)
    assert torch.equal(Dropout(1.0)(x), torch.zeros_like(x))
    half = torch.randn(32, 32, dtype=torch.bfloat16)
    assert Dropout(0.1)(half).dtype == torch.bfloat16


def test_models_use_it_and_keep_their_state_dict() -> None:
    model = create_model("res_tf", inputs="ALL", num_layers=2)
    dropouts = [m for m in model.modules() if isinstance(m, nn.Dropout)]
    assert dropouts and all(type(m) is Dropout for m in dropouts)
    assert type(model.transformer.layers[1].dropout1) is Dropout  # inside torch's layer
    plain = nn.Sequential(nn.Linear(3, 4), nn.Dropout(0.25), nn.Sequential(nn.Dropout(0.5)))
    keys = list(plain.state_dict())
    use_fast_dropout(plain)
    assert [type(m) for m in (plain[1], plain[2][0])] == [Dropout, Dropout]
    assert (plain[1].p, plain[2][0].p) == (0.25, 0.5)
    assert list(plain.state_dict()) == keys
