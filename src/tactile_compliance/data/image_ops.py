"""Small image operations shared by the importers, and the one reader of image files."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from tactile_compliance.data.plausibility import MAX_FRAME_SIDE_PX, check_size


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


def parse_corners(text: str) -> tuple[tuple[float, float], ...]:
    """Parse ``"x,y x,y x,y x,y"`` (a warp's four corners in px, e.g. top-left, top-right,
    bottom-right, bottom-left) into four ``(x, y)`` pairs.

    Raises:
        ValueError: not four comma-separated pairs of numbers.
    """
    try:
        points = tuple(tuple(float(v) for v in point.split(",")) for point in text.split())
    except ValueError as err:
        raise ValueError(f"corners must be four points 'x,y x,y x,y x,y' ({err})") from err
    if len(points) != 4 or any(len(point) != 2 for point in points):
        raise ValueError(f"corners must be four points 'x,y x,y x,y x,y', got {text!r}")
    return points  # type: ignore[return-value]


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


# ---------------------------------------------------------------------- image files
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: JPEG start-of-frame markers (baseline, progressive, lossless...), which carry the size;
#: 0xC4 (Huffman tables), 0xC8 (reserved) and 0xCC (arithmetic coding) are not frames.
_JPEG_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}


def _jpeg_size(data: bytes) -> tuple[int, int] | None:
    """(H, W) px from a JPEG's start-of-frame segment, or None if there is none."""
    i = 2
    while i + 4 <= len(data):
        if data[i] != 0xFF:
            return None
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker in (0x01, 0xD8) or 0xD0 <= marker <= 0xD7:  # no length
            i += 2
            continue
        if marker in (0xD9, 0xDA):  # end of image, start of scan: no frame header first
            return None
        length = int.from_bytes(data[i + 2 : i + 4], "big")
        if marker in _JPEG_SOF and i + 9 <= len(data):
            height = int.from_bytes(data[i + 5 : i + 7], "big")
            width = int.from_bytes(data[i + 7 : i + 9], "big")
            return height, width
        i += 2 + length
    return None


def _other_size(path: Path) -> tuple[int, int] | None:
    """(H, W) px of another format (TIFF, WebP, ...) from its header, through Pillow
    (matplotlib's dependency) when it is there; None when it cannot tell."""
    try:
        from PIL import Image
    except ImportError:  # pragma: no cover - matplotlib requires Pillow
        return None
    try:
        with Image.open(path) as image:
            width, height = image.size
    except Image.DecompressionBombError:
        return MAX_FRAME_SIDE_PX + 1, MAX_FRAME_SIDE_PX + 1  # Pillow refuses it as too large
    except Exception:  # not an image Pillow knows: OpenCV decides below
        return None
    return int(height), int(width)


def image_header_size(path: str | Path, data: bytes) -> tuple[int, int] | None:
    """(H, W) px an image file's header claims, read before anything is decoded (PNG,
    JPEG, BMP; other formats through Pillow); None when the header does not say."""
    if data.startswith(_PNG_SIGNATURE) and len(data) >= 24 and data[12:16] == b"IHDR":
        return int.from_bytes(data[20:24], "big"), int.from_bytes(data[16:20], "big")
    if data.startswith(b"\xff\xd8"):
        return _jpeg_size(data)
    if data.startswith(b"BM") and len(data) >= 26:
        if int.from_bytes(data[14:18], "little") == 12:  # BITMAPCOREHEADER: 16-bit sizes
            return int.from_bytes(data[20:22], "little"), int.from_bytes(data[18:20], "little")
        width = int.from_bytes(data[18:22], "little", signed=True)
        height = int.from_bytes(data[22:26], "little", signed=True)
        return abs(height), abs(width)
    return _other_size(Path(path))


def truncation_problem(data: bytes) -> str | None:
    """Why an image file is cut short (a JPEG without its end-of-image marker after the
    last scan, a PNG without its IEND chunk), or None. libjpeg decodes a truncated JPEG
    anyway (it only warns "Premature end of JPEG file") and fills the rest with grey."""
    if data.startswith(b"\xff\xd8"):
        last_scan = data.rfind(b"\xff\xda")
        # Inside entropy-coded data every 0xFF is followed by 0x00 or a restart marker,
        # so the end-of-image marker after the last scan is the real end.
        if last_scan < 0 or data.find(b"\xff\xd9", last_scan) < 0:
            return "a truncated JPEG (no end-of-image marker after its last scan)"
    elif data.startswith(_PNG_SIGNATURE) and data.rfind(b"IEND") < 0:
        return "a truncated PNG (no IEND chunk at its end)"
    return None


def read_image_file(path: str | Path) -> np.ndarray:
    """One image file as a uint8 BGR array (H, W, 3): the one reader of image files.

    The header's size is checked before decoding (each side at most
    ``plausibility.MAX_FRAME_SIDE_PX``, so a header claiming 100000 x 100000 px allocates
    nothing), and a file cut short is refused rather than decoded with grey rows.

    Raises:
        FileNotFoundError: no such file.
        ValueError: too large, truncated, or not an image OpenCV can read.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such image file")
    data = path.read_bytes()
    size = image_header_size(path, data)
    if size is not None:
        height, width = size
        if not (1 <= height <= MAX_FRAME_SIDE_PX and 1 <= width <= MAX_FRAME_SIDE_PX):
            raise ValueError(
                f"{path}: its header says {width}x{height} px; frames are at most "
                f"{MAX_FRAME_SIDE_PX}x{MAX_FRAME_SIDE_PX} px, so it was not decoded"
            )
    problem = truncation_problem(data)
    if problem:
        raise ValueError(f"{path}: {problem}; copy the file again")
    try:
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    except cv2.error as err:
        first = (str(err).strip().splitlines() or [""])[-1]
        raise ValueError(f"{path}: not an image file OpenCV can read ({first})") from None
    if image is None:
        raise ValueError(f"{path}: not an image file OpenCV can read")
    height, width = image.shape[:2]
    if not (height <= MAX_FRAME_SIDE_PX and width <= MAX_FRAME_SIDE_PX):
        raise ValueError(
            f"{path}: the image is {width}x{height} px; frames are at most "
            f"{MAX_FRAME_SIDE_PX}x{MAX_FRAME_SIDE_PX} px"
        )
    return image
