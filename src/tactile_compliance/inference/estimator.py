"""The task-level inference API: a checkpoint in, Young's modulus in Pa out.

```python
from tactile_compliance.inference import ComplianceEstimator

estimator = ComplianceEstimator.from_checkpoint("runs/RUN/best.pt")
result = estimator.predict(frames, force=[8.1, 31.0, 58.7], width=[0.050, 0.047, 0.044])
result.modulus_pa, result.log10_modulus_pa
```

The estimator owns no preprocessing of its own: input checks and scalar normalisation are
in :mod:`tactile_compliance.inference.inputs` (built on the normalisation functions used in
training), and the forward pass is :func:`tactile_compliance.runs.forward.forward_batch`,
the function training, validation and ``evaluate`` call. A checkpoint therefore gives the
same numbers here as on the evaluation path.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from tactile_compliance.data.normalisation import NormalisationConstants, denormalise_modulus
from tactile_compliance.inference.inputs import PreparedInputs, prepare_inputs, required_inputs
from tactile_compliance.models import InputStrategy
from tactile_compliance.runs.checkpoint import load_checkpoint
from tactile_compliance.runs.forward import forward_batch

if TYPE_CHECKING:
    from tactile_compliance.inference.streaming import StreamingEstimator

__all__ = ["ComplianceEstimator", "Prediction", "resolve_checkpoint"]

#: File name of a run's best checkpoint (``training.train.BEST_FILE``); a run directory
#: is accepted wherever a checkpoint path is.
BEST_CHECKPOINT = "best.pt"


def resolve_checkpoint(path: str | Path) -> Path:
    """A checkpoint file, or a run directory holding ``best.pt`` -> the checkpoint file."""
    path = Path(path)
    if path.is_dir():
        candidate = path / BEST_CHECKPOINT
        if not candidate.is_file():
            raise FileNotFoundError(f"{path}: run directory without {BEST_CHECKPOINT}")
        return candidate
    if not path.is_file():
        raise FileNotFoundError(f"{path}: checkpoint not found")
    return path


@dataclass(frozen=True)
class Prediction:
    """Young's modulus predicted for one grasp (floats) or a batch (arrays of shape (B,)).

    Attributes:
        modulus_pa: Young's modulus E in Pa.
        log10_modulus_pa: log10 of E in Pa (the scale errors are measured on, in decades).
        normalised: the model's raw output y in (0, 1), ``(log10 E - lo) / (hi - lo)`` with
            the checkpoint's label range.
    """

    modulus_pa: Any
    log10_modulus_pa: Any
    normalised: Any

    @property
    def batched(self) -> bool:
        """Whether this is a batch (arrays) rather than one grasp (floats)."""
        return isinstance(self.modulus_pa, np.ndarray)

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-serialisable values (lists for a batch)."""

        def plain(value: Any) -> Any:
            return value.tolist() if isinstance(value, np.ndarray) else float(value)

        return {
            "modulus_pa": plain(self.modulus_pa),
            "log10_modulus_pa": plain(self.log10_modulus_pa),
            "normalised": plain(self.normalised),
        }

    @classmethod
    def from_normalised(
        cls, y: np.ndarray, constants: NormalisationConstants, single: bool
    ) -> Prediction:
        """Read model outputs ``y`` (B,) back to Pa with the checkpoint's constants."""
        y = np.asarray(y, dtype=np.float64)
        modulus = np.asarray(denormalise_modulus(y, constants), dtype=np.float64)
        log10 = np.log10(modulus)
        if single:
            return cls(float(modulus[0]), float(log10[0]), float(y[0]))
        return cls(modulus, log10, y)


def _training_store_size(meta: dict[str, Any]) -> tuple[int, int] | None:
    """Frame size of the store a checkpoint was trained on, when that store is still there.

    A checkpoint without ``image_size`` was trained at its store's native resolution;
    inputs of another size are resized to it instead of silently being fed at the wrong
    scale. Checkpoints record that size (``store_image_size``); older ones only name the
    store, whose header is read when it is still there.
    """
    recorded = meta.get("store_image_size")
    if recorded:
        return int(recorded[0]), int(recorded[1])
    store = (meta.get("config") or {}).get("data", {}).get("store")
    if not store:
        return None
    header = Path(store) / "header.json"
    try:
        size = json.loads(header.read_text())["image_size"]
        return int(size[0]), int(size[1])
    except (OSError, ValueError, KeyError, TypeError, IndexError):
        return None


