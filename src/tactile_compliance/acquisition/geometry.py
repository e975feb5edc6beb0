"""How a camera frame becomes a sensor frame (``FrameGeometry``: warp, crop, resize) and
the sensors' preset geometries; the frame errors it raises. Used by ``sensors.py``'s
sources and by calibrations.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import cv2
import numpy as np

from tactile_compliance.data.image_ops import resize_frames
from tactile_compliance.data.plausibility import check_size

__all__ = [
    "MINI_CAPTURE_SIZE",
    "MINI_GEOMETRY",
    "PLAIN_GEOMETRY",
    "WEDGE_CAMERA_SIZE",
    "WEDGE_GEOMETRY",
    "Corners",
    "FrameError",
    "FrameGeometry",
    "FrameSizeError",
]


class FrameError(ValueError):
    """One frame is unusable; the source itself can go on (see subclasses)."""


class FrameSizeError(FrameError):
    """A frame's size differs from the source's first frame or the calibration's size."""


# ---------------------------------------------------------------------- geometry
Corners = tuple[tuple[float, float], tuple[float, float], tuple[float, float], tuple[float, float]]


@dataclass(frozen=True)
class FrameGeometry:
    """How a camera frame becomes a sensor frame: warp, then crop, then resize.

    Attributes:
        input_size: the camera frame size (H, W) px expected; None accepts any size.
        warp_corners: the pad's four (x, y) px corners in the camera frame (top-left,
            top-right, bottom-right, bottom-left), warped onto ``warp_size``; None: no warp.
        warp_size: (H, W) px of the warped image.
        crop_px: pixels removed from each side after the warp.
        crop_fraction: share of the height and of the width removed from each side,
            after ``crop_px``.
        output_size: (H, W) px of the final frame; None keeps the cropped size.
    """

    input_size: tuple[int, int] | None = None
    warp_corners: Corners | None = None
    warp_size: tuple[int, int] | None = None
    crop_px: int = 0
    crop_fraction: float = 0.0
    output_size: tuple[int, int] | None = None

    def __post_init__(self) -> None:
        # Types and sizes are checked here, before a frame is warped or resized: a size is
        # whole pixels within data.plausibility.MAX_FRAME_SIDE_PX (a 40000 x 40000 output
        # would allocate 4.8 GB per frame), crop_px an integer, never text.
        for name in ("input_size", "warp_size", "output_size"):
            size = getattr(self, name)
            if size is not None:
                object.__setattr__(self, name, check_size(size, name))
        if (self.warp_corners is None) != (self.warp_size is None):
            raise ValueError("warp_corners and warp_size go together (both or neither)")
        if self.warp_corners is not None:
            object.__setattr__(self, "warp_corners", _checked_corners(self.warp_corners))
            if self.input_size is not None:
                height, width = self.input_size
                outside = [
                    (x, y)
                    for x, y in self.warp_corners
                    if not (-0.5 <= x <= width - 0.5 and -0.5 <= y <= height - 0.5)
                ]
                if outside:
                    raise ValueError(
                        f"warp corner(s) {outside} lie outside the {height}x{width} px camera "
                        f"frame (x in [0, {width - 1}], y in [0, {height - 1}]); the warped "
                        f"image would be black there"
                    )
        if isinstance(self.crop_px, bool) or not isinstance(self.crop_px, (int, np.integer)):
            raise ValueError(f"crop_px must be a whole number of pixels, got {self.crop_px!r}")
        if int(self.crop_px) < 0:
            raise ValueError(f"crop_px must be >= 0, got {self.crop_px}")
        object.__setattr__(self, "crop_px", int(self.crop_px))
        fraction = self.crop_fraction
        if isinstance(fraction, bool) or not isinstance(fraction, (int, float, np.number)):
            raise ValueError(f"crop_fraction must be a number, got {fraction!r}")
        if not 0.0 <= float(fraction) < 0.5:
            raise ValueError(f"crop_fraction must be in [0, 0.5), got {fraction}")
        object.__setattr__(self, "crop_fraction", float(fraction))

    def cropped_size(self, size: tuple[int, int]) -> tuple[int, int]:
        """(H, W) px left after warp and crop of a camera frame of ``size``."""
        h, w = self.warp_size if self.warp_size is not None else size
        h, w = h - 2 * self.crop_px, w - 2 * self.crop_px
        dy, dx = int(h * self.crop_fraction), int(w * self.crop_fraction)
        h, w = h - 2 * dy, w - 2 * dx
        if h < 1 or w < 1:
            raise ValueError(f"the crop leaves nothing of a {size[0]}x{size[1]} frame")
        return h, w

    def frame_size(self, size: tuple[int, int]) -> tuple[int, int]:
        """(H, W) px of the sensor frames made from camera frames of ``size``."""
        return self.output_size if self.output_size is not None else self.cropped_size(size)

    def warp(self, frame: np.ndarray) -> np.ndarray:
        """The warp step alone (the frame as is without ``warp_corners``): the image the
        crop is taken from."""
        if self.warp_corners is None or self.warp_size is None:
            return frame
        h, w = self.warp_size
        target = np.float32([[0, 0], [w - 1, 0], [w - 1, h - 1], [0, h - 1]])
        matrix = cv2.getPerspectiveTransform(np.float32(self.warp_corners), target)
        return cv2.warpPerspective(frame, matrix, (w, h), flags=cv2.INTER_LINEAR)

    def crop_box(self, size: tuple[int, int]) -> tuple[int, int, int, int]:
        """(top, left, height, width) px of the crop in the warped image of a camera frame
        of ``size`` (H, W)."""
        warped = self.warp_size if self.warp_size is not None else size
        h, w = self.cropped_size(size)
        top = self.crop_px + int((warped[0] - 2 * self.crop_px) * self.crop_fraction)
        left = self.crop_px + int((warped[1] - 2 * self.crop_px) * self.crop_fraction)
        return top, left, h, w

    def apply(self, frame: np.ndarray) -> np.ndarray:
        """Warp, crop and resize one uint8 camera frame (H, W, 3).

        Raises:
            FrameSizeError: the frame is not (H, W, 3) or not ``input_size``.
        """
        if frame.ndim != 3 or frame.shape[2] != 3:
            raise FrameSizeError(f"a frame must be (H, W, 3), got {tuple(frame.shape)}")
        size = (int(frame.shape[0]), int(frame.shape[1]))
        if self.input_size is not None and size != self.input_size:
            raise FrameSizeError(
                f"frame is {size[0]}x{size[1]} px, the sensor geometry expects "
                f"{self.input_size[0]}x{self.input_size[1]}"
            )
        out = self.warp(frame)
        top, left, h, w = self.crop_box(size)
        out = out[top : top + h, left : left + w]
        if self.output_size is not None:
            out = resize_frames(out[None], self.output_size)[0]
        return np.ascontiguousarray(out, dtype=np.uint8)

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly dict (lists for tuples)."""
        data = asdict(self)
        if data["warp_corners"] is not None:
            data["warp_corners"] = [list(point) for point in data["warp_corners"]]
        return {k: list(v) if isinstance(v, tuple) else v for k, v in data.items()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> FrameGeometry:
        """Inverse of :meth:`to_dict`; unknown keys are an error."""
        unknown = set(data) - set(cls.__dataclass_fields__)
        if unknown:
            raise ValueError(f"unknown frame geometry field(s) {sorted(unknown)}")
        return cls(**data)


def _checked_corners(points: Any) -> Corners:
    """Four finite (x, y) px points spanning a convex quadrilateral of area >= 1 px²
    (others make a degenerate warp: a smeared or black reference)."""
    try:
        corners = tuple((float(x), float(y)) for x, y in points)
    except (TypeError, ValueError) as err:
        raise ValueError(f"warp_corners must be four (x, y) points, got {points!r}") from err
    if len(corners) != 4 or not all(math.isfinite(v) for p in corners for v in p):
        raise ValueError(f"warp_corners must be four finite (x, y) points, got {corners!r}")
    # Cross products of consecutive edges: one sign all round = convex, in order. The
    # area is the shoelace formula's.
    turns, twice_area = [], 0.0
    for i in range(4):
        (x0, y0), (x1, y1), (x2, y2) = corners[i], corners[(i + 1) % 4], corners[(i + 2) % 4]
        turns.append((x1 - x0) * (y2 - y1) - (y1 - y0) * (x2 - x1))
        twice_area += x0 * y1 - x1 * y0
    area = 0.5 * abs(twice_area)
    if area < 1.0 or not (all(t > 0 for t in turns) or all(t < 0 for t in turns)):
        raise ValueError(
            f"warp_corners {[list(p) for p in corners]} do not span a convex quadrilateral "
            f"(collinear, repeated or crossed points; area {area:.3g} px²): give the pad's "
            f"corners in the order top-left, top-right, bottom-right, bottom-left"
        )
    return corners  # type: ignore[return-value]


PLAIN_GEOMETRY = FrameGeometry()
"""Frames as the camera delivers them."""

MINI_CAPTURE_SIZE = (2464, 3280)  # (H, W) px asked for; the Mini may deliver another mode

# The manufacturer's examples crop the gel's unlit border (1/7 per side) and resize.
MINI_GEOMETRY = FrameGeometry(crop_fraction=1.0 / 7.0, output_size=(240, 320))

WEDGE_CAMERA_SIZE = (480, 640)  # (H, W) px of the public dataset's Wedge rig

WEDGE_GEOMETRY = FrameGeometry(
    input_size=WEDGE_CAMERA_SIZE,
    warp_corners=((0.0, 0.0), (639.0, 0.0), (639.0, 479.0), (0.0, 479.0)),
    warp_size=(300, 400),
    crop_px=25,
)
"""GelSight Wedge: the dataset's 250 x 350 frames; the default corners are the whole
camera frame, the pad's come from ``calibrate --corners``."""
