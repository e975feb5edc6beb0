"""Small image operations shared by the importers."""

from __future__ import annotations

import cv2
import numpy as np

from tactile_compliance.data.plausibility import check_size


def parse_size(text: str | None) -> tuple[int, int] | None:
    """Parse ``"HxW"`` (pixels, e.g. ``"250x350"``) into (height, width); None passes through.

    Each side must lie in ``[1, MAX_FRAME_SIDE_PX]`` (:func:`check_size`)."""
    if text is None or text == "":
        return None
    parts = text.lower().replace(" ", "").split("x")
    if len(parts) != 2 or not all(p.isdigit() for p in parts) or min(int(p) for p in parts) < 1:
        raise ValueError(
            f"size must look like HxW with positive integers (e.g. 250x350), got {text!r}"
        )
    return check_size((int(parts[0]), int(parts[1])))


def resize_frames(frames: np.ndarray, size: tuple[int, int] | None) -> np.ndarray:
    """Resize (T, H, W, C) frames to ``size`` = (height, width) px; area averaging to shrink."""
    if size is None or tuple(frames.shape[1:3]) == tuple(size):
        return frames
    height, width = size
    shrinking = height * width < frames.shape[1] * frames.shape[2]
    interpolation = cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR
    # cv2 handles float32 and uint8; float64 is converted to keep memory and time down.
    work = frames.astype(np.float32) if frames.dtype not in (np.uint8, np.float32) else frames
    return np.stack([cv2.resize(f, (width, height), interpolation=interpolation) for f in work])


def difference_images(frames: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """``(frame - GaussianBlur11x11(reference)) / 255 + 0.5`` as float32, channels kept.

    The recording pipeline's difference images (the generator renders them, streaming
    inference computes them from raw camera frames). The blur runs on the uint8
    reference, as in the real pipeline (OpenCV returns uint8; it suppresses the
    reference's pixel noise), so every value is a multiple of 1/255 offset by 0.5 (to
    float32 rounding).

    Args:
        frames: raw uint8 frames (n, H, W, 3).
        reference: the raw uint8 no-contact frame (H, W, 3) of the same sensor.
    """
    blurred = cv2.GaussianBlur(reference, (11, 11), 0)
    out = np.empty(frames.shape, dtype=np.float32)
    scale = 1.0 / 255.0
    for k in range(frames.shape[0]):  # one fused SIMD pass per frame
        cv2.addWeighted(frames[k], scale, blurred, -scale, 0.5, dst=out[k], dtype=cv2.CV_32F)
    return out
