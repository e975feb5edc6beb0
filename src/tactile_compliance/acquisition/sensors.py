"""Frame sources (sensor cameras, replayed videos, folders of frames) yielding
``(timestamp_s, uint8 BGR frame)`` cut to the pad. See docs/inference.md, "Live sensors,
calibration and your own grasps".
"""

from __future__ import annotations

import contextlib
import csv
import math
import queue
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import cv2
import numpy as np

from tactile_compliance.data.image_ops import read_image_file, resize_frames
from tactile_compliance.data.plausibility import check_size

__all__ = [
    "MINI_GEOMETRY",
    "PLAIN_GEOMETRY",
    "WEDGE_GEOMETRY",
    "DigitSource",
    "FolderSource",
    "FrameError",
    "FrameGeometry",
    "FrameSizeError",
    "FrameSource",
    "FrameSourceBase",
    "RosbagSource",
    "SensorError",
    "StampedOnArrival",
    "TimestampError",
    "VideoCaptureSource",
    "gelsight_mini",
    "gelsight_wedge",
    "iter_frames",
    "open_source",
]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


class SensorError(OSError):
    """A source cannot be opened or stopped delivering frames (device, stream, file)."""


class FrameError(ValueError):
    """One frame is unusable; the source itself can go on (see subclasses)."""


class FrameSizeError(FrameError):
    """A frame's size differs from the source's first frame or the calibration's size."""


class TimestampError(FrameError):
    """A frame's timestamp is older than the previous frame's (time going backwards)."""


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


# ---------------------------------------------------------------------- sources
@runtime_checkable
class FrameSource(Protocol):
    """Anything that yields ``(timestamp_s, bgr_uint8_frame)`` and can be closed."""

    def __iter__(self) -> Iterator[tuple[float, np.ndarray]]: ...

    def __enter__(self) -> FrameSource: ...

    def __exit__(self, *exc: object) -> None: ...

    def close(self) -> None: ...


class FrameSourceBase:
    """Applies the geometry, checks sizes and timestamps; subclasses implement ``_grab``:
    ``(timestamp_s, raw_bgr_frame)``, None at the end, :class:`SensorError` on failure."""

    #: What the source reads, for messages (a path, URL, device).
    name: str = "source"
    #: True for a device or stream that delivers frames as they happen (not a replay), so
    #: the robot's readings of a frame may still be on their way.
    live: bool = False

    def __init__(self, geometry: FrameGeometry = PLAIN_GEOMETRY) -> None:
        self.geometry = geometry
        self._last_time: float | None = None
        self._frame_size: tuple[int, int] | None = None
        self.last_raw_size: tuple[int, int] | None = None
        self.last_raw: np.ndarray | None = None
        self.frames_read = 0

    # subclasses
    def _grab(self) -> tuple[float, np.ndarray] | None:  # pragma: no cover - abstract
        raise NotImplementedError

    def close(self) -> None:
        """Release the device or file (idempotent)."""

    # protocol
    def __enter__(self) -> FrameSourceBase:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __iter__(self) -> Iterator[tuple[float, np.ndarray]]:
        """Every frame until the stream ends; a bad frame raises (see :func:`iter_frames`)."""
        while (item := self.read()) is not None:
            yield item

    def read(self) -> tuple[float, np.ndarray] | None:
        """The next ``(timestamp_s, frame)``, or None at the end of the stream.

        Raises:
            FrameSizeError, TimestampError: this frame is unusable (it is consumed; the
                next call reads the next frame).
            SensorError: the device or stream failed.
        """
        grabbed = self._grab()
        if grabbed is None:
            return None
        timestamp_s, raw = grabbed
        self.frames_read += 1
        raw = np.asarray(raw)
        #: (H, W) px of the last camera frame, before the geometry (for calibrations).
        self.last_raw_size = (int(raw.shape[0]), int(raw.shape[1])) if raw.ndim >= 2 else None
        #: The last camera frame itself (``calibrate``'s picture of the warp and crop).
        self.last_raw = raw
        try:
            frame = self.geometry.apply(raw)
        except FrameSizeError as err:
            raise FrameSizeError(f"{self.name}: frame {self.frames_read - 1}: {err}") from None
        size = (int(frame.shape[0]), int(frame.shape[1]))
        if self._frame_size is None:
            self._frame_size = size
        elif size != self._frame_size:
            raise FrameSizeError(
                f"{self.name}: frame {self.frames_read - 1} is {size[0]}x{size[1]} px, the "
                f"first frame was {self._frame_size[0]}x{self._frame_size[1]}"
            )
        t = float(timestamp_s)
        if not np.isfinite(t):
            raise TimestampError(f"{self.name}: frame {self.frames_read - 1} has no valid time")
        if self._last_time is not None and t < self._last_time:
            raise TimestampError(
                f"{self.name}: frame {self.frames_read - 1} at {t:.4f} s is older than the "
                f"previous frame ({self._last_time:.4f} s): timestamps go backwards"
            )
        self._last_time = t
        return t, frame


