"""Self-describing model checkpoints (``model.pt``).

A checkpoint holds everything needed to use the model without the run directory or
the config file: weights, model name, hyperparameters, input strategy, normalisation
constants, the frame size the model was trained at, the data/split/training
configuration, the seed, which backbone weights were used and the package version.
It contains only tensors and plain Python values, so it loads with
``torch.load(weights_only=True)``: no pickled code is ever executed.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from tactile_compliance import __version__
from tactile_compliance.data.normalisation import NormalisationConstants
from tactile_compliance.models import create_model

CHECKPOINT_FORMAT = "tactile-compliance-model"
CHECKPOINT_VERSION = 1


@dataclass
class LoadedModel:
    """A model rebuilt from a checkpoint plus what it needs for its input pipeline."""

    model: torch.nn.Module
    constants: NormalisationConstants
    image_size: tuple[int, int] | None
    inputs: str
    meta: dict[str, Any]


def save_checkpoint(
    path: str | Path,
    model: torch.nn.Module,
    *,
    constants: NormalisationConstants,
    image_size: tuple[int, int] | None,
    config: dict[str, Any],
    seed: int,
    metrics: dict[str, Any] | None = None,
) -> Path:
    """Write ``model`` and its description to ``path`` (atomically)."""
    path = Path(path)
    payload = {
        "format": CHECKPOINT_FORMAT,
        "format_version": CHECKPOINT_VERSION,
        "package_version": __version__,
        "model_name": model.model_name,
        "inputs": model.inputs.value,
        "hparams": dict(model.hparams),
        "backbone_weights": str(getattr(model, "backbone_weights", "none")),
        "normalisation": constants.to_dict(),
        "image_size": list(image_size) if image_size is not None else None,
        "config": config,
        "seed": int(seed),
        "metrics": metrics or {},
        "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()},
    }
    tmp = path.with_name(path.name + ".tmp")
    torch.save(payload, tmp)
    tmp.replace(path)
    return path


def load_checkpoint(path: str | Path, device: str | torch.device = "cpu") -> LoadedModel:
    """Rebuild a model from a checkpoint written by :func:`save_checkpoint` (eval mode)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: checkpoint not found")
    try:
        payload = torch.load(path, map_location=device, weights_only=True)
    except Exception as err:  # torch raises several types for foreign/corrupt files
        raise ValueError(f"{path}: not a readable tactile-compliance checkpoint ({err})") from err
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        raise ValueError(f"{path}: not a tactile-compliance model checkpoint")
    if int(payload.get("format_version", 0)) > CHECKPOINT_VERSION:
        raise ValueError(f"{path}: checkpoint format is newer than this package; upgrade it")
    # Backbone weights come from the state dict: never download while loading.
    model = create_model(payload["model_name"], inputs=payload["inputs"], **payload["hparams"])
    model.load_state_dict(payload["state_dict"])
    model.backbone_weights = payload.get("backbone_weights", "none")
    model.to(device).eval()
    image_size = payload.get("image_size")
    meta = {k: v for k, v in payload.items() if k != "state_dict"}
    return LoadedModel(
        model=model,
        constants=NormalisationConstants.from_dict(payload["normalisation"]),
        image_size=tuple(image_size) if image_size else None,
        inputs=payload["inputs"],
        meta=meta,
    )
