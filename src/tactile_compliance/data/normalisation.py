"""Normalisation of labels, analytical estimates, force, width and images: one function per
quantity (and its inverse where a model output is read back), every constant in
:class:`NormalisationConstants`, which checkpoints store. Numpy or torch in, the same out.

See docs/protocol.md, "2. Normalisation".
"""

from __future__ import annotations

import math
import sys
from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

from tactile_compliance.data.plausibility import MODULUS

if TYPE_CHECKING:
    import torch

# torch is not imported here: config.py imports this module, and the command line loads
# the config (to report a typo at once) before anything imports torch. Where a tensor
# exists torch is already imported, so the tensor branches take it from sys.modules.
ArrayT = TypeVar("ArrayT", np.ndarray, "torch.Tensor")


def _torch() -> Any:
    """The torch module; only called with a tensor in hand, so it is already imported."""
    return sys.modules["torch"]


def _is_tensor(x: Any) -> bool:
    """Whether ``x`` is a torch tensor, without importing torch (none exists without it)."""
    torch = sys.modules.get("torch")
    return torch is not None and isinstance(x, torch.Tensor)


#: Per-channel mean of the dataset's difference images in [0, 1], **BGR order**, as
#: published by Kuhlmann et al. (mfkuhlmann/youngs-modulus-estimation,
#: ``src/dataset/k_fold_youngs_data_module.py``, the ``Normalize`` transform). Their frames
#: are the dataset's ``RGB*.pkl`` arrays unchanged (``src/dataset/offloaded_dataset.py``:
#: no channel flip), and those were written from ``cv2.VideoCapture`` frames by Burgess et
#: al. (GelSight-lab/TactileEstimateModulus, ``src/wedge_video.py``), i.e. B, G, R.
PUBLISHED_IMAGE_MEAN_BGR: tuple[float, float, float] = (0.49638007, 0.49770336, 0.49385751)
#: Per-channel standard deviation, same source and order as :data:`PUBLISHED_IMAGE_MEAN_BGR`.
PUBLISHED_IMAGE_STD_BGR: tuple[float, float, float] = (0.04634926, 0.06181679, 0.07152624)

#: The label range (log10 Pa) a model may be trained on: 1 Pa (softer than any object a
#: gripper can hold) to ``plausibility.MODULUS.high`` (1e13 Pa, beyond diamond).
LABEL_LOG10_BOUNDS: tuple[float, float] = (0.0, math.log10(MODULUS.high))

#: The plausible range (low, high, unit) of each scale: a force scale is a grasp's force
#: (the dataset's 60 N; ``plausibility.FORCE`` ends at 1000 N), a width scale the
#: gripper's opening (0.08 m; ``plausibility.WIDTH`` ends at 0.2 m), the estimates' span
#: a number of decades (12; 1 Pa to beyond diamond is 13) from an offset near 1e2 Pa, a
#: depth scale a grasp's indentation (1 mm; ``plausibility.DEPTH`` ends at 100 mm).
SCALE_BOUNDS: dict[str, tuple[float, float, str]] = {
    "depth_scale_mm": (1e-3, 100.0, "mm"),
    "force_scale_n": (1e-2, 1000.0, "N"),
    "width_scale_m": (1e-3, 0.2, "m"),
    "estimate_log10_span": (0.1, 30.0, "decades"),
    "estimate_log10_min": (-10.0, 20.0, "log10 Pa"),
}

__all__ = [
    "MISSING_SCALAR",
    "SCALE_BOUNDS",
    "NormalisationConstants",
    "denormalise_images",
    "denormalise_modulus",
    "normalise_depth",
    "normalise_estimates",
    "normalise_force",
    "normalise_images",
    "normalise_modulus",
    "normalise_width",
]


#: What a missing (NaN) scalar input is after normalisation, in training and at inference
#: (a model trained with ``training.estimate_dropout`` learns it as "no estimate"). For
#: the estimates it is the normalised clamp floor, 1e2 Pa, which no grasp's fit reaches.
MISSING_SCALAR = 0.0