def iter_frames(
    source: FrameSourceBase, on_error: Callable[[FrameError], None] | None = None
) -> Iterator[tuple[float, np.ndarray]]:
    """Frames of ``source``, skipping bad ones: each :class:`FrameError` goes to
    ``on_error`` (default: re-raised) and the loop continues with the next frame."""
    while True:
        try:
            item = source.read()
        except FrameError as err:
            if on_error is None:
                raise
            on_error(err)
            continue
        if item is None:
            return
        yield item


class StampedOnArrival(FrameSourceBase):
    """A live source read by a background thread, so each frame is stamped when it arrives
    (docs/inference.md, "Clocks: frames stamped on arrival").

    Args:
        inner: the source to read (its geometry applies, its own stamps are the times).
        max_pending: frames held at most; a consumer further behind gets a
            :class:`SensorError` (memory is bounded: 2,000 Mini frames are 460 MB).
    """

    def __init__(self, inner: FrameSourceBase, max_pending: int = 2000) -> None:
        super().__init__(inner.geometry)
        self.inner = inner
        self.name = inner.name
        self.live = inner.live
        self.max_pending = int(max_pending)
        self._queue: queue.Queue[tuple[float, np.ndarray] | BaseException | None] = queue.Queue()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"read {self.name}", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                item = self.inner._grab()
                if item is not None and self._queue.qsize() >= self.max_pending:
                    item = SensorError(
                        f"{self.name}: {self.max_pending} frames wait to be processed; "
                        "the estimator cannot keep up with the sensor"
                    )
                self._queue.put(item)
                if item is None or isinstance(item, SensorError):
                    return
        except BaseException as err:  # handed to the consumer, raised there
            self._queue.put(err)

    @property
    def pending(self) -> int:
        """Frames read from the device and not yet taken by the consumer."""
        return self._queue.qsize()

    def _grab(self) -> tuple[float, np.ndarray] | None:
        if self._stop.is_set() and self._queue.empty():
            return None
        item = self._queue.get()
        if isinstance(item, BaseException):
            self._stop.set()
            raise item
        if item is None:
            self._stop.set()
        return item

    def stop(self) -> None:
        """Stop the reader thread; the inner source stays open (its owner closes it)."""
        self._stop.set()
        self._thread.join(timeout=2.0)

    def close(self) -> None:
        self.stop()
        self.inner.close()


@contextlib.contextmanager
def _opencv_quiet() -> Iterator[None]:
    """OpenCV's log at ERROR level inside: opening a missing camera makes its backends
    print WARN lines (V4L2 "can't open camera by index", FFMPEG "configured with
    libavdevice") to stderr before the one-line SensorError that says the cause."""
    logging = cv2.utils.logging
    level = logging.getLogLevel()
    logging.setLogLevel(logging.LOG_LEVEL_ERROR)
    try:
        yield
    finally:
        logging.setLogLevel(level)


