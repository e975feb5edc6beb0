"""Validation of user input for the inference API, and conversion to a model batch.
See docs/inference.md, "Inputs" and "One preprocessing path".
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from tactile_compliance.data.inputs import (
    ANALYTICAL_INPUTS,
    INPUTS,
    MIN_FRAME_SIDE_PX,
    NUM_FRAMES,
    InputStrategy,
)
from tactile_compliance.data.normalisation import MISSING_SCALAR, NormalisationConstants
from tactile_compliance.data.plausibility import (
    DEPTH,
    FRAME,
    as_real_number,
    dtype_problem,
    format_number,
)
from tactile_compliance.data.store import frames_from_uint8

__all__ = [
    "PreparedInputs",
    "check_depth",
    "check_frames",
    "check_scalar",
    "prepare_inputs",
]

#: One grey level: frames decoded from the store (``(u + 0.5) / 255`` reaches 1.002) pass.
_RANGE_TOLERANCE = FRAME.tolerance
#: The smallest and largest value a stored frame decodes to, ``(0 + 0.5) / 255`` and
#: ``(255 + 0.5) / 255`` (float32, exactly as ``frames_from_uint8`` computes them).
_DECODED_RANGE = tuple(frames_from_uint8(np.array([0, 255], dtype=np.uint8)).tolist())


@dataclass
class PreparedInputs:
    """A validated batch, ready for ``runs.forward.model_arguments``.

    Attributes:
        batch: the strategy's inputs by name, and nothing else: ``frames`` (B, 3, H, W, 3)
            uint8 or float32 tensor in the store's encoding, ``depth`` (B, 3, h, w) float32
            in mm, and the normalised float32 scalars (``force`` (B, 3), ``width`` (B, 3),
            ``estimates`` (B, 2)).
        size: the number of grasps B.
        single: the caller passed one grasp (unbatched arrays); results are unwrapped.
    """

    batch: dict[str, torch.Tensor]
    size: int
    single: bool

    def chunks(self, batch_size: int) -> list[dict[str, torch.Tensor]]:
        """The batch cut into pieces of at most ``batch_size`` grasps (bounded memory)."""
        return [
            {key: value[start : start + batch_size] for key, value in self.batch.items()}
            for start in range(0, self.size, batch_size)
        ]


def _shape(value: Any) -> str:
    shape = getattr(value, "shape", None)
    return str(tuple(shape)) if shape is not None else type(value).__name__


def check_frames(frames: Any, *, channel_order: str = "RGB") -> tuple[torch.Tensor, bool]:
    """Validate frames; returns ``((B, 3, H, W, 3) tensor, single)``, RGB.

    uint8 stays uint8 (the store's encoding); floats become float32, checked by the frame
    rule (``data.plausibility.FRAME``) and saturated like the store's encoding, so a frame
    decoded from the store gives exactly the uint8 frame's result.

    Raises:
        ValueError: wrong type, shape, dtype, NaN/inf, values outside [0, 1] beyond what
            the frame rule allows, or frames smaller than ``MIN_FRAME_SIDE_PX``.
    """
    order = str(channel_order).upper()
    if order not in ("RGB", "BGR"):
        raise ValueError(f"channel_order must be 'RGB' or 'BGR', got {channel_order!r}")
    if isinstance(frames, torch.Tensor):
        array = frames.detach().cpu().numpy()
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
    if min(height, width) < MIN_FRAME_SIDE_PX:
        side = MIN_FRAME_SIDE_PX
        raise ValueError(f"frames are {height}x{width} px; models need at least {side}x{side}")
    if array.dtype == np.uint8:
        # np.array copies memmaps/read-only views: torch cannot wrap non-writable memory.
        tensor = torch.from_numpy(np.array(array, dtype=np.uint8, copy=True))
    elif np.issubdtype(array.dtype, np.floating):
        work = np.asarray(array, dtype=np.float32)
        if not np.all(np.isfinite(work)):
            bad = int(np.count_nonzero(~np.isfinite(work)))
            raise ValueError(f"frames contain {bad} NaN/inf values")
        low, high = float(work.min()), float(work.max())
        if FRAME.below(low) or FRAME.above(high):
            for index, grasp in enumerate(work):  # the rule judges each grasp on its own
                problem = FRAME.violation(grasp, reason=False)
                if problem:
                    where = "" if single else f" (grasp {index} of the batch)"
                    raise ValueError(
                        f"float frames must be difference images in [0, 1] (centred near "
                        f"0.5), got values in [{low:.4g}, {high:.4g}]{where}: {problem}; "
                        f"0..255 images must be uint8, and already-normalised frames must "
                        f"not be passed (the estimator normalises)"
                    )
        lowest, highest = (np.float32(v) for v in _DECODED_RANGE)
        if low < lowest or high > highest:  # saturated pixels: what the store would hold
            work = np.clip(work, lowest, highest)
        tensor = torch.from_numpy(np.array(work, copy=True))
    else:
        raise ValueError(
            f"frames must be uint8 (0..255) or float in [0, 1], got dtype {array.dtype}"
        )
    if order == "BGR":
        tensor = tensor.flip(-1)
    return tensor.contiguous(), single


def check_scalar(
    name: str, value: Any, batch: int, single: bool, *, allow_nan: bool = False
) -> np.ndarray:
    """Validate one scalar input in its physical unit; returns float64 ``(batch, size)``.
    Bool, complex, datetime and text are refused, never cast (a cast would drop an
    imaginary part or turn a date into a number). ``allow_nan``: NaN passes as missing
    (a model trained with estimate dropout); infinity never does.

    Raises:
        ValueError: not numeric, wrong shape, NaN (unless allowed) or inf, or outside the
            plausible range.
    """
    spec = INPUTS[name]
    rule = spec.rule
    what = f"`{name}` ({spec.meaning}, {spec.unit})"
    array = _numeric_array(value, what)
    expected = (spec.size,) if single else (batch, spec.size)
    if single and array.shape == (1, spec.size):
        array = array[0]
    if array.shape != expected:
        got = "a scalar" if array.ndim == 0 else f"shape {tuple(array.shape)}"
        raise ValueError(f"{what} must have shape {expected} to match the other inputs, got {got}")
    finite = np.isfinite(array) | (allow_nan & np.isnan(array))
    if not finite.all():
        raise ValueError(f"{what} contains NaN/inf ({int((~finite).sum())} values); {spec.hint}")
    plausible = f"plausible {rule.quantity} range {rule.interval()}"
    if rule.below(array).any():
        raise ValueError(
            f"{what} must be {rule.lower_bound()} ({plausible}), got min "
            f"{format_number(float(np.nanmin(array)))}; {spec.hint}"
        )
    upper = rule.upper_bound()
    if upper is not None and rule.above(array).any():
        raise ValueError(
            f"{what} must be {upper} ({plausible}), got max "
            f"{format_number(float(np.nanmax(array)))}; {spec.hint}"
        )
    return array.reshape(batch, spec.size)


def _numeric_array(value: Any, what: str) -> np.ndarray:
    """``value`` as a float64 array when it holds only integers and floats, else a
    ValueError naming ``what`` (nothing is cast from bool, complex, datetime or text)."""
    if isinstance(value, torch.Tensor):
        tensor = value.detach().cpu()
        if tensor.is_floating_point():
            tensor = tensor.to(torch.float64)  # bfloat16 has no numpy dtype
        value = tensor.numpy()
    try:
        array = np.asarray(value)
    except (TypeError, ValueError) as err:  # e.g. ragged nested lists
        raise ValueError(f"{what} must be numeric, got {type(value).__name__}") from err
    if array.dtype == object:  # mixed Python objects: each must be a real number
        try:
            numbers = [as_real_number(item) for item in array.ravel().tolist()]
        except ValueError as err:
            raise ValueError(f"{what} must be numeric: {err}") from None
        return np.asarray(numbers, dtype=np.float64).reshape(array.shape)
    problem = dtype_problem(array.dtype)
    if problem:
        raise ValueError(f"{what} must be numeric (integers or floats), got dtype {problem}")
    return np.asarray(array, dtype=np.float64)


def check_depth(depth: Any) -> tuple[torch.Tensor, bool]:
    """Validate depth maps in mm; returns ``((B, 3, h, w) float32 tensor, single)``.

    NaN marks a pixel without depth (the store's convention) and is kept; the model reads
    it as 0 mm.

    Raises:
        ValueError: not numeric, wrong shape, inf, values beyond the depth rule
            (``data.plausibility.DEPTH``), or maps smaller than ``MIN_FRAME_SIDE_PX``.
    """
    what = f"`depth` ({INPUTS['depth'].meaning}, mm)"
    array = _numeric_array(depth, what)
    if array.ndim not in (3, 4) or array.shape[-3] != NUM_FRAMES:
        raise ValueError(
            f"{what} must have shape ({NUM_FRAMES}, h, w) for one grasp or "
            f"(B, {NUM_FRAMES}, h, w) for a batch, got {_shape(array)}"
        )
    single = array.ndim == 3
    if single:
        array = array[None]
    if array.shape[0] == 0:
        raise ValueError("depth: empty batch (B = 0)")
    height, width = array.shape[2:]
    if min(height, width) < MIN_FRAME_SIDE_PX:
        raise ValueError(
            f"depth maps are {height}x{width} px; models need at least "
            f"{MIN_FRAME_SIDE_PX}x{MIN_FRAME_SIDE_PX}"
        )
    if np.isinf(array).any():
        raise ValueError(f"{what} contains inf values; {INPUTS['depth'].hint}")
    finite = array[np.isfinite(array)]
    if finite.size and (DEPTH.below(finite).any() or DEPTH.above(finite).any()):
        raise ValueError(
            f"{what} must lie in the plausible depth range {DEPTH.interval()}, got "
            f"[{format_number(float(finite.min()))}, {format_number(float(finite.max()))}]; "
            f"{INPUTS['depth'].hint}"
        )
    return torch.from_numpy(np.array(array, dtype=np.float32, copy=True)), single


def prepare_inputs(
    given: Mapping[str, Any],
    *,
    inputs: InputStrategy | str,
    constants: NormalisationConstants,
    channel_order: str = "RGB",
    describe: str = "this model",
    missing_estimates: bool = False,
) -> PreparedInputs:
    """Validate the inputs strategy ``inputs`` takes and normalise its scalars.

    Args:
        given: input name -> value (``frames``, ``depth``, ``force`` in N, ``width`` in
            m, ``estimates`` in Pa, as ``data.inputs.INPUTS`` describes them); None
            entries count as absent. Inputs the strategy does not take are ignored and not
            validated: an ensemble passes every member the same inputs, and a member must
            not fail on an input only another member uses.
        describe: how error messages name the estimator.
        missing_estimates: NaN analytical estimates are missing, not an error: they become
            ``MISSING_SCALAR`` as in training (``RunInputs.missing_estimates``).

    Raises:
        ValueError: a missing input (named with its meaning, unit and shape), an unknown
            input name, or an input that fails its check; all inputs must describe the
            same number of grasps.
    """
    strategy = InputStrategy.parse(inputs)
    unknown = sorted(set(given) - set(INPUTS))
    if unknown:
        raise ValueError(f"unknown input(s) {unknown}; inputs are {', '.join(INPUTS)}")
    missing = [spec for spec in strategy.inputs if given.get(spec.name) is None]
    if missing:
        needed = "; ".join(spec.describe() for spec in missing)
        raise ValueError(f"{describe} uses inputs={strategy.value} and needs {needed}, got None")
    batch: dict[str, torch.Tensor] = {}
    image = strategy.image
    if image is not None:  # the image comes first and tells the number of grasps
        if image.name == "frames":
            batch["frames"], single = check_frames(given["frames"], channel_order=channel_order)
        else:
            batch["depth"], single = check_depth(given["depth"])
        size = int(batch[image.name].shape[0])
    else:
        shape = np.shape(given[strategy.inputs[0].name])
        single = len(shape) <= 1
        size = 1 if single else int(shape[0])
    for spec in strategy.scalars:
        allow_nan = missing_estimates and spec.name in ANALYTICAL_INPUTS
        physical = check_scalar(spec.name, given[spec.name], size, single, allow_nan=allow_nan)
        assert spec.normalise is not None  # every scalar has one (data.inputs checks)
        # float64 normalisation then float32, exactly like model_inputs() on the store.
        normalised = np.asarray(spec.normalise(physical, constants), dtype=np.float32)
        if allow_nan:
            normalised = np.nan_to_num(normalised, nan=MISSING_SCALAR)
        batch[spec.name] = torch.from_numpy(normalised)
    return PreparedInputs(batch=batch, size=size, single=single)