@dataclass(frozen=True)
class NormalisationConstants:
    """All normalisation constants of one dataset (units in the field names).

    Attributes:
        label_log10_min, label_log10_max: the label range, log10 Pa (default 1e3-1e12 Pa).
        estimate_clamp_pa: analytical estimates are clamped to this range (Pa) before log10.
        estimate_log10_min, estimate_log10_span: the estimates' offset (log10 Pa) and span
            (decades).
        force_scale_n: 60 N, the grasp's force threshold; width_scale_m: 0.08 m, the
            gripper's maximum opening; depth_scale_mm: 1 mm, about a grasp's peak
            indentation (depth maps are divided by it).
        image_mean, image_std: per channel, difference images in [0, 1], in the store's
            order **R, G, B** (the published BGR statistics reversed).

    Checkpoints store these values (:meth:`to_dict` / :meth:`from_dict`), so a model keeps
    the statistics it was trained with (models trained before the channel-order fix keep
    the BGR tuple).
    """

    label_log10_min: float = 3.0
    label_log10_max: float = 12.0
    estimate_clamp_pa: tuple[float, float] = (1e2, 1e14)
    estimate_log10_min: float = 2.0
    estimate_log10_span: float = 12.0
    force_scale_n: float = 60.0
    width_scale_m: float = 0.08
    depth_scale_mm: float = 1.0
    image_mean: tuple[float, float, float] = PUBLISHED_IMAGE_MEAN_BGR[::-1]
    image_std: tuple[float, float, float] = PUBLISHED_IMAGE_STD_BGR[::-1]

    def __post_init__(self) -> None:
        # Every constant is checked here, so a tampered or careless checkpoint, config.json
        # or configuration (NaN, inf, text, a label range of 1e400 Pa) is refused where it
        # is read, before it can turn into a NaN or a 9e256 Pa estimate.
        for name in ("label_log10_min", "label_log10_max", "estimate_log10_min"):
            object.__setattr__(self, name, _finite(name, getattr(self, name)))
        for name in ("estimate_log10_span", "force_scale_n", "width_scale_m", "depth_scale_mm"):
            object.__setattr__(self, name, _finite(name, getattr(self, name), positive=True))
        # Coerce lists (from JSON/YAML) to tuples so instances stay hashable and comparable.
        for name, length in (("estimate_clamp_pa", 2), ("image_mean", 3), ("image_std", 3)):
            object.__setattr__(self, name, _finite_tuple(name, getattr(self, name), length))
        if not self.label_log10_max > self.label_log10_min:
            raise ValueError(
                f"label_log10_max ({self.label_log10_max}) must exceed "
                f"label_log10_min ({self.label_log10_min})"
            )
        low, high = LABEL_LOG10_BOUNDS
        if self.label_log10_min < low or self.label_log10_max > high:
            raise ValueError(
                f"the label range 1e{self.label_log10_min:g}..1e{self.label_log10_max:g} Pa "
                f"lies outside the plausible moduli 1e{low:g}..1e{high:g} Pa "
                f"(label_log10_min/max)"
            )
        # Finite is not enough: force_scale_n 1e300 turns every force into 0 and shifts
        # the estimates without an error. The bounds are the readings' plausible ranges.
        for name, (low, high, unit) in SCALE_BOUNDS.items():
            value = getattr(self, name)
            if not low <= value <= high:
                raise ValueError(
                    f"normalisation constant {name} {value:g} {unit} is outside the plausible "
                    f"[{low:g}, {high:g}] {unit}"
                )
        lo, hi = self.estimate_clamp_pa
        if not 0 < lo < hi:
            raise ValueError(f"estimate_clamp_pa must be (lo, hi) with 0 < lo < hi, got {lo, hi}")
        if min(self.image_std) <= 0 or max(self.image_std) > 1:
            raise ValueError(
                "image_std values must be positive and at most 1 (difference images in "
                f"[0, 1]), got {list(self.image_std)}"
            )
        if min(self.image_mean) < 0 or max(self.image_mean) > 1:
            raise ValueError(
                f"image_mean values must lie in [0, 1] (difference images), got "
                f"{list(self.image_mean)}"
            )

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_label_range(
        cls, label_range_pa: tuple[float, float], **kwargs: Any
    ) -> NormalisationConstants:
        """Constants whose label range is ``label_range_pa = (E_min, E_max)`` in Pa."""
        lo, hi = (float(v) for v in label_range_pa)
        if not 0 < lo < hi:
            raise ValueError(f"label range must satisfy 0 < min < max (Pa), got {lo, hi}")
        return cls(label_log10_min=math.log10(lo), label_log10_max=math.log10(hi), **kwargs)

    @classmethod
    def for_shore_data(cls) -> NormalisationConstants:
        """Constants for the Shore-hardness (Yuan) data trained alone: labels in [1e3, 1e7] Pa."""
        return cls(label_log10_min=3.0, label_log10_max=7.0)

    @property
    def label_range_pa(self) -> tuple[float, float]:
        """The label range (E_min, E_max) in Pa."""
        return (10.0**self.label_log10_min, 10.0**self.label_log10_max)

    @property
    def label_log10_span(self) -> float:
        """Width of the label range in decades."""
        return self.label_log10_max - self.label_log10_min

    # ------------------------------------------------------------------ (de)serialisation
    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON dict (tuples become lists); inverse of :meth:`from_dict`."""
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> NormalisationConstants:
        """Rebuild from :meth:`to_dict` output; unknown keys are an error (not ignored)."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(
                f"unknown normalisation constant(s) {unknown}; valid keys: {sorted(known)}"
            )
        return cls(**dict(data))


