"""The one forward path from a data batch to a prediction.

Training, evaluation, the feature cache and the inference API (PyTorch and ONNX) all call
:func:`model_arguments`, so every input is prepared the same way and cached features are
used whenever a batch carries them.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset

from tactile_compliance.data.dataset import GraspDataset, batch_loader, prepare_images
from tactile_compliance.devices import DEFAULT_DEVICE, resolve_device
from tactile_compliance.runs.run_inputs import RunInputs


def model_arguments(
    batch: Mapping[str, torch.Tensor],
    run_inputs: RunInputs,
    augmentation: torch.nn.Module | None = None,
) -> tuple[torch.Tensor | None, dict[str, torch.Tensor]]:
    """A batch of :class:`GraspDataset` (or ``input_checks.PreparedInputs``) as the model
    takes it: ``(images, scalars)``.

    ``images`` is the strategy's image input resized to ``run_inputs.image_size`` and
    normalised (``data.dataset.prepare_images``, (B, 3, 3, h, w)), or None for a
    frame-free strategy or a batch that carries cached ``features`` instead; ``scalars``
    maps the strategy's scalar inputs to their normalised (B, size) tensors.

    Raises:
        KeyError: the batch lacks one of the strategy's inputs.
    """
    strategy = run_inputs.inputs
    scalars = {name: batch[name] for name in strategy.scalar_names}
    image = strategy.image
    if image is None or "features" in batch:
        return None, scalars
    images = prepare_images(
        image.name, batch[image.name], run_inputs.constants, run_inputs.image_size, augmentation
    )
    return images, scalars


def forward_batch(
    model: torch.nn.Module,
    batch: Mapping[str, torch.Tensor],
    run_inputs: RunInputs,
    augmentation: torch.nn.Module | None = None,
) -> torch.Tensor:
    """Normalised log10 modulus predictions (B,) for a batch from :class:`GraspDataset`."""
    images, scalars = model_arguments(batch, run_inputs, augmentation)
    if "features" in batch:
        return model.forward_features(batch["features"].float(), **scalars)
    return model(images, **scalars)


@torch.no_grad()
def predict_dataset(
    model: torch.nn.Module,
    dataset: Dataset,
    run_inputs: RunInputs,
    *,
    batch_size: int = 64,
    device: str | torch.device = DEFAULT_DEVICE,
) -> np.ndarray:
    """Normalised predictions for every item of ``dataset``, in order (eval mode)."""
    device = resolve_device(device)
    was_training = model.training
    model.eval().to(device)
    outputs = []
    try:
        batches = (
            batch_loader(dataset, batch_size)
            if isinstance(dataset, GraspDataset)
            else DataLoader(dataset, batch_size=batch_size, shuffle=False)
        )
        for batch in batches:
            batch = {k: v.to(device) for k, v in batch.items()}
            outputs.append(forward_batch(model, batch, run_inputs).float().cpu())
    finally:
        model.train(was_training)
    return torch.cat(outputs).numpy() if outputs else np.zeros(0, np.float32)
