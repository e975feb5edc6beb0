"""The LightningModule: loss, optimiser, learning-rate schedule, validation N-MSE.

The loss's l2 term is the published code's (a sum of *unsquared* norms per tensor), not
PyTorch's ``weight_decay``. See docs/training.md, "What one run does", step 5.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import lightning as L
import torch

from tactile_compliance.data.normalisation import MISSING_SCALAR
from tactile_compliance.runs.forward import forward_batch
from tactile_compliance.runs.run_inputs import RunInputs

#: Where a training checkpoint keeps the augmentation generator's state.
AUGMENTATION_RNG_KEY = "augmentation_rng_state"
#: Where it keeps the generator that picks the grasps whose estimates are hidden.
ESTIMATE_DROPOUT_RNG_KEY = "estimate_dropout_rng_state"


@torch.no_grad()
def parameter_norms(params: list[torch.nn.Parameter]) -> list[torch.Tensor]:
    """``||p_i||_2`` of every parameter tensor (no gradient): the l2 term is their sum."""
    return list(torch._foreach_norm(params)) if params else []


@torch.no_grad()
def add_sum_of_norms_gradient(
    params: list[torch.nn.Parameter], norms: list[torch.Tensor], weight: float
) -> None:
    """Add the gradient of ``weight * sum_i ||p_i||_2``, ``weight * p_i / ||p_i||``, to
    every ``p_i.grad`` in place (zero for an all-zero tensor): one pass instead of
    differentiating the term (benchmarks/README.md, "What made the heads faster").
    """
    for param, norm in zip(params, torch.stack(norms).tolist() if norms else [], strict=True):
        # An all-zero tensor has no l2 gradient (autograd's norm gives it 0 as well).
        scale = weight / norm if norm > 0 else 0.0
        if param.grad is None:
            param.grad = param.detach() * scale
        elif scale != 0.0:
            param.grad.add_(param.detach(), alpha=scale)


def last_block(backbone: torch.nn.Module) -> torch.nn.Module:
    """The backbone's last child module that has parameters (ResNet ``layer4``, VGG's
    ``classifier`` (fc6/fc7), Top10NN's ``fc``): what ``finetune: last_block`` trains."""
    with_parameters = [m for m in backbone.children() if any(True for _ in m.parameters())]
    if not with_parameters:
        raise ValueError(f"{type(backbone).__name__} has no trainable block")
    return with_parameters[-1]


