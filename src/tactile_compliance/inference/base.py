"""The ``predict`` API every estimator shares: checks, normalisation, read-back to Pa.

Subclasses only run the network (:meth:`BaseEstimator._forward`). See docs/inference.md,
"One preprocessing path" and "ONNX export".
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import torch

from tactile_compliance.data.normalisation import NormalisationConstants, denormalise_modulus
from tactile_compliance.inference.input_checks import prepare_inputs
from tactile_compliance.models import InputStrategy
from tactile_compliance.runs.run_inputs import RunInputs

__all__ = ["BaseEstimator", "Prediction", "to_plain"]


def to_plain(value: Any) -> Any:
    """A result value as plain JSON: a list for an array (a batch), a float otherwise."""
    return value.tolist() if isinstance(value, np.ndarray) else float(value)


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
        return {
            "modulus_pa": to_plain(self.modulus_pa),
            "log10_modulus_pa": to_plain(self.log10_modulus_pa),
            "normalised": to_plain(self.normalised),
        }

    @classmethod
    def from_normalised(
        cls, y: np.ndarray, constants: NormalisationConstants, single: bool
    ) -> Prediction:
        """Read model outputs ``y`` (B,) back to Pa with the checkpoint's constants."""
        y = np.asarray(y, dtype=np.float64)
        if not np.all(np.isfinite(y)):
            # The last line of defence: loaded weights and constants are checked, inputs
            # too; a NaN here means a broken model, and no NaN may leave as an estimate.
            raise ValueError(
                f"the model produced {int(np.sum(~np.isfinite(y)))} non-finite output(s) "
                f"(NaN or inf); its weights or inputs are broken, no estimate is given"
            )
        modulus = np.asarray(denormalise_modulus(y, constants), dtype=np.float64)
        log10 = np.log10(modulus)
        if single:
            return cls(float(modulus[0]), float(log10[0]), float(y[0]))
        return cls(modulus, log10, y)


class BaseEstimator(ABC):
    """A network plus the checkpoint's preprocessing: predicts Young's modulus in Pa.

    Subclasses set the attributes below when they load and implement :meth:`_forward`.

    Attributes:
        run_inputs: the run's input record (``runs.run_inputs.RunInputs``): frame sizes,
            normalisation constants, input strategy, sensor and analytical estimator.
        source: where the network was loaded from (named in error messages).
        meta: what the checkpoint recorded (seed, package version, ...).
    """

    #: How error messages name this kind of estimator, before its source.
    kind: ClassVar[str] = "estimator"

    run_inputs: RunInputs
    source: str
    meta: dict[str, Any]

    @property
    @abstractmethod
    def model_name(self) -> str:
        """Registry name of the model (``top10nn``, ``vgg_lstm``, ``res_tf``)."""

    @property
    def constants(self) -> NormalisationConstants:
        """The run's normalisation constants (scalars, frames, labels)."""
        return self.run_inputs.constants

    @property
    def inputs(self) -> InputStrategy:
        """The run's input strategy."""
        return self.run_inputs.inputs

    @property
    def required_inputs(self) -> tuple[str, ...]:
        """The inputs ``predict`` needs (``data.inputs.INPUTS`` names, image first), e.g.
        ``("frames", "force", "width")`` or, frame-free, ``("force", "width")``."""
        return self.inputs.input_names

    @abstractmethod
    def _forward(self, chunk: dict[str, torch.Tensor]) -> np.ndarray:
        """Normalised outputs y (b,) of one chunk of ``input_checks.PreparedInputs``: the
        strategy's image input as given (``runs.forward.model_arguments`` resizes and
        normalises it) and its normalised scalars."""

    def predict(
        self,
        frames: Any = None,
        force: Any = None,
        width: Any = None,
        estimates: Any = None,
        *,
        channel_order: str = "RGB",
        batch_size: int = 64,
        **other_inputs: Any,
    ) -> Prediction:
        """Young's modulus of one grasp or a batch (docs/inference.md, "Inputs").

        Give the inputs of the model's strategy (:attr:`required_inputs`) by name, in
        physical units; inputs it does not take are ignored, so one call serves an
        ensemble of several strategies.

        Args:
            frames: three difference images ``(3, H, W, 3)`` or a batch
                ``(B, 3, H, W, 3)``; uint8 or float in [0, 1]; RGB unless ``channel_order``.
                None for a frame-free or depth model.
            force: normal force in N at the three frames, ``(3,)`` / ``(B, 3)``.
            width: gripper width in m at the three frames.
            estimates: (elastic E, Hertz E*) in Pa, ``(2,)`` / ``(B, 2)``.
            channel_order: ``"RGB"`` (store order) or ``"BGR"`` (OpenCV) of ``frames``.
            batch_size: grasps per forward pass (memory bound, not a result change).
            other_inputs: the table's other inputs (``data.inputs.INPUTS``), e.g.
                ``depth=`` depth maps ``(3, h, w)`` / ``(B, 3, h, w)`` in mm.

        Returns:
            :class:`Prediction` with floats for one grasp, (B,) arrays for a batch.

        Raises:
            ValueError: a bad, missing or unknown input, named with its unit and shape.
        """
        if batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size}")
        given = {"frames": frames, "force": force, "width": width, "estimates": estimates}
        prepared = prepare_inputs(
            {**given, **other_inputs},
            inputs=self.inputs,
            constants=self.constants,
            channel_order=channel_order,
            describe=f"{self.kind} {self.source} ({self.model_name})",
            missing_estimates=self.run_inputs.missing_estimates,
        )
        y = np.concatenate([self._forward(chunk) for chunk in prepared.chunks(batch_size)])
        return Prediction.from_normalised(y, self.constants, prepared.single)
