"""Surface textures of objects, as height fields [mm] imprinted on the gel.

See docs/synthetic.md, "Surface families" (the families, and why detail below two pixels
is attenuated).
"""

from __future__ import annotations

import cv2
import numpy as np

from tactile_compliance.synthetic.materials import TextureSpec

__all__ = ["resolved_fraction", "texture_canvas", "texture_window"]

MIN_SCALE_PX = 2.0
"""Smallest texture scale the pixel grid holds [px] (periods: the Nyquist limit)."""


def resolved_fraction(scale_mm: float, pixel_mm: float) -> float:
    """Share of a texture's amplitude that survives averaging over a pixel [-]."""
    return float(min(1.0, (scale_mm / pixel_mm) / MIN_SCALE_PX))


def _blurred_noise(
    rng: np.random.Generator, shape: tuple[int, int], sigma_px: tuple[float, float]
) -> np.ndarray:
    white = rng.standard_normal(shape, dtype=np.float32)
    sx, sy = max(sigma_px[0], 0.3), max(sigma_px[1], 0.3)
    field = cv2.GaussianBlur(white, (0, 0), sigmaX=sx, sigmaY=sy, borderType=cv2.BORDER_REFLECT)
    std = float(field.std())
    return field / (std if std > 0 else 1.0)


def texture_canvas(
    spec: TextureSpec, size: tuple[int, int], pixel_mm: float, rng: np.random.Generator
) -> np.ndarray:
    """A (2H, 2W) height field [mm] with zero mean.

    Its standard deviation is ``spec.amplitude_mm`` times :func:`resolved_fraction`
    (detail below two pixels is averaged away by the camera) times
    ``spec.imprint_gain`` (open pores print whatever the foam's stiffness).
    """
    h, w = 2 * size[0], 2 * size[1]
    scale_px = max(spec.scale_mm / pixel_mm, MIN_SCALE_PX)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    c, s = np.cos(spec.angle_rad), np.sin(spec.angle_rad)
    along = xx * c + yy * s
    across = -xx * s + yy * c
    kind = spec.kind
    if kind == "machined":
        # Turning / milling lay: parallel lines, with tool chatter along them.
        field = np.sin(2 * np.pi * across / scale_px)
        field += spec.fine_share * _blurred_noise(rng, (h, w), (1.0, 1.0))
    elif kind == "knurled":
        period = max(scale_px, 3.0)
        field = np.abs(np.sin(np.pi * (along + across) / period)) + np.abs(
            np.sin(np.pi * (along - across) / period)
        )
    elif kind == "grain":
        # Fibres: streaks elongated along the grain, plus the growth-ring ridges.
        streaks = _blurred_noise(rng, (h, w), (spec.elongation * scale_px, 0.6 * scale_px))
        mat = cv2.getRotationMatrix2D((w / 2, h / 2), float(np.rad2deg(spec.angle_rad)), 1.0)
        field = cv2.warpAffine(streaks, mat, (w, h), borderMode=cv2.BORDER_REFLECT)
        field += 0.5 * np.sin(2 * np.pi * across / max(4.0 * scale_px, 3.0))
    elif kind == "cellular":
        pores = _blurred_noise(rng, (h, w), (scale_px / 2, scale_px / 2))
        # Open pores are holes in the surface: the gel is pushed less where they are.
        threshold = float(np.quantile(pores, 1.0 - spec.open_fraction))
        field = -np.clip(pores - threshold, 0.0, None)
        field = cv2.GaussianBlur(field, (0, 0), max(scale_px / 6, 0.5))
    elif kind == "organic":
        # Skin: low-frequency bumps (peel dimples, wrinkles) plus fine roughness.
        field = _blurred_noise(rng, (h, w), (scale_px, scale_px))
        field += spec.fine_share * _blurred_noise(
            rng, (h, w), (max(scale_px / 6, 0.5), max(scale_px / 6, 0.5))
        )
    else:  # smooth, matte, rubbery: isotropic roughness at its own scale
        field = _blurred_noise(rng, (h, w), (scale_px, scale_px))
    field = field.astype(np.float32)
    field -= field.mean()
    std = float(field.std())
    amplitude = spec.amplitude_mm * resolved_fraction(spec.scale_mm, pixel_mm) * spec.imprint_gain
    return field * np.float32(amplitude / (std if std > 0 else 1.0))


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
