"""Training-module pieces that were rewritten for speed must match their plain forms."""

import pytest
import torch

from tactile_compliance.data.normalisation import NormalisationConstants
from tactile_compliance.models import create_model
from tactile_compliance.models.vgg_lstm import project_steps
from tactile_compliance.runs.run_inputs import RunInputs
from tactile_compliance.training.module import (
    ComplianceModule,
    add_sum_of_norms_gradient,
    parameter_norms,
)


def test_sum_of_norms_gradient_matches_autograd() -> None:
    torch.manual_seed(0)
    params = [torch.randn(5, 3), torch.zeros(4), torch.randn(7, dtype=torch.float64)]
    fast = [p.clone().requires_grad_() for p in params]
    plain = [p.clone().requires_grad_() for p in params]
    norms = parameter_norms(fast)
    data_loss = sum((p * p).sum() for p in fast)  # some gradient already in .grad
    data_loss.backward()
    add_sum_of_norms_gradient(fast, norms, 2.5)
    reference = sum(p.norm(2) for p in plain)
    (sum((p * p).sum() for p in plain) + 2.5 * reference).backward()
    assert torch.allclose(torch.stack(norms).sum().double(), reference.double())
    for a, b in zip(fast, plain, strict=True):
        assert torch.allclose(a.grad, b.grad, atol=1e-6)
    assert torch.all(fast[1].grad == 0)  # an all-zero tensor gets no l2 gradient (not NaN)
    fresh = [torch.randn(3, requires_grad=True)]  # no data gradient yet: .grad is created
    add_sum_of_norms_gradient(fresh, parameter_norms(fresh), 1.0)
    assert torch.allclose(fresh[0].grad, fresh[0].detach() / fresh[0].detach().norm())


@pytest.mark.filterwarnings(r"ignore:You are trying to `self.log\(\)`")
@pytest.mark.parametrize("l2_weight", [0.0, 0.3])
def test_training_step_gradient_is_mse_plus_l2(l2_weight: float) -> None:
    """The module's step (loss.backward + on_after_backward) gives the gradient of
    MSE + l2_weight * sum_i ||p_i|| over the trainable (head) parameters."""
    torch.manual_seed(2)
    model = create_model("res_tf", inputs="ALL", num_layers=1, dim_feedforward=32).eval()
    module = ComplianceModule(
        model,
        RunInputs((224, 224), (224, 224), NormalisationConstants(), "ALL"),
        lr=1e-3,
        gamma=None,
        l2_weight=l2_weight,
        freeze_backbone=True,
    )
    batch = {
        "features": torch.randn(6, 3, model.feature_dim),
        "force": torch.rand(6, 3),
        "width": torch.rand(6, 3),
        "estimates": torch.rand(6, 2),
        "label": torch.rand(6),
    }
    loss = module.training_step(batch, 0)
    loss.backward()
    module.on_after_backward()
    got = [p.grad.clone() for p in module.trainable_parameters()]
    assert all(p.grad is None for p in model.backbone.parameters())
    module.zero_grad(set_to_none=True)
    prediction = model.forward_features(
        batch["features"], force=batch["force"], width=batch["width"], estimates=batch["estimates"]
    )
    reference = torch.mean((prediction - batch["label"]) ** 2)
    reference = reference + l2_weight * sum(p.norm(2) for p in module.trainable_parameters())
    reference.backward()
    assert torch.allclose(loss, reference)
    for a, p in zip(got, module.trainable_parameters(), strict=True):
        assert torch.allclose(a, p.grad, atol=1e-6)


def test_vgg_lstm_head_is_the_lstm_cell_recurrence() -> None:
    """The batched input projection must give nn.LSTMCell's exact recurrence."""
    torch.manual_seed(1)
    model = create_model("vgg_lstm", inputs="ALL").eval()
    features, force, width = torch.randn(4, 3, 4096), torch.rand(4, 3), torch.rand(4, 3)
    estimates = torch.rand(4, 2)
    constant = [
        model.estimate_encoder["elastic"](estimates[:, 0:1]),
        model.estimate_encoder["hertz"](estimates[:, 1:2]),
    ]
    hidden = torch.zeros(4, model.lstm.hidden_size)
    cell = torch.zeros_like(hidden)
    outputs = []
    for t in range(3):
        step = torch.cat(
            [
                features[:, t],
                model.force_encoder(force[:, t : t + 1]),
                model.width_encoder(width[:, t : t + 1]),
                *constant,
            ],
            dim=1,
        )
        hidden, cell = model.lstm(step, (hidden, cell))
        outputs.append(model.output(hidden))
    expected = torch.cat(outputs, dim=1) @ torch.softmax(model.step_weights, dim=0)
    with torch.no_grad():
        got = model._head(features, {"force": force, "width": width, "estimates": estimates})
    assert torch.allclose(got, expected.detach(), atol=1e-6)


@pytest.mark.parametrize("image_needs_grad", [False, True])
def test_vgg_lstm_step_projection_gradients_match_autograd(image_needs_grad: bool) -> None:
    """project_steps skips the image columns' input gradient only when nothing needs it."""
    torch.manual_seed(3)
    image = torch.randn(5, 3, 40, requires_grad=image_needs_grad)
    scalars = torch.randn(5, 3, 7, requires_grad=True)
    weight = torch.randn(16, 47, requires_grad=True)
    bias = torch.randn(16, requires_grad=True)
    out = project_steps(image, scalars, weight, bias)
    upstream = torch.randn_like(out)
    grads = torch.autograd.grad(
        out, [t for t in (image, scalars, weight, bias) if t.requires_grad], upstream
    )
    reference = torch.nn.functional.linear(torch.cat([image, scalars], -1), weight, bias)
    expected = torch.autograd.grad(
        reference, [t for t in (image, scalars, weight, bias) if t.requires_grad], upstream
    )
    assert torch.allclose(out, reference)
    for got, want in zip(grads, expected, strict=True):
        assert torch.allclose(got, want, atol=1e-5)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        half = project_steps(image, scalars, weight, bias)
    assert half.dtype == torch.bfloat16
    half_grad = torch.autograd.grad(half.float(), weight, upstream)[0]
    assert torch.allclose(half_grad, expected[-2], rtol=0.05, atol=0.5)
