"""Surface textures of objects, as height fields imprinted on the gel.

Textures are the weak material cues of the real data: wood grain, machining marks,
knurling, foam pores, the matte roughness of moulded plastic. They are generated once
per object and finger side on a canvas twice the image size (heights in mm, zero mean);
each grasp takes a randomly placed, randomly flipped window, so repeated grasps of an
object show the same surface at different places. The renderer scales the imprint by
the gel's share of the deformation (a soft object's texture flattens instead of
printing into the gel) and applies it only where the object touches.
"""

from __future__ import annotations

import cv2
import numpy as np

from tactile_compliance.synthetic.objects import TextureSpec

__all__ = ["texture_canvas", "texture_window"]


def _blurred_noise(
    rng: np.random.Generator, shape: tuple[int, int], sigma_px: tuple[float, float]
) -> np.ndarray:
    white = rng.standard_normal(shape, dtype=np.float32)
    sx, sy = max(sigma_px[0], 0.3), max(sigma_px[1], 0.3)
    field = cv2.GaussianBlur(white, (0, 0), sigmaX=sx, sigmaY=sy, borderType=cv2.BORDER_REFLECT)
    std = float(field.std())
    return field / (std if std > 0 else 1.0)


def _rotate(field: np.ndarray, angle_rad: float) -> np.ndarray:
    h, w = field.shape
    mat = cv2.getRotationMatrix2D((w / 2, h / 2), float(np.rad2deg(angle_rad)), 1.0)
    return cv2.warpAffine(field, mat, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def texture_canvas(
    spec: TextureSpec, size: tuple[int, int], pixel_mm: float, rng: np.random.Generator
) -> np.ndarray:
    """A (2H, 2W) height field [mm] with zero mean and std ``spec.amplitude_mm``."""
    h, w = 2 * size[0], 2 * size[1]
    scale_px = spec.scale_mm / pixel_mm
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    c, s = np.cos(spec.angle_rad), np.sin(spec.angle_rad)
    along = xx * c + yy * s
    across = -xx * s + yy * c
    kind = spec.kind
    if kind == "machined":
        field = np.sin(2 * np.pi * across / max(scale_px, 2.0))
        field += 0.3 * _blurred_noise(rng, (h, w), (1.0, 1.0))
    elif kind == "knurled":
        period = max(scale_px, 3.0)
        field = np.abs(np.sin(np.pi * (along + across) / period)) + np.abs(
            np.sin(np.pi * (along - across) / period)
        )
    elif kind == "grain":
        streaks = _blurred_noise(rng, (h, w), (6.0 * scale_px, 0.6 * scale_px))
        field = _rotate(streaks, spec.angle_rad)
        field += 0.5 * np.sin(2 * np.pi * across / max(4.0 * scale_px, 3.0))
    elif kind == "cellular":
        pores = _blurred_noise(rng, (h, w), (scale_px / 2, scale_px / 2))
        # Pores are holes in the surface: the gel is pushed less where they are.
        field = -np.clip(pores - 0.8, 0.0, None)
        field = cv2.GaussianBlur(field, (0, 0), max(scale_px / 6, 0.5))
    elif kind == "organic":
        field = _blurred_noise(rng, (h, w), (scale_px, scale_px))
        field += 0.3 * _blurred_noise(rng, (h, w), (scale_px / 6, scale_px / 6))
    else:  # smooth, matte, rubbery: isotropic roughness at its own scale
        field = _blurred_noise(rng, (h, w), (scale_px, scale_px))
    field = field.astype(np.float32)
    field -= field.mean()
    std = float(field.std())
    return field * np.float32(spec.amplitude_mm / (std if std > 0 else 1.0))


def texture_window(
    canvas: np.ndarray, size: tuple[int, int], rng: np.random.Generator
) -> np.ndarray:
    """A randomly placed, randomly flipped (H, W) window of a texture canvas [mm]."""
    h, w = size
    i = int(rng.integers(0, canvas.shape[0] - h + 1))
    j = int(rng.integers(0, canvas.shape[1] - w + 1))
    window = canvas[i : i + h, j : j + w]
    flip = int(rng.integers(0, 4))
    if flip & 1:
        window = window[::-1]
    if flip & 2:
        window = window[:, ::-1]
    return np.ascontiguousarray(window)
