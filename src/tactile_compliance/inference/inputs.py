"""Validation of user input for the inference API, and conversion to a model batch.

Everything a robot program hands to :meth:`ComplianceEstimator.predict` passes through
:func:`prepare_inputs` first. It checks shapes, dtypes, value ranges and NaN, and raises a
``ValueError`` that names the argument, the expected shape/unit and what it got. It then
normalises the scalar inputs with the functions of
:mod:`tactile_compliance.data.normalisation` (the same functions ``model_inputs`` uses for
training), so the dict it returns is exactly what :func:`~tactile_compliance.training.
forward.forward_batch` receives on the evaluation path. Frames stay in the store's
encoding (uint8, or float in [0, 1]); ``prepare_frames`` resizes and normalises them later.

Conventions of the public API (units in the names):

* ``frames``: three RGB difference images of one grasp ``(3, H, W, 3)`` or a batch
  ``(B, 3, H, W, 3)``; uint8 in the store's encoding (``data.store.frames_to_uint8``,
  decoded as ``(u + 0.5) / 255``) or float in [0, 1].
* ``force``: normal force in N at the three frames, ``(3,)`` or ``(B, 3)``.
* ``width``: gripper width in m at the three frames, ``(3,)`` or ``(B, 3)``.
* ``estimates``: analytical estimates (elastic E, Hertz E*) in Pa, ``(2,)`` or ``(B, 2)``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from tactile_compliance.data.normalisation import (
    NormalisationConstants,
    normalise_estimates,
    normalise_force,
    normalise_width,
)
from tactile_compliance.models import NUM_FRAMES, InputStrategy

__all__ = [
    "SCALAR_SPECS",
    "PreparedInputs",
    "ScalarSpec",
    "check_frames",
    "check_scalar",
    "prepare_inputs",
    "required_inputs",
]

#: Tolerance on the [0, 1] range of float frames: one grey level, so frames decoded from
#: the store (``(u + 0.5) / 255`` reaches 1.002) and float16 round-off pass unchanged.
_RANGE_TOLERANCE = 1.0 / 255.0


@dataclass(frozen=True)
class ScalarSpec:
    """What one scalar input is, its unit and the range that is physically plausible."""

    name: str
    size: int
    meaning: str
    unit: str
    low: float | None
    high: float | None
    hint: str


#: Scalar inputs: shape per grasp, unit and plausible range. The ranges catch the usual
#: unit mix-ups (width in mm, force already normalised is *not* caught: F/60 N is still a
#: valid force) without rejecting real grasps: the dataset's grasps reach ~60 N and the
#: gripper opens to 0.08 m.
SCALAR_SPECS: dict[str, ScalarSpec] = {
    "force": ScalarSpec(
        "force",
        NUM_FRAMES,
        "normal force at the three frames",
        "N",
        0.0,
        1000.0,
        "pass the raw reading in newtons (the model divides by 60 N itself)",
    ),
    "width": ScalarSpec(
        "width",
        NUM_FRAMES,
        "gripper width at the three frames",
        "m",
        0.0,
        0.2,
        "pass metres, not millimetres (the gripper opens to 0.08 m)",
    ),
    "estimates": ScalarSpec(
        "estimates",
        2,
        "analytical estimates (elastic E, Hertz E*)",
        "Pa",
        None,
        None,
        "values are clamped to [1e2, 1e14] Pa like in training; NaN means 'missing' and "
        "cannot be used by an ALL model",
    ),
}


@dataclass
class PreparedInputs:
    """A validated batch, ready for ``forward_batch``.

    Attributes:
        batch: ``frames`` (B, 3, H, W, 3) uint8 or float32 tensor in the store's encoding,
            plus the normalised float32 scalars the strategy uses (``force``, ``width``,
            ``estimates``; shape (B, 3), (B, 3), (B, 2)).
        single: the caller passed one grasp (unbatched arrays); results are unwrapped.
    """

    batch: dict[str, torch.Tensor]
    single: bool

    def __len__(self) -> int:
        return int(self.batch["frames"].shape[0])

    def chunks(self, batch_size: int) -> list[dict[str, torch.Tensor]]:
        """The batch cut into pieces of at most ``batch_size`` grasps (bounded memory)."""
        n = len(self)
        return [
            {key: value[start : start + batch_size] for key, value in self.batch.items()}
            for start in range(0, n, batch_size)
        ]


def required_inputs(inputs: InputStrategy | str) -> tuple[str, ...]:
    """Scalar inputs a strategy needs besides the frames, e.g. ``("force", "width")``.

    The strategy's own ``needs`` (one vocabulary for models and inference); this only
    also accepts the strategy's name, as checkpoints and ONNX metadata record it.
    """
    return InputStrategy.parse(inputs).needs


def _shape(value: Any) -> str:
    shape = getattr(value, "shape", None)
    return str(tuple(shape)) if shape is not None else type(value).__name__


def check_frames(
    frames: Any, *, channel_order: str = "RGB", min_size: int = 1
) -> tuple[torch.Tensor, bool]:
    """Validate frames; returns ``((B, 3, H, W, 3) tensor, single)``.

    uint8 stays uint8 (the store's encoding, decoded by ``prepare_frames``); floats become
    float32 and must lie in [0, 1] within one grey level. They are not clipped, so a
    decoded store frame gives exactly the uint8 frame's result. ``channel_order="BGR"``
    flips the channels (OpenCV images) so the model always sees RGB.

    Raises:
        ValueError: wrong type, shape, dtype, NaN/inf, values outside [0, 1], or frames
            smaller than ``min_size`` pixels.
    """
    order = str(channel_order).upper()
    if order not in ("RGB", "BGR"):
        raise ValueError(f"channel_order must be 'RGB' or 'BGR', got {channel_order!r}")
    if isinstance(frames, torch.Tensor):
        array = frames.detach().cpu().numpy()
    elif isinstance(frames, np.ndarray):
        array = frames
    elif frames is None:
        raise ValueError("frames are required: three difference images (3, H, W, 3), RGB")
    else:
        try:
            array = np.asarray(frames)
        except (TypeError, ValueError) as err:
            kind = type(frames).__name__
            raise ValueError(f"frames must be a numeric array, got {kind}") from err
    expected = "(3, H, W, 3) for one grasp or (B, 3, H, W, 3) for a batch (3 frames, RGB last)"
    if array.ndim not in (4, 5):
        raise ValueError(f"frames must have shape {expected}, got {_shape(array)}")
    single = array.ndim == 4
    if single:
        array = array[None]
    if array.shape[1] != NUM_FRAMES or array.shape[-1] != 3:
        shape = tuple(array.shape[1:]) if single else tuple(array.shape)
        raise ValueError(f"frames must have shape {expected}, got {shape}")
    if array.shape[0] == 0:
        raise ValueError("frames: empty batch (B = 0)")
    height, width = array.shape[2:4]
    if min(height, width) < min_size:
        raise ValueError(
            f"frames are {height}x{width} px; this model needs at least {min_size}x{min_size}"
        )
    if array.dtype == np.uint8:
        # np.array copies memmaps/read-only views: torch cannot wrap non-writable memory.
        tensor = torch.from_numpy(np.array(array, dtype=np.uint8, copy=True))
    elif np.issubdtype(array.dtype, np.floating):
        work = np.asarray(array, dtype=np.float32)
        if not np.all(np.isfinite(work)):
            bad = int(np.count_nonzero(~np.isfinite(work)))
            raise ValueError(f"frames contain {bad} NaN/inf values")
        low, high = float(work.min()), float(work.max())
        if low < -_RANGE_TOLERANCE or high > 1 + _RANGE_TOLERANCE:
            raise ValueError(
                f"float frames must be difference images in [0, 1] (centred near 0.5), got "
                f"values in [{low:.4g}, {high:.4g}]; 0..255 images must be uint8, and "
                f"already-normalised frames must not be passed (the estimator normalises)"
            )
        tensor = torch.from_numpy(np.array(work, copy=True))
    else:
        raise ValueError(
            f"frames must be uint8 (0..255) or float in [0, 1], got dtype {array.dtype}"
        )
    if order == "BGR":
        tensor = tensor.flip(-1)
    return tensor.contiguous(), single


def check_scalar(name: str, value: Any, batch: int, single: bool) -> np.ndarray:
    """Validate one scalar input in its physical unit; returns float64 ``(batch, size)``.

    Raises:
        ValueError: not numeric, wrong shape, NaN/inf, or outside the plausible range.
    """
    spec = SCALAR_SPECS[name]
    what = f"`{name}` ({spec.meaning}, {spec.unit})"
    if isinstance(value, torch.Tensor):
        value = value.detach().cpu().numpy()
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{what} must be numeric, got {type(value).__name__}") from err
    expected = (spec.size,) if single else (batch, spec.size)
    if single and array.shape == (1, spec.size):
        array = array[0]
    if array.shape != expected:
        got = "a scalar" if array.ndim == 0 else f"shape {tuple(array.shape)}"
        raise ValueError(f"{what} must have shape {expected} to match the frames, got {got}")
    finite = np.isfinite(array)
    if not finite.all():
        raise ValueError(f"{what} contains NaN/inf ({int((~finite).sum())} values); {spec.hint}")
    if spec.low is not None and (array < spec.low).any():
        raise ValueError(
            f"{what} must be >= {spec.low:g} {spec.unit}, got min {array.min():.4g}; {spec.hint}"
        )
    if spec.high is not None and (array > spec.high).any():
        raise ValueError(
            f"{what} must be <= {spec.high:g} {spec.unit}, got max {array.max():.4g}; {spec.hint}"
        )
    return array.reshape(batch, spec.size)


_NORMALISERS = {
    "force": normalise_force,
    "width": normalise_width,
    "estimates": normalise_estimates,
}


def prepare_inputs(
    frames: Any,
    scalars: Mapping[str, Any],
    *,
    inputs: InputStrategy | str,
    constants: NormalisationConstants,
    min_size: int = 1,
    channel_order: str = "RGB",
    describe: str = "this model",
) -> PreparedInputs:
    """Validate frames and the scalar inputs the strategy needs; normalise the scalars.

    Inputs the strategy does not use are ignored without validation (like the models do),
    so one call site can feed estimators of every strategy.

    Args:
        frames: see the module docstring.
        scalars: ``{"force": ..., "width": ..., "estimates": ...}`` in N, m and Pa; None
            entries count as absent.
        inputs: the checkpoint's input strategy.
        constants: the checkpoint's normalisation constants.
        min_size: smallest frame side the model accepts (after resizing).
        channel_order: ``"RGB"`` (default, the store's order) or ``"BGR"`` (OpenCV).
        describe: how error messages name the estimator (e.g. its checkpoint).
    """
    tensor, single = check_frames(frames, channel_order=channel_order, min_size=min_size)
    batch_size = int(tensor.shape[0])
    batch: dict[str, torch.Tensor] = {"frames": tensor}
    strategy = InputStrategy.parse(inputs)
    for name in required_inputs(strategy):
        value = scalars.get(name)
        if value is None:
            spec = SCALAR_SPECS[name]
            shape = f"({spec.size},)" if single else f"(B, {spec.size})"
            raise ValueError(
                f"{describe} uses inputs={strategy.value} and needs `{name}` ({spec.meaning}, "
                f"{spec.unit}, shape {shape}), got None"
            )
        physical = check_scalar(name, value, batch_size, single)
        # float64 normalisation then float32, exactly like model_inputs() on the store.
        normalised = np.asarray(_NORMALISERS[name](physical, constants), dtype=np.float32)
        batch[name] = torch.from_numpy(normalised)
    return PreparedInputs(batch=batch, single=single)
