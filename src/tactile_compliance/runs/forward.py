"""The one forward path from a data batch to a prediction.

Training, evaluation and the inference API all call :func:`forward_batch`, so frames are
always prepared the same way and cached features are used whenever a batch carries them.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset

from tactile_compliance.data.dataset import GraspDataset, batch_loader, prepare_frames
from tactile_compliance.data.normalisation import NormalisationConstants
from tactile_compliance.devices import DEFAULT_DEVICE, resolve_device


def forward_batch(
    model: torch.nn.Module,
    batch: Mapping[str, torch.Tensor],
    constants: NormalisationConstants,
    image_size: tuple[int, int] | None,
    augmentation: torch.nn.Module | None = None,
) -> torch.Tensor:
    """Normalised log10 modulus predictions (B,) for a batch from :class:`GraspDataset`."""
    scalars = {key: batch.get(key) for key in ("force", "width", "estimates")}
    if "features" in batch:
        return model.forward_features(batch["features"].float(), **scalars)
    frames = prepare_frames(batch["frames"], constants, image_size, augmentation)
    return model(frames, **scalars)


@torch.no_grad()
def predict_dataset(
    model: torch.nn.Module,
    dataset: Dataset,
    constants: NormalisationConstants,
    image_size: tuple[int, int] | None,
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
            outputs.append(forward_batch(model, batch, constants, image_size).float().cpu())
    finally:
        model.train(was_training)
    return torch.cat(outputs).numpy() if outputs else np.zeros(0, np.float32)
