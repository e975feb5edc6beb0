"""Depth maps [mm] from difference images: the public dataset's photometric heuristic (the
one function for real and rendered frames) and the one Poisson solver every depth model uses.

See docs/sensors.md and, for rendered frames, docs/synthetic.md ("Rendering").
"""

from __future__ import annotations

from functools import lru_cache
from typing import Protocol

import cv2
import numpy as np
import scipy.fft

__all__ = [
    "DepthModel",
    "fill_masked",
    "poisson_depth",
    "reconstruct_depth",
]

DEPTH_TO_MM = 21.5
"""Scale of the Poisson solution [mm per unit] of the real pipeline at 0.0875 mm/px (its fit
against a calibration ball)."""

CALIBRATION_WIDTH_PX = 350
"""Width [px] of the frames ``DEPTH_TO_MM`` was fitted on (the dataset's 250 x 350 crop);
a frame ``w`` px wide over the same field has ``350 / w`` times larger pixels, so its
slopes integrate to proportionally larger depths."""

_PIXEL_SIZE_MM = 35.0 / 400.0  # the dataset's pixel: 400 px over the 35 mm pad [mm]
_FIELD_WIDTH_MM = CALIBRATION_WIDTH_PX * _PIXEL_SIZE_MM  # 30.625 mm across the crop


def _pixel_size_mm(width_px: int) -> float:
    """Pixel size [mm] of a frame ``width_px`` wide spanning the dataset's field of view."""
    return _FIELD_WIDTH_MM / width_px


_MARKER_THRESHOLD = 0.07  # difference-image darkness that flags a marker pixel [-]

# Rows: gx = G - (B + R) / 2, gy = B - R, and B + G + R, from BGR pixels.
_CHANNEL_MIX = np.array([[-0.5, 1.0, -0.5], [1.0, 0.0, -1.0], [1.0, 1.0, 1.0]], dtype=np.float32)


def _fast_length(n: int) -> int:
    """Smallest m >= n with m + 1 a product of 2, 3, 5 (a fast DST-I length)."""
    m = n
    while True:
        k = m + 1
        for p in (2, 3, 5):
            while k % p == 0:
                k //= p
        if k == 1:
            return m
        m += 1


@lru_cache(maxsize=16)
def _inverse_eigenvalues(rows: int, cols: int) -> np.ndarray:
    """1 / eigenvalues of the 5-point Laplacian with Dirichlet borders (DST-I basis).

    Deliberately not the original's: it divides by ``cos(pi k / (N + 2))`` terms, mixing
    DST-II with DST-I eigenvalues.
    """
    ky = 2.0 * np.cos(np.pi * np.arange(1, rows + 1) / (rows + 1)) - 2.0
    kx = 2.0 * np.cos(np.pi * np.arange(1, cols + 1) / (cols + 1)) - 2.0
    return (1.0 / (ky[:, None] + kx[None, :])).astype(np.float32)


def fill_masked(grad: np.ndarray, mask: np.ndarray, sigma: float) -> np.ndarray:
    """Replace values under the mask by a normalised-convolution average around it (a box
    of ``2 round(sigma) + 1`` px): the markers' fill of the dataset heuristic (on its
    gradients) and of a calibrated depth model (on its difference images).

    ``grad`` and ``mask`` are (n, H, W); frames are blurred as the channels of one image.
    """
    out = grad.copy()
    for start in range(0, grad.shape[0], 128):  # OpenCV: up to 128 channels
        sl = slice(start, start + 128)
        keep = np.ascontiguousarray((~mask[sl]).astype(np.float32).transpose(1, 2, 0))
        values = np.ascontiguousarray(grad[sl].transpose(1, 2, 0))
        box = (2 * round(sigma) + 1, 2 * round(sigma) + 1)  # a box filter is cheap and enough
        num = cv2.blur(values * keep, box).reshape(values.shape)
        den = cv2.blur(keep, box).reshape(values.shape)
        filled = (num / np.maximum(den, 1e-3)).transpose(2, 0, 1)
        out[sl] = np.where(mask[sl], filled, grad[sl])
    return out