class ComplianceEstimator:
    """A trained model plus its own preprocessing: predicts Young's modulus in Pa.

    Build it with :meth:`from_checkpoint`. ``predict`` accepts one grasp or a batch,
    validates everything (``ValueError`` with a clear message on bad input) and applies
    the checkpoint's frame size and normalisation constants.
    """

    def __init__(
        self,
        model: torch.nn.Module,
        constants: NormalisationConstants,
        image_size: tuple[int, int] | None,
        *,
        meta: dict[str, Any] | None = None,
        device: str | torch.device = "cpu",
        source: str | None = None,
    ) -> None:
        self.device = torch.device(device)
        self.model = model.to(self.device).eval()
        self.constants = constants
        self.image_size = tuple(image_size) if image_size is not None else None
        self.meta = dict(meta or {})
        self.source = source or "<in memory>"
        self.inputs: InputStrategy = InputStrategy.parse(model.inputs)
        #: (H, W) px of the store the model was trained on, when known: readers of raw
        #: sources (grasp directories, videos) resize to it with the importer's function
        #: first, so frames take the same path as at import time.
        self.store_image_size: tuple[int, int] | None = None

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_checkpoint(
        cls,
        path: str | Path,
        device: str | torch.device = "cpu",
        *,
        backbone_weights: str | Path | None = None,
    ) -> ComplianceEstimator:
        """Load a ``best.pt`` checkpoint (or a run directory holding one).

        Loading never executes pickled code (``weights_only=True``) and never downloads
        backbone weights. A checkpoint of a frozen-backbone run stores the head only and
        rebuilds the backbone from its recorded seed or weights file (``imagenet``: the
        torch.hub cache); ``backbone_weights`` names a local copy of that file instead.
        """
        file = resolve_checkpoint(path)
        loaded = load_checkpoint(file, device=device, backbone_weights=backbone_weights)
        store_size = _training_store_size(loaded.meta)
        estimator = cls(
            loaded.model,
            loaded.constants,
            loaded.image_size or store_size,
            meta=loaded.meta,
            device=device,
            source=str(file),
        )
        estimator.store_image_size = store_size
        return estimator

    # ------------------------------------------------------------------ description
    @property
    def model_name(self) -> str:
        """Registry name of the model (``top10nn``, ``vgg_lstm``, ``res_tf``)."""
        return str(getattr(self.model, "model_name", type(self.model).__name__))

    @property
    def required_inputs(self) -> tuple[str, ...]:
        """Scalar inputs ``predict`` needs besides the frames, e.g. ``("force", "width")``."""
        return required_inputs(self.inputs)

    @property
    def min_frame_size(self) -> int:
        """Smallest accepted frame side in pixels (1 when the checkpoint resizes frames)."""
        if self.image_size is not None:
            return 1
        return int(getattr(self.model, "min_image_size", 1))

    def describe(self) -> dict[str, Any]:
        """What the estimator is: model, strategy, frame size, label range, provenance."""
        lo, hi = self.constants.label_range_pa
        return {
            "checkpoint": self.source,
            "model": self.model_name,
            "inputs": self.inputs.value,
            "required_inputs": ["frames", *self.required_inputs],
            "image_size": list(self.image_size) if self.image_size else None,
            "label_range_pa": [lo, hi],
            "backbone_weights": str(getattr(self.model, "backbone_weights", "none")),
            "seed": self.meta.get("seed"),
            "package_version": self.meta.get("package_version"),
            "device": str(self.device),
        }

    def __repr__(self) -> str:
        size = "x".join(map(str, self.image_size)) if self.image_size else "native"
        return (
            f"ComplianceEstimator({self.model_name}, inputs={self.inputs.value}, "
            f"image_size={size}, checkpoint={self.source!r})"
        )

    # ------------------------------------------------------------------ prediction
    def prepare(
        self,
        frames: Any,
        force: Any = None,
        width: Any = None,
        estimates: Any = None,
        *,
        channel_order: str = "RGB",
    ) -> PreparedInputs:
        """Validate and normalise inputs (what ``predict`` runs first); see ``inputs``."""
        return prepare_inputs(
            frames,
            {"force": force, "width": width, "estimates": estimates},
            inputs=self.inputs,
            constants=self.constants,
            min_size=self.min_frame_size,
            channel_order=channel_order,
            describe=f"checkpoint {self.source} ({self.model_name})",
        )

    @torch.no_grad()
    def predict_prepared(self, prepared: PreparedInputs, batch_size: int = 64) -> np.ndarray:
        """Normalised outputs y (B,) of a prepared batch, through ``forward_batch``."""
        if batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size}")
        outputs = []
        for chunk in prepared.chunks(batch_size):
            chunk = {key: value.to(self.device) for key, value in chunk.items()}
            y = forward_batch(self.model, chunk, self.constants, self.image_size)
            outputs.append(y.float().cpu().numpy())
        return np.concatenate(outputs)

    def predict(
        self,
        frames: Any,
        force: Any = None,
        width: Any = None,
        estimates: Any = None,
        *,
        channel_order: str = "RGB",
        batch_size: int = 64,
    ) -> Prediction:
        """Young's modulus of one grasp or a batch.

        Args:
            frames: three difference images ``(3, H, W, 3)`` or a batch
                ``(B, 3, H, W, 3)``; uint8 or float in [0, 1]; RGB unless ``channel_order``.
            force: normal force in N at the three frames, ``(3,)`` / ``(B, 3)``
                (required by ImageF, ImageFW, ALL).
            width: gripper width in m at the three frames (required by ImageFW, ALL).
            estimates: (elastic E, Hertz E*) in Pa, ``(2,)`` / ``(B, 2)`` (required by ALL).
            channel_order: ``"RGB"`` (store order) or ``"BGR"`` (OpenCV).
            batch_size: grasps per forward pass (memory bound, not a result change).

        Returns:
            :class:`Prediction` with floats for one grasp, (B,) arrays for a batch.

        Raises:
            ValueError: bad shapes, dtypes, ranges, NaN, or an input the checkpoint's
                strategy needs is missing.
        """
        prepared = self.prepare(frames, force, width, estimates, channel_order=channel_order)
        y = self.predict_prepared(prepared, batch_size=batch_size)
        return Prediction.from_normalised(y, self.constants, prepared.single)

    # ------------------------------------------------------------------ streaming
    def stream(self, **options: Any) -> StreamingEstimator:
        """A :class:`~tactile_compliance.inference.streaming.StreamingEstimator` on this model.

        Options are those of ``StreamingEstimator`` (``window``, ``frame_kind``,
        ``reference``, ``estimates_pa``, thresholds).
        """
        from tactile_compliance.inference.streaming import StreamingEstimator

        return StreamingEstimator(self, **options)