# ---------------------------------------------------------------------- helpers
def _finite(name: str, value: Any, *, positive: bool = False) -> float:
    """``value`` as a float: a real, finite number (> 0 with ``positive``), never text or
    a boolean (those are not cast)."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"normalisation constant {name} must be a number, got {value!r}")
    number = float(value)
    if not math.isfinite(number) or (positive and number <= 0):
        need = "a finite number > 0" if positive else "a finite number"
        raise ValueError(f"normalisation constant {name} must be {need}, got {number}")
    return number


def _finite_tuple(name: str, values: Any, length: int) -> tuple[float, ...]:
    if isinstance(values, (str, bytes)) or not hasattr(values, "__len__") or len(values) != length:
        raise ValueError(f"normalisation constant {name} needs {length} numbers, got {values!r}")
    return tuple(_finite(name, v) for v in values)


def _as_array(x: Any) -> np.ndarray | torch.Tensor:
    return x if _is_tensor(x) else np.asarray(x, dtype=np.float64)


def _log10(x: np.ndarray | torch.Tensor) -> np.ndarray | torch.Tensor:
    return _torch().log10(x) if _is_tensor(x) else np.log10(x)


def _pow10(x: np.ndarray | torch.Tensor) -> np.ndarray | torch.Tensor:
    return _torch().pow(10.0, x) if _is_tensor(x) else np.power(10.0, x)


def _unwrap_scalar(x: Any, original: Any) -> Any:
    # Scalars in, scalars out: keeps call sites like `normalise_modulus(2e5)` readable.
    if isinstance(original, (int, float, np.floating, np.integer)) and isinstance(x, np.ndarray):
        return float(x)
    return x


# ---------------------------------------------------------------------- labels
def normalise_modulus(modulus_pa: Any, c: NormalisationConstants | None = None) -> Any:
    """Young's modulus (Pa) -> normalised label ``y`` (log10 min-max; [0, 1] inside the range).

    Labels outside the range are not clipped: they map outside [0, 1], so the function
    stays invertible. Raises ``ValueError`` for non-positive numpy values (log10
    undefined); torch tensors are not checked element-wise (no host sync in training
    loops). NaN passes through.
    """
    c = c or NormalisationConstants()
    x = _as_array(modulus_pa)
    if isinstance(x, np.ndarray) and np.any(x <= 0):
        raise ValueError("Young's modulus must be positive (Pa) to take log10")
    y = (_log10(x) - c.label_log10_min) / c.label_log10_span
    return _unwrap_scalar(y, modulus_pa)


def denormalise_modulus(y: Any, c: NormalisationConstants | None = None) -> Any:
    """Normalised label ``y`` -> Young's modulus (Pa); inverse of :func:`normalise_modulus`."""
    c = c or NormalisationConstants()
    x = _as_array(y)
    return _unwrap_scalar(_pow10(x * c.label_log10_span + c.label_log10_min), y)