def poisson_depth(gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
    """Integrate per-pixel gradients (n, H, W) with zero depth on the border (DST-I).

    ``gx`` / ``gy`` are depth steps per pixel along columns / rows; the depth comes out in
    their unit (mm per pixel in, mm out). Every depth model integrates with this solver.
    """
    n, h, w = gx.shape
    # Divergence with forward differences on the interior, as in the original solver.
    f = np.zeros((n, h, w), dtype=np.float32)
    f[:, :-1, 1:] += gx[:, :-1, 1:] - gx[:, :-1, :-1]
    f[:, 1:, :-1] += gy[:, 1:, :-1] - gy[:, :-1, :-1]
    # Zero-padded to a fast FFT length (unlike the original): the border condition moves a
    # few pixels out.
    rows, cols = _fast_length(h - 2), _fast_length(w - 2)
    padded = np.zeros((n, rows, cols), dtype=np.float32)
    padded[:, : h - 2, : w - 2] = f[:, 1:-1, 1:-1]
    spectrum = scipy.fft.dstn(padded, type=1, axes=(1, 2), norm="ortho")
    spectrum *= _inverse_eigenvalues(rows, cols)
    solution = scipy.fft.idstn(spectrum, type=1, axes=(1, 2), norm="ortho")
    depth = np.zeros((n, h, w), dtype=np.float32)
    depth[:, 1:-1, 1:-1] = solution[:, : h - 2, : w - 2]
    return depth


def _resize_stack(stack: np.ndarray, size: tuple[int, int], interpolation: int) -> np.ndarray:
    """Resize (n, H, W) frames to ``size`` = (H', W'), frame by frame.

    Single-channel calls on contiguous frames take OpenCV's SIMD paths (INTER_AREA at an
    integer factor included); stacking frames as channels would need strided transposes.
    """
    out = np.empty((stack.shape[0], *size), dtype=np.float32)
    for k in range(stack.shape[0]):
        cv2.resize(stack[k], (size[1], size[0]), dst=out[k], interpolation=interpolation)
    return out


class DepthModel(Protocol):
    """A calibrated depth model (``data.depth_model.CalibratedDepthModel``)."""

    def depth_mm(self, diff: np.ndarray) -> np.ndarray: ...


def reconstruct_depth(
    diff_bgr: np.ndarray,
    markers: bool = False,
    solve_scale: float = 1.0,
    model: str | DepthModel = "dataset",
) -> np.ndarray:
    """Depth maps [mm] (n, H, W) from difference images (n, H, W, 3) BGR in [0, 1].

    Args:
        diff_bgr: difference images, BGR channel order, centred near 0.5.
        markers: the images come from the marker finger (mask and fill the markers).
        solve_scale: resolution of the Poisson solve relative to the image (1: as the
            original; 0.5: gradients averaged 2x2, solved, upsampled bilinearly - 4x
            cheaper, loses only detail finer than two pixels).
        model: ``"dataset"``, the public dataset's heuristic (this module, bit for bit as
            the stored depths), or a sensor's calibrated model
            (``data.depth_model.CalibratedDepthModel``, ``tactile-compliance
            calibrate-depth``), which ignores ``markers`` and ``solve_scale``.
    """
    diff = np.asarray(diff_bgr, dtype=np.float32)
    if diff.ndim == 3:
        diff = diff[None]
    if not isinstance(model, str):
        return model.depth_mm(diff)
    if model != "dataset":
        raise ValueError(f"unknown depth model {model!r}; give 'dataset' or a calibrated model")
    n, h, w, _ = diff.shape
    # gx = G - (B + R) / 2, gy = B - R and the channel sum B + G + R, in one SIMD pass
    # per frame (the channel-interleaved layout makes per-channel numpy ops strided).
    mixed = np.empty((3, n, h, w), dtype=np.float32)
    for k in range(n):
        cv2.split(cv2.transform(diff[k], _CHANNEL_MIX), list(mixed[:, k]))
    gx, gy, channel_sum = mixed
    # The real pipeline's linearisation (a slope from a sine-like intensity change).
    gx = gx / np.sqrt(np.maximum(1.0 - gx * gx, 1e-3)) / 128.0
    gy = gy / np.sqrt(np.maximum(1.0 - gy * gy, 1e-3)) / 128.0
    marker_mask = None
    if markers:  # the original's ``demark`` step
        dark = channel_sum < 3.0 * (0.5 - _MARKER_THRESHOLD)
        # Grow each marker blob by one pixel (its soft rim) before filling.
        marker_mask = dark.copy()
        marker_mask[:, 1:, :] |= dark[:, :-1, :]
        marker_mask[:, :-1, :] |= dark[:, 1:, :]
        marker_mask[:, :, 1:] |= dark[:, :, :-1]
        marker_mask[:, :, :-1] |= dark[:, :, 1:]
    scale = DEPTH_TO_MM * _pixel_size_mm(w) / _PIXEL_SIZE_MM
    if solve_scale < 1.0:
        small = (max(round(h * solve_scale), 8), max(round(w * solve_scale), 8))
        step = w / small[1]  # full-resolution pixels per solver pixel
        gx = _resize_stack(gx, small, cv2.INTER_AREA) * np.float32(step)
        gy = _resize_stack(gy, small, cv2.INTER_AREA) * np.float32(step)
        if marker_mask is not None:
            # A solver pixel is a marker pixel if any pixel under it is.
            marker_mask = _resize_stack(marker_mask.astype(np.float32), small, cv2.INTER_AREA) > 0
    if marker_mask is not None:
        sigma = max(0.25 / _pixel_size_mm(gx.shape[2]), 1.0)
        gx = fill_masked(gx, marker_mask, sigma)
        gy = fill_masked(gy, marker_mask, sigma)
    depth = poisson_depth(gx, gy)
    if solve_scale < 1.0:
        depth = _resize_stack(depth, (h, w), cv2.INTER_LINEAR)
    depth *= np.float32(scale)
    return depth