class VideoCaptureSource(FrameSourceBase):
    """An OpenCV ``VideoCapture``: a camera index, a device path, a video file or a URL.

    Args:
        capture_size, fourcc, fps: the mode to ask a live camera for ((H, W) px, e.g.
            ``"MJPG"``, frames/s); ignored for files.
        timestamps: ``"auto"`` (files: the video's own frame times; devices and streams:
            ``time.monotonic()``), ``"video"`` or ``"clock"``.

    Raises:
        SensorError: nothing could be opened at ``target`` (no such camera, file or stream).
    """

    def __init__(
        self,
        target: int | str | Path,
        geometry: FrameGeometry = PLAIN_GEOMETRY,
        *,
        capture_size: tuple[int, int] | None = None,
        fourcc: str | None = None,
        fps: float | None = None,
        timestamps: str = "auto",
        name: str | None = None,
    ) -> None:
        super().__init__(geometry)
        if timestamps not in ("auto", "video", "clock"):
            raise ValueError(f"timestamps must be auto, video or clock, got {timestamps!r}")
        is_index = isinstance(target, int) or (isinstance(target, str) and target.isdigit())
        text = str(target)
        is_url = "://" in text
        self.is_file = not is_index and not is_url and not text.startswith("/dev/")
        self.name = name or (f"camera {text}" if is_index else text)
        if self.is_file and not Path(text).is_file():
            raise SensorError(f"{text}: no such video file")
        if not self.is_file and not is_index and not is_url and not Path(text).exists():
            raise SensorError(f"{text}: no such device (is the sensor plugged in?)")
        self.live = not self.is_file
        self._decoded = 0  # frames read so far (a file's are checked at its end)
        self.use_video_time = timestamps == "video" or (timestamps == "auto" and self.is_file)
        with _opencv_quiet():  # its warnings on a failed open say less than the error below
            self._capture = cv2.VideoCapture(int(text) if is_index else text)
        if not self._capture.isOpened():
            self._capture.release()
            what = "camera" if is_index else "stream" if is_url else "video"
            raise SensorError(
                f"{self.name}: cannot open the {what} (not connected, in use, or not a "
                f"format OpenCV reads)"
            )
        if not self.is_file:
            # Ask for the mode before reading: a UVC camera picks its format on the first grab.
            if fourcc:
                self._capture.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter_fourcc(*fourcc))
            if capture_size is not None:
                self._capture.set(cv2.CAP_PROP_FRAME_WIDTH, capture_size[1])
                self._capture.set(cv2.CAP_PROP_FRAME_HEIGHT, capture_size[0])
            if fps:
                self._capture.set(cv2.CAP_PROP_FPS, fps)

    def _grab(self) -> tuple[float, np.ndarray] | None:
        if self._capture is None:
            return None
        ok, frame = self._capture.read()
        if not ok or frame is None:
            if self.is_file:
                self._check_complete()
                return None  # end of the video
            raise SensorError(f"{self.name}: the device stopped delivering frames")
        self._decoded += 1
        if self.use_video_time:
            return self._capture.get(cv2.CAP_PROP_POS_MSEC) / 1000.0, frame
        return time.monotonic(), frame

    def _check_complete(self) -> None:
        """At the end of a video file: refuse one that decodes short of the frames its
        container promises (a file cut short or damaged: ffmpeg only logs "overread"), so
        it is not taken for a shorter recording."""
        promised = int(self._capture.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
        # Containers without a frame count give an estimate from the duration, which may
        # be one frame off; a truncated file misses far more.
        if promised > 0 and self._decoded < promised - MAX_MISSING_FRAMES:
            raise SensorError(
                f"{self.name}: the video ends after {self._decoded} of the {promised} frames "
                f"its container promises: the file is truncated or damaged (copy it again)"
            )

    def close(self) -> None:
        if self._capture is not None:
            self._capture.release()
            self._capture = None


#: Frames a video file may decode short of its container's frame count before it counts
#: as truncated (an estimated count can be one off).
MAX_MISSING_FRAMES = 1


def gelsight_mini(
    device: int | str | Path = 0,
    geometry: FrameGeometry = MINI_GEOMETRY,
    *,
    capture_size: tuple[int, int] = MINI_CAPTURE_SIZE,
    fourcc: str = "MJPG",
    timestamps: str = "auto",
) -> VideoCaptureSource:
    """A GelSight Mini (a UVC camera) by index, ``/dev/v4l/by-id/...`` path or a replayed
    video of one."""
    return VideoCaptureSource(
        device,
        geometry,
        capture_size=capture_size,
        fourcc=fourcc,
        timestamps=timestamps,
        name=f"GelSight Mini {device}",
    )


def gelsight_wedge(
    url: str | Path,
    corners: Corners | None = None,
    geometry: FrameGeometry = WEDGE_GEOMETRY,
    *,
    timestamps: str = "auto",
) -> VideoCaptureSource:
    """A GelSight Wedge streaming MJPEG over HTTP (or a replayed video of one); ``corners``
    replaces the geometry's ``warp_corners``."""
    if corners is not None:
        geometry = replace(geometry, warp_corners=corners)
    return VideoCaptureSource(url, geometry, timestamps=timestamps, name=f"GelSight Wedge {url}")


class DigitSource(FrameSourceBase):
    """A DIGIT sensor through the optional, non-commercial ``digit-interface`` package
    (docs/inference.md, "Live sensors, calibration and your own grasps").

    Args:
        resolution: ``"QVGA"`` or ``"VGA"`` (``Digit.STREAMS``); None keeps the default.
        fps: frame rate of that stream (e.g. 60 or 30); None keeps the default.

    Raises:
        SensorError: ``digit-interface`` is not installed, or the DIGIT cannot be opened.
    """

    def __init__(
        self,
        serial: str,
        geometry: FrameGeometry = PLAIN_GEOMETRY,
        *,
        resolution: str | None = None,
        fps: int | None = None,
    ) -> None:
        super().__init__(geometry)
        self.name = f"DIGIT {serial}"
        self.live = True
        try:
            from digit_interface import Digit  # optional, non-commercial licence
        except ImportError as err:
            raise SensorError(
                "DIGIT sensors need the optional package digit-interface, which is not "
                "installed (pip install digit-interface; it has a non-commercial licence, "
                "so tactile-compliance does not install it)"
            ) from err
        try:
            digit = Digit(serial)
            digit.connect()
            if resolution is not None:
                stream = Digit.STREAMS[resolution]
                digit.set_resolution(stream)
                if fps is not None:
                    digit.set_fps(stream["fps"][f"{int(fps)}fps"])
        except (KeyError, ValueError) as err:
            raise ValueError(f"{self.name}: unsupported resolution/fps ({err})") from err
        except Exception as err:  # the driver raises plain Exceptions for a missing device
            raise SensorError(f"{self.name}: cannot open the DIGIT ({err})") from err
        self._digit: Any = digit

    def _grab(self) -> tuple[float, np.ndarray] | None:
        if self._digit is None:
            return None
        try:
            frame = self._digit.get_frame()
        except Exception as err:
            raise SensorError(f"{self.name}: the sensor stopped delivering frames ({err})") from err
        return time.monotonic(), np.asarray(frame)

    def close(self) -> None:
        if getattr(self, "_digit", None) is not None:
            try:
                self._digit.disconnect()
            finally:
                self._digit = None


class FolderSource(FrameSourceBase):
    """Image files of a folder in name order; timestamps come from ``timestamps_csv``
    (columns ``file,timestamp_s``, or one column ``timestamp_s`` in name order) or from
    ``fps`` (frame i at ``i / fps`` s).

    Raises:
        SensorError: no such folder or no image in it.
        ValueError: neither or both of ``fps`` and ``timestamps_csv``; a bad CSV.
    """

    def __init__(
        self,
        folder: str | Path,
        geometry: FrameGeometry = PLAIN_GEOMETRY,
        *,
        fps: float | None = None,
        timestamps_csv: str | Path | None = None,
    ) -> None:
        super().__init__(geometry)
        self.folder = Path(folder)
        self.name = str(self.folder)
        if not self.folder.is_dir():
            raise SensorError(f"{self.folder}: no such folder of frames")
        self.files = sorted(p for p in self.folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not self.files:
            raise SensorError(f"{self.folder}: no image files ({', '.join(IMAGE_SUFFIXES)})")
        if (fps is None) == (timestamps_csv is None):
            raise ValueError(f"{self.folder}: give the frames' fps or a timestamps CSV (one)")
        if fps is not None:
            if not fps > 0:
                raise ValueError(f"fps must be > 0, got {fps}")
            self.times = [i / float(fps) for i in range(len(self.files))]
        else:
            self.times = self._read_times(Path(timestamps_csv))  # type: ignore[arg-type]
        self._next = 0

    def _read_times(self, path: Path) -> list[float]:
        try:
            with open(path, newline="", encoding="utf-8") as handle:
                rows = list(csv.DictReader(handle))
        except OSError as err:
            raise ValueError(f"{path}: cannot read the timestamps CSV ({err})") from err
        if not rows or "timestamp_s" not in rows[0]:
            raise ValueError(f"{path}: expected a column timestamp_s (and optionally file)")
        try:
            if "file" in rows[0]:
                by_name = {r["file"]: float(r["timestamp_s"]) for r in rows}
                missing = [p.name for p in self.files if p.name not in by_name]
                if missing:
                    raise ValueError(f"{path}: no timestamp for {missing[0]}")
                return [by_name[p.name] for p in self.files]
            times = [float(r["timestamp_s"]) for r in rows]
        except (TypeError, ValueError) as err:
            raise ValueError(f"{path}: {err}") from err
        if len(times) != len(self.files):
            raise ValueError(f"{path}: {len(times)} timestamps for {len(self.files)} frames")
        return times

    def _grab(self) -> tuple[float, np.ndarray] | None:
        if self._next >= len(self.files):
            return None
        i, self._next = self._next, self._next + 1
        try:  # its size checked before decoding, a truncated file refused
            frame = read_image_file(self.files[i])
        except (ValueError, OSError) as err:
            self.frames_read += 1
            raise FrameError(f"{err} (not a readable image)") from None
        return self.times[i], frame


class RosbagSource(FrameSourceBase):
    """The images of a ROS 2 (or ROS 1) bag, with the bag's own timestamps, and the
    grasp's force and width readings from the same bag (``acquisition/rosbag.py``,
    docs/ros2.md). A replay: ``live`` is False.

    Args:
        target: ``PATH[,image=TOPIC][,force=TOPIC][,width=TOPIC][,axis=z][,joints=A+B]
            [,stamps=header]`` (``rosbag.parse_bag_options``).

    Attributes:
        readings_arrays: ``(timestamp_s, force_n, width_m)`` of the bag, on the frames'
            clock (``readings.Readings(*source.readings_arrays)``).

    Raises:
        SensorError: no such bag, or ``rosbags`` is not installed.
        ValueError: a topic missing or ambiguous, a malformed option.
    """

    def __init__(self, target: str, geometry: FrameGeometry = PLAIN_GEOMETRY) -> None:
        super().__init__(geometry)
        from tactile_compliance.acquisition.rosbag import BagError, open_bag

        try:
            self._bag: Any = open_bag(target)
        except BagError as err:
            text = str(err)
            if "no such bag" in text or "rosbags" in text:
                raise SensorError(text) from None
            raise
        self.name = f"rosbag {self._bag.path}"
        try:
            self.readings_arrays = self._bag.readings()
        except BaseException:
            self._bag.close()
            raise
        self._images = self._bag.images()

    def _grab(self) -> tuple[float, np.ndarray] | None:
        if self._bag is None:
            return None
        return next(self._images, None)

    def close(self) -> None:
        if getattr(self, "_bag", None) is not None:
            self._bag.close()
            self._bag = None


# ---------------------------------------------------------------------- specs
SPEC_KINDS = ("mini", "wedge", "digit", "video", "camera", "folder", "rosbag")


def open_source(
    spec: str,
    *,
    geometry: FrameGeometry | None = None,
    fps: float | None = None,
    timestamps_csv: str | Path | None = None,
) -> FrameSourceBase:
    """Open the source a spec string names (the table in docs/inference.md, "Live
    sensors, calibration and your own grasps").

    Args:
        geometry: replaces the preset's warp/crop/resize (a calibration's geometry).
        fps, timestamps_csv: the frames' timing for a folder.

    Raises:
        ValueError: an unknown kind; SensorError: nothing to open there.
    """
    kind, sep, target = spec.partition(":")
    if not sep or target.startswith("//") or len(kind) < 2:
        kind, target = "", spec  # a plain path, index or URL (or a Windows drive letter)
    elif kind not in SPEC_KINDS:
        raise ValueError(
            f"unknown source kind {kind!r} in {spec!r}; use one of {', '.join(SPEC_KINDS)} "
            f"(e.g. mini:0, video:grasp.avi)"
        )
    if not target:
        raise ValueError(f"source spec {spec!r} names no device, file or URL")

    def pick(default: FrameGeometry) -> FrameGeometry:
        return geometry if geometry is not None else default

    if kind == "mini":
        return gelsight_mini(target, pick(MINI_GEOMETRY))
    if kind == "wedge":
        return gelsight_wedge(target, geometry=pick(WEDGE_GEOMETRY))
    if kind == "digit":
        return DigitSource(target, pick(PLAIN_GEOMETRY))
    if kind == "rosbag":
        return RosbagSource(target, pick(PLAIN_GEOMETRY))
    if kind == "folder" or (kind == "" and Path(target).is_dir()):
        return FolderSource(target, pick(PLAIN_GEOMETRY), fps=fps, timestamps_csv=timestamps_csv)
    # video, camera, or a plain path, index or URL
    if kind == "camera" and not (target.isdigit() or target.startswith("/dev/")):
        raise ValueError(f"camera:{target}: expected a camera index or a /dev/ path")
    return VideoCaptureSource(target, pick(PLAIN_GEOMETRY))