# ---------------------------------------------------------------------- scalar inputs
def normalise_estimates(estimate_pa: Any, c: NormalisationConstants | None = None) -> Any:
    """Analytical estimate(s) (Pa) -> clamp to ``estimate_clamp_pa`` -> log10 -> affine.

    Works element-wise on any shape (e.g. ``(n, 2)`` for elastic + Hertz). NaN stays NaN so
    missing estimates are never silently turned into a valid-looking value.
    """
    c = c or NormalisationConstants()
    lo, hi = c.estimate_clamp_pa
    x = _as_array(estimate_pa)
    clamped = _torch().clamp(x, lo, hi) if _is_tensor(x) else np.clip(x, lo, hi)
    y = (_log10(clamped) - c.estimate_log10_min) / c.estimate_log10_span
    return _unwrap_scalar(y, estimate_pa)


def normalise_force(force_n: Any, c: NormalisationConstants | None = None) -> Any:
    """Normal force (N) -> ``F / force_scale_n`` (60 N by default)."""
    c = c or NormalisationConstants()
    return _unwrap_scalar(_as_array(force_n) / c.force_scale_n, force_n)


def normalise_width(width_m: Any, c: NormalisationConstants | None = None) -> Any:
    """Gripper width (m) -> ``W / width_scale_m`` (0.08 m by default)."""
    c = c or NormalisationConstants()
    return _unwrap_scalar(_as_array(width_m) / c.width_scale_m, width_m)


def normalise_depth(depth_mm: Any, c: NormalisationConstants | None = None) -> Any:
    """Depth maps (mm) -> ``depth / depth_scale_mm`` (1 mm by default); NaN stays NaN."""
    c = c or NormalisationConstants()
    return _unwrap_scalar(_as_array(depth_mm) / c.depth_scale_mm, depth_mm)


# ---------------------------------------------------------------------- images
def _channel_stats(
    x: np.ndarray | torch.Tensor, c: NormalisationConstants, channel_axis: int
) -> tuple[Any, Any]:
    ndim = x.ndim
    axis = channel_axis % ndim if ndim else 0
    if ndim == 0 or x.shape[axis] != 3:
        raise ValueError(
            f"images need 3 channels on axis {channel_axis}, got shape {tuple(x.shape)}"
        )
    shape = [1] * ndim
    shape[axis] = 3
    if _is_tensor(x):
        torch = _torch()
        dtype = x.dtype if x.is_floating_point() else torch.float32
        mean = torch.tensor(c.image_mean, dtype=dtype, device=x.device).reshape(shape)
        std = torch.tensor(c.image_std, dtype=dtype, device=x.device).reshape(shape)
    else:
        dtype = x.dtype if np.issubdtype(x.dtype, np.floating) else np.float32
        mean = np.asarray(c.image_mean, dtype=dtype).reshape(shape)
        std = np.asarray(c.image_std, dtype=dtype).reshape(shape)
    return mean, std


def normalise_images(
    images: ArrayT, c: NormalisationConstants | None = None, channel_axis: int = -1
) -> ArrayT:
    """Images in [0, 1] -> ``(x - mean) / std`` per channel.

    Args:
        images: numpy array or torch tensor, any layout; values in [0, 1] (not uint8).
        c: constants (mean/std in the store's channel order).
        channel_axis: axis holding the 3 colour channels: ``-1`` for the store's
            channels-last ``(n, 3 frames, H, W, 3)``, ``-3`` for the model's ``(B, T, C, H, W)``.
    """
    c = c or NormalisationConstants()
    x = images if _is_tensor(images) else np.asarray(images)
    # uint8 would be normalised as if 0..255 were in [0, 1]: a silent 255x error.
    if x.dtype == (_torch().uint8 if _is_tensor(x) else np.uint8):
        raise ValueError("normalise_images expects float images in [0, 1], got uint8")
    mean, std = _channel_stats(x, c, channel_axis)
    out = x - mean
    out /= std  # in place: one batch-sized temporary instead of two
    return out


def denormalise_images(
    images: ArrayT, c: NormalisationConstants | None = None, channel_axis: int = -1
) -> ArrayT:
    """Inverse of :func:`normalise_images` (for visualisation): ``x * std + mean``."""
    c = c or NormalisationConstants()
    x = images if _is_tensor(images) else np.asarray(images)
    mean, std = _channel_stats(x, c, channel_axis)
    return x * std + mean