class ComplianceModule(L.LightningModule):
    """Wraps a compliance model for training; validation logs ``val_nmse`` per epoch.

    ``estimate_dropout``: the share of training grasps (drawn per batch, with a generator
    seeded by ``seed``, so a resumed run draws as an uninterrupted one) whose analytical
    inputs are set to ``MISSING_SCALAR``, what a NaN estimate becomes; validation and
    test see them all.
    """

    def __init__(
        self,
        model: torch.nn.Module,
        run_inputs: RunInputs,
        *,
        lr: float,
        gamma: float | None,
        l2_weight: float,
        augmentation: torch.nn.Module | None = None,
        freeze_backbone: bool = False,
        finetune: str = "all",
        compile_model: bool = False,
        estimate_dropout: float = 0.0,
        seed: int = 0,
    ) -> None:
        super().__init__()
        self.model = model
        self.run_inputs = run_inputs
        self.lr = lr
        self.gamma = gamma
        self.l2_weight = l2_weight
        self.augmentation = augmentation
        self.freeze_backbone = freeze_backbone
        if freeze_backbone:
            for parameter in model.backbone.parameters():
                parameter.requires_grad_(False)
        elif finetune == "last_block":
            trainable = {id(p) for p in last_block(model.backbone).parameters()}
            for parameter in model.backbone.parameters():
                parameter.requires_grad_(id(parameter) in trainable)
        # Compile the forward only; the state dict keeps the plain model's key names.
        self._forward_model: Callable[..., Any] = (
            torch.compile(model) if compile_model else model  # type: ignore[assignment]
        )
        self._val_squared_errors: list[torch.Tensor] = []
        self._l2_norms: list[torch.Tensor] | None = None
        if bool(estimate_dropout) != run_inputs.missing_estimates:
            raise ValueError(  # the checkpoint would promise what training did not do
                f"estimate_dropout={estimate_dropout} but run_inputs.missing_estimates="
                f"{run_inputs.missing_estimates}: they are one setting (RunInputs.resolve)"
            )
        self.estimate_dropout = float(estimate_dropout)
        self._dropout_generator = torch.Generator().manual_seed(int(seed))
        self._reset_epoch_state()

    def _frozen_backbone_prefixes(self) -> tuple[str, ...]:
        """State-dict key prefixes of the backbone (also under a torch.compile wrapper)."""
        return tuple(
            f"{name}."
            for name, module in self.named_modules(remove_duplicate=False)
            if module is self.model.backbone
        )

    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        # The augmentation's own generator (seeded per run): a resumed run must draw the
        # same augmentations as an uninterrupted one.
        generator = getattr(self.augmentation, "generator", None)
        if generator is not None:
            checkpoint[AUGMENTATION_RNG_KEY] = generator.get_state()
        if self.estimate_dropout:
            checkpoint[ESTIMATE_DROPOUT_RNG_KEY] = self._dropout_generator.get_state()
        # A frozen backbone is rebuilt by train() on resume (fixed seed or weights file),
        # so last.ckpt leaves it out: 0.53 GB less per save for VGG16.
        if self.freeze_backbone:
            prefixes = self._frozen_backbone_prefixes()
            checkpoint["state_dict"] = {
                k: v for k, v in checkpoint["state_dict"].items() if not k.startswith(prefixes)
            }

    def on_load_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        generator = getattr(self.augmentation, "generator", None)
        if generator is not None and AUGMENTATION_RNG_KEY in checkpoint:
            generator.set_state(checkpoint[AUGMENTATION_RNG_KEY])
        if ESTIMATE_DROPOUT_RNG_KEY in checkpoint:
            self._dropout_generator.set_state(checkpoint[ESTIMATE_DROPOUT_RNG_KEY])
        # Put this module's own frozen backbone tensors back so Lightning's strict load
        # still checks every head key; a checkpoint that has them (older runs) keeps its.
        if self.freeze_backbone:
            prefixes = self._frozen_backbone_prefixes()
            state = checkpoint["state_dict"]
            for key, value in self.state_dict().items():
                if key.startswith(prefixes):
                    state.setdefault(key, value)

    def trainable_parameters(self) -> list[torch.nn.Parameter]:
        return [p for p in self.model.parameters() if p.requires_grad]

    def on_train_epoch_start(self) -> None:
        # A frozen backbone keeps its BatchNorm statistics: eval mode inside train mode.
        if self.freeze_backbone:
            self.model.backbone.eval()
        self._reset_epoch_state()

    def _reset_epoch_state(self) -> None:
        # Per-step bookkeeping is kept out of Lightning: listing the parameters walks every
        # backbone module, and each self.log() call costs ~0.6 ms (benchmarks/README.md).
        self._trainable: list[torch.nn.Parameter] = self.trainable_parameters()
        self._train_sums = torch.zeros(2, dtype=torch.float64, device=self.device)
        self._train_count = 0

    def on_train_epoch_end(self) -> None:
        if self._train_count:
            mse, loss = (self._train_sums / self._train_count).float()
            self.log("train_mse", mse)
            self.log("train_loss", loss, prog_bar=True)

    def _predict(self, batch: dict[str, torch.Tensor], augment: bool) -> torch.Tensor:
        return forward_batch(
            self._forward_model,  # type: ignore[arg-type]
            batch,
            self.run_inputs,
            self.augmentation if augment else None,
        )

    def _hide_estimates(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """The batch with the analytical inputs of a random ``estimate_dropout`` share of
        its grasps set to ``MISSING_SCALAR`` (a new dict: the batch's tensors may be views
        of the cached inputs, which later epochs read again)."""
        names = self.run_inputs.analytical_inputs
        if not self.estimate_dropout or not names:
            return batch
        draws = torch.rand(len(batch["label"]), generator=self._dropout_generator)
        hidden = (draws < self.estimate_dropout).to(batch["label"].device)[:, None]
        out = dict(batch)
        for name in names:
            out[name] = torch.where(
                hidden, torch.full_like(batch[name], MISSING_SCALAR), batch[name]
            )
        return out

    def training_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        batch = self._hide_estimates(batch)
        prediction = self._predict(batch, augment=True).float()
        mse = torch.mean((prediction - batch["label"]) ** 2)
        loss = mse
        if self.l2_weight > 0:
            # The l2 term's value is logged with the loss; its gradient is added in place
            # after the backward pass (on_after_backward), which is much cheaper than
            # differentiating it. The parameters do not change in between.
            self._l2_norms = parameter_norms(self._trainable)
            loss = mse + self.l2_weight * torch.stack(self._l2_norms).sum()
        # Epoch means weighted by batch size (what self.log(on_epoch=True) computed).
        size = len(prediction)
        self._train_sums += torch.stack([mse.detach(), loss.detach()]).double() * size
        self._train_count += size
        return loss

    def on_after_backward(self) -> None:
        # Lightning calls this after loss.backward(), before the optimiser step. Exact for
        # the precisions the config allows ("32", "bf16-mixed"): neither scales the loss.
        if self._l2_norms is not None:
            add_sum_of_norms_gradient(self._trainable, self._l2_norms, self.l2_weight)
            self._l2_norms = None

    def transfer_batch_to_device(
        self, batch: Any, device: torch.device, dataloader_idx: int
    ) -> Any:
        # Our batches are flat dicts of tensors; Lightning's generic collection walk took
        # ~1 ms per step.
        if isinstance(batch, dict) and all(isinstance(v, torch.Tensor) for v in batch.values()):
            return {key: value.to(device) for key, value in batch.items()}
        return super().transfer_batch_to_device(batch, device, dataloader_idx)

    def validation_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> None:
        prediction = self._predict(batch, augment=False).float()
        self._val_squared_errors.append(((prediction - batch["label"]) ** 2).detach())

    def on_validation_epoch_end(self) -> None:
        if not self._val_squared_errors:
            return
        # Epoch-level N-MSE over all validation samples (not a mean of batch means).
        nmse = torch.cat(self._val_squared_errors).mean()
        self._val_squared_errors.clear()
        self.log("val_nmse", nmse, prog_bar=True)

    def configure_optimizers(self) -> Any:
        params = self.trainable_parameters()
        # The fused kernel updates every tensor in one pass (about 2x faster than the
        # default multi-tensor path on a CPU); it needs floating-point CPU/CUDA tensors.
        fused = all(p.is_floating_point() and p.device.type in ("cpu", "cuda") for p in params)
        optimizer = torch.optim.Adam(params, lr=self.lr, fused=fused or None)
        if self.gamma is None:
            return optimizer
        scheduler = torch.optim.lr_scheduler.StepLR(optimizer, step_size=1, gamma=self.gamma)
        return {
            "optimizer": optimizer,
            "lr_scheduler": {"scheduler": scheduler, "interval": "epoch"},
        }
