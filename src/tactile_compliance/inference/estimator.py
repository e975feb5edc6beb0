"""``ComplianceEstimator``: a PyTorch checkpoint in, Young's modulus in Pa out.

The forward pass is ``runs.forward.forward_batch``, the evaluation path's. See
docs/inference.md.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from tactile_compliance.data.store import HEADER_FILE
from tactile_compliance.devices import DEFAULT_DEVICE, resolve_device
from tactile_compliance.inference.base import BaseEstimator
from tactile_compliance.runs.checkpoint import load_checkpoint
from tactile_compliance.runs.forward import forward_batch
from tactile_compliance.runs.layout import BEST_FILE
from tactile_compliance.runs.output_calibration import CALIBRATION_KEY, OutputCalibration
from tactile_compliance.runs.run_inputs import RunInputs

if TYPE_CHECKING:
    from tactile_compliance.inference.streaming import StreamingEstimator

__all__ = ["ComplianceEstimator", "resolve_checkpoint"]


def resolve_checkpoint(path: str | Path) -> Path:
    """A checkpoint file, or a run directory holding ``best.pt`` -> the checkpoint file.

    Raises:
        FileNotFoundError: no such file, a directory without ``best.pt`` (a store given in
            the checkpoint's place is named as such).
        ValueError: an ONNX export, which only ``OnnxEstimator`` runs.
    """
    path = Path(path)
    if path.is_dir():
        candidate = path / BEST_FILE
        if not candidate.is_file():
            if (path / HEADER_FILE).is_file():
                raise FileNotFoundError(
                    f"{path} is a GraspStore, not a checkpoint: give the checkpoint first, "
                    f"then the store (predict CHECKPOINT SOURCE)"
                )
            raise FileNotFoundError(f"{path}: run directory without {BEST_FILE}")
        return candidate
    if not path.is_file():
        raise FileNotFoundError(f"{path}: checkpoint not found")
    if path.suffix.lower() == ".onnx":
        raise ValueError(
            f"{path} is an ONNX export: run it with OnnxEstimator in Python (docs/inference.md, "
            f'"ONNX export"); this command takes best.pt, a run directory or an '
            f"`export --safetensors` directory"
        )
    return path


def _size(size: tuple[int, int] | None) -> list[int] | None:
    return None if size is None else list(size)


class ComplianceEstimator(BaseEstimator):
    """A trained PyTorch model plus its own preprocessing: predicts Young's modulus in Pa.

    Build it with :meth:`from_checkpoint` (a ``best.pt``) or :meth:`from_pretrained` (an
    exported safetensors directory); ``run_inputs`` is the checkpoint's record.
    """

    kind = "checkpoint"

    def __init__(
        self,
        model: torch.nn.Module,
        run_inputs: RunInputs,
        *,
        meta: dict[str, Any] | None = None,
        device: str | torch.device = DEFAULT_DEVICE,
        source: str | None = None,
    ) -> None:
        self.device = torch.device(resolve_device(device))
        self.model = model.to(self.device).eval()
        self.run_inputs = run_inputs
        self.meta = dict(meta or {})
        self.source = source or "<in memory>"
        # `adapt`'s map of the model's log10 prediction onto a rig's reference objects,
        # applied to every prediction (runs.output_calibration); None: the model's own.
        recorded = self.meta.get(CALIBRATION_KEY)
        self.calibration: OutputCalibration | None = (
            None if recorded is None else OutputCalibration.from_dict(recorded, self.source)
        )

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_checkpoint(
        cls,
        path: str | Path,
        device: str | torch.device = DEFAULT_DEVICE,
        *,
        backbone_weights: str | Path | None = None,
    ) -> ComplianceEstimator:
        """Load a ``best.pt`` checkpoint (or a run directory holding one).

        Loading never executes pickled code (``weights_only=True``) and never downloads.
        ``backbone_weights``: a local copy of a frozen backbone's weights file (see
        docs/inference.md, "Command line").
        """
        file = resolve_checkpoint(path)
        device = resolve_device(device)
        loaded = load_checkpoint(file, device=device, backbone_weights=backbone_weights)
        return cls(
            loaded.model, loaded.run_inputs, meta=loaded.meta, device=device, source=str(file)
        )

    @classmethod
    def from_pretrained(
        cls, path: str | Path, device: str | torch.device = DEFAULT_DEVICE
    ) -> ComplianceEstimator:
        """Load a directory written by ``tactile-compliance export CHECKPOINT --safetensors DIR``.

        Nothing is downloaded; needs ``safetensors`` (docs/inference.md, "Deployable
        weights").

        Raises:
            FileNotFoundError: no such directory, or ``config.json`` or
                ``model.safetensors`` missing.
            SafetensorsMissingError: ``safetensors`` is not installed.
            ValueError: weights that do not fit the model ``config.json`` describes.
        """
        from tactile_compliance.inference.pretrained import load_pretrained

        device = resolve_device(device)
        loaded = load_pretrained(path, device=device)
        return cls(
            loaded.model, loaded.run_inputs, meta=loaded.meta, device=device, source=str(path)
        )

    @classmethod
    def load(
        cls,
        path: str | Path,
        device: str | torch.device = DEFAULT_DEVICE,
        *,
        backbone_weights: str | Path | None = None,
    ) -> ComplianceEstimator:
        """A checkpoint (``best.pt`` or a run directory, :meth:`from_checkpoint`) or a
        directory of ``export --safetensors`` (:meth:`from_pretrained`), told by its files:
        what ``predict`` and ``live`` accept."""
        from tactile_compliance.inference.pretrained import WEIGHTS_FILE

        if (Path(path) / WEIGHTS_FILE).is_file():
            return cls.from_pretrained(path, device=device)
        return cls.from_checkpoint(path, device=device, backbone_weights=backbone_weights)

    def save_pretrained(self, path: str | Path, *, license: str = "other") -> dict[str, Any]:
        """Write what ``export --safetensors DIR`` writes, for :meth:`from_pretrained`.

        ``path``: new, empty or an earlier export. The estimator must come from a file,
        whose sha256 the card records. ``license``: an SPDX identifier (``other``: the
        weights follow the licence of their training data).

        Returns:
            ``out``, ``files`` (name -> bytes), ``config`` (what ``config.json`` holds).
        """
        from tactile_compliance.inference.pretrained import (
            WEIGHTS_FILE,
            run_evaluation,
            write_pretrained,
        )

        source = Path(self.source)
        checkpoint = source / WEIGHTS_FILE if source.is_dir() else source
        if not checkpoint.is_file():
            raise ValueError(
                f"{self.source}: an estimator not loaded from a file cannot be saved "
                "(its checkpoint is recorded); use from_checkpoint or from_pretrained"
            )
        # A run's best.pt: the card shows the run's metrics.
        evaluation = run_evaluation(checkpoint) if checkpoint.suffix == ".pt" else None
        return write_pretrained(
            self, path, checkpoint=checkpoint, evaluation=evaluation, license=license
        )

    # ------------------------------------------------------------------ description
    @property
    def model_name(self) -> str:
        """The model's registry name (its class name for a model without one)."""
        return str(getattr(self.model, "model_name", type(self.model).__name__))

    def describe(self) -> dict[str, Any]:
        """What the estimator is: model, strategy, frame size, label range, provenance."""
        lo, hi = self.constants.label_range_pa
        return {
            "checkpoint": self.source,
            "model": self.model_name,
            "inputs": self.inputs.value,
            "required_inputs": list(self.required_inputs),
            "image_size": _size(self.run_inputs.image_size),
            "label_range_pa": [lo, hi],
            "backbone_weights": str(getattr(self.model, "backbone_weights", "none")),
            "seed": self.meta.get("seed"),
            "package_version": self.meta.get("package_version"),
            "run_inputs": self.run_inputs.to_dict(),
            "device": str(self.device),
            "output_calibration": None if self.calibration is None else self.calibration.to_dict(),
        }

    def __repr__(self) -> str:
        size = "x".join(map(str, self.run_inputs.image_size or ("none",)))
        return (
            f"ComplianceEstimator({self.model_name}, inputs={self.inputs.value}, "
            f"image_size={size}, checkpoint={self.source!r})"
        )

    # ------------------------------------------------------------------ prediction
    @torch.no_grad()
    def _forward(self, chunk: dict[str, torch.Tensor]) -> np.ndarray:
        """Normalised outputs of one prepared chunk, through ``forward_batch``."""
        chunk = {key: value.to(self.device) for key, value in chunk.items()}
        y = forward_batch(self.model, chunk, self.run_inputs)
        out = y.float().cpu().numpy()
        if self.calibration is not None:
            out = self.calibration.apply_normalised(out, self.constants)
        return out

    # ------------------------------------------------------------------ streaming
    def stream(self, **options: Any) -> StreamingEstimator:
        """A :class:`~tactile_compliance.inference.streaming.StreamingEstimator` on this model
        (``options``: its ``window``, ``frame_kind``, ``reference``, ``estimates_pa``, ...)."""
        from tactile_compliance.inference.streaming import StreamingEstimator

        return StreamingEstimator(self, **options)
