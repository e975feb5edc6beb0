"""Training-module pieces that were rewritten for speed must match their plain forms."""

import torch

from tactile_compliance.models import create_model
from tactile_compliance.training.module import sum_of_norms


def test_sum_of_norms_matches_autograd_norms() -> None:
    torch.manual_seed(0)
    params = [torch.randn(5, 3), torch.zeros(4), torch.randn(7, dtype=torch.float64)]
    fast = [p.clone().requires_grad_() for p in params]
    plain = [p.clone().requires_grad_() for p in params]
    value = sum_of_norms(fast)
    (2.5 * value).backward()
    reference = sum(p.norm(2) for p in plain)
    (2.5 * reference).backward()
    assert torch.allclose(value.double(), reference.double())
    for a, b in zip(fast, plain, strict=True):
        assert torch.allclose(a.grad, b.grad, atol=1e-6)
    assert torch.all(fast[1].grad == 0)  # an all-zero tensor gets no gradient (not NaN)
    check = [torch.randn(3, dtype=torch.float64, requires_grad=True),
             torch.randn(2, 2, dtype=torch.float64, requires_grad=True)]
    assert torch.autograd.gradcheck(lambda *x: sum_of_norms(list(x)), check)


def test_vgg_lstm_head_is_the_lstm_cell_recurrence() -> None:
    """The batched input projection must give nn.LSTMCell's exact recurrence."""
    torch.manual_seed(1)
    model = create_model("vgg_lstm", inputs="ALL").eval()
    features, force, width = torch.randn(4, 3, 4096), torch.rand(4, 3), torch.rand(4, 3)
    estimates = torch.rand(4, 2)
    constant = [model.estimate_encoder["elastic"](estimates[:, 0:1]),
                model.estimate_encoder["hertz"](estimates[:, 1:2])]
    hidden = torch.zeros(4, model.lstm.hidden_size)
    cell = torch.zeros_like(hidden)
    outputs = []
    for t in range(3):
        step = torch.cat([features[:, t], model.force_encoder(force[:, t : t + 1]),
                          model.width_encoder(width[:, t : t + 1]), *constant], dim=1)
        hidden, cell = model.lstm(step, (hidden, cell))
        outputs.append(model.output(hidden))
    expected = torch.cat(outputs, dim=1) @ torch.softmax(model.step_weights, dim=0)
    with torch.no_grad():
        got = model._head(features, force, width, estimates)
    assert torch.allclose(got, expected.detach(), atol=1e-6)
