"""Frame sources (sensor cameras, replayed videos, folders of frames) yielding
``(timestamp_s, uint8 BGR frame)`` cut to the pad. See docs/inference.md, "Live sensors,
calibration and your own grasps".

Every source yields frames of one (H, W, 3) uint8 BGR shape after its ``FrameGeometry``;
a video or bag gives its own frame times, a live device is stamped on arrival
(:class:`StampedOnArrival`). :class:`SensorError` (an ``OSError``): the source fails;
:class:`FrameError` (a ``ValueError``): one frame is unusable and the source goes on.
"""

from __future__ import annotations

import contextlib
import csv
import os
import queue
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import cv2
import numpy as np

from tactile_compliance.acquisition.geometry import (
    MINI_CAPTURE_SIZE,
    MINI_GEOMETRY,
    PLAIN_GEOMETRY,
    WEDGE_GEOMETRY,
    Corners,
    FrameError,
    FrameGeometry,
    FrameSizeError,
)
from tactile_compliance.data.image_ops import read_image_file

__all__ = [
    "MINI_GEOMETRY",
    "PLAIN_GEOMETRY",
    "SENSORS",
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
    "SensorKind",
    "StampedOnArrival",
    "TimestampError",
    "VideoCaptureSource",
    "gelsight_mini",
    "gelsight_wedge",
    "iter_frames",
    "names_a_file",
    "open_source",
    "parse_spec",
    "read_on_arrival",
]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


class SensorError(OSError):
    """A source cannot be opened or stopped delivering frames (device, stream, file)."""


class TimestampError(FrameError):
    """A frame's timestamp is older than the previous frame's (time going backwards)."""


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
    (docs/inference.md, "Clocks: frames stamped on arrival"). Every frame is kept, in
    order, with its arrival time; :attr:`pending` says how far behind the consumer is.

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
        self.is_file = names_a_file(text)
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


#: Where Linux names its video devices (``videoN/name``: a Mini's starts "GelSight Mini").
V4L_SYSFS = Path("/sys/class/video4linux")
#: How far a Mini's frames may be from its 3280:2464 aspect ratio (relative).
MINI_ASPECT_TOLERANCE = 0.02


def device_name(device: str) -> str | None:
    """The name the OS gives the camera at an index or ``/dev/`` path (Linux: sysfs, which
    gsrobotics' own tools read to find a Mini); None where it gives none."""
    node = f"video{device}" if device.isdigit() else Path(os.path.realpath(device)).name
    try:
        return (V4L_SYSFS / node / "name").read_text(encoding="utf-8").strip() or None
    except (OSError, UnicodeDecodeError):
        return None


def gelsight_mini(
    device: int | str | Path = 0,
    geometry: FrameGeometry = MINI_GEOMETRY,
    *,
    capture_size: tuple[int, int] = MINI_CAPTURE_SIZE,
    fourcc: str = "MJPG",
    timestamps: str = "auto",
) -> VideoCaptureSource:
    """A GelSight Mini (a UVC camera) by index, ``/dev/v4l/by-id/...`` path or a replayed
    video of one.

    A device is checked to be a Mini, as far as OpenCV and the OS tell: its name (where
    the OS gives one: Linux) must contain "GelSight", and the mode it delivers must have
    the Mini's 4:3 aspect ratio (3280 x 2464 px asked for).

    Raises:
        SensorError: nothing there, or a camera that is not a Mini (the message names it).
    """
    target = str(device)
    if not names_a_file(target) and "://" not in target:
        name = device_name(target)
        if name is not None and "gelsight" not in name.lower():
            raise SensorError(
                f"mini:{target}: the camera there is {name!r}, not a GelSight Mini; give "
                f"the Mini's index or /dev/v4l/by-id/ path (v4l2-ctl --list-devices), or "
                f"camera:{target} for another camera"
            )
    source = VideoCaptureSource(
        device,
        geometry,
        capture_size=capture_size,
        fourcc=fourcc,
        timestamps=timestamps,
        name=f"GelSight Mini {device}",
    )
    if not source.is_file:
        width = source._capture.get(cv2.CAP_PROP_FRAME_WIDTH)
        height = source._capture.get(cv2.CAP_PROP_FRAME_HEIGHT)
        expected = MINI_CAPTURE_SIZE[1] / MINI_CAPTURE_SIZE[0]
        if width > 0 and height > 0 and abs(width / height / expected - 1) > MINI_ASPECT_TOLERANCE:
            source.close()
            raise SensorError(
                f"mini:{target}: the camera delivers {width:.0f}x{height:.0f} px, not a "
                f"GelSight Mini's 4:3 stream ({MINI_CAPTURE_SIZE[1]}x{MINI_CAPTURE_SIZE[0]} "
                f"asked for); give the Mini's index, or camera:{target} for another camera"
            )
    return source


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


# ---------------------------------------------------------------------- the table
def names_a_file(target: str) -> bool:
    """Whether a ``VideoCaptureSource`` target is a video file (a replay), not a camera
    index, a ``/dev/`` device or a stream URL (both live)."""
    return not (target.isdigit() or "://" in target or target.startswith("/dev/"))


#: A kind's liveness: ``"yes"`` (a device: frames as they happen), ``"no"`` (a replay on
#: its recorded times) or ``"unless a file"`` (a device or stream, or a video file of one).
LIVENESS = ("yes", "no", "unless a file")


@dataclass(frozen=True)
class SensorKind:
    """One kind of frame source, named ``NAME:TARGET`` in a source spec (docs/sensors.md,
    "Adding a sensor").

    Attributes:
        name: the spec prefix (``mini`` in ``mini:0``).
        source_class: the :class:`FrameSourceBase` subclass that reads it.
        geometry: the default geometry (a calibration's replaces it).
        live: one of :data:`LIVENESS`. :func:`open_source` sets the source's ``live`` from
            it, so a live source's frames are stamped on arrival (:func:`read_on_arrival`).
        channel_order: the order of the channels its frames are in (every source's
            ``_grab`` returns BGR, the order OpenCV and the dataset use; the contract test
            in ``tests/test_sensors.py`` checks it).
        help: the spec's forms, for the CLI help and the docs.
        opens: ``(target, geometry, fps, timestamps_csv) -> source``.
    """

    name: str
    source_class: type[FrameSourceBase]
    geometry: FrameGeometry
    live: str
    channel_order: str
    help: str
    opens: Callable[[str, FrameGeometry, float | None, Any], FrameSourceBase]

    def is_live(self, target: str) -> bool:
        """Whether the source this kind opens at ``target`` is live."""
        return self.live == "yes" or (self.live == "unless a file" and not names_a_file(target))


def _camera(target: str, geometry: FrameGeometry, *_: Any) -> VideoCaptureSource:
    if not (target.isdigit() or target.startswith("/dev/")):
        raise ValueError(f"camera:{target}: expected a camera index or a /dev/ path")
    return VideoCaptureSource(target, geometry)


#: Every kind of frame source, in the order the CLI help and the docs list them. A new
#: sensor is one entry here and one class.
SENSORS = (
    SensorKind(
        "mini",
        VideoCaptureSource,
        MINI_GEOMETRY,
        "unless a file",
        "BGR",
        "mini:0, mini:/dev/v4l/by-id/...",
        lambda target, geometry, *_: gelsight_mini(target, geometry),
    ),
    SensorKind(
        "wedge",
        VideoCaptureSource,
        WEDGE_GEOMETRY,
        "unless a file",
        "BGR",
        "wedge:http://host:port/stream.mjpg",
        lambda target, geometry, *_: gelsight_wedge(target, geometry=geometry),
    ),
    SensorKind(
        "digit",
        DigitSource,
        PLAIN_GEOMETRY,
        "yes",
        "BGR",
        "digit:SERIAL",
        lambda target, geometry, *_: DigitSource(target, geometry),
    ),
    SensorKind("camera", VideoCaptureSource, PLAIN_GEOMETRY, "yes", "BGR", "camera:0", _camera),
    SensorKind(
        "video",
        VideoCaptureSource,
        PLAIN_GEOMETRY,
        "unless a file",
        "BGR",
        "video:FILE",
        lambda target, geometry, *_: VideoCaptureSource(target, geometry),
    ),
    SensorKind(
        "folder",
        FolderSource,
        PLAIN_GEOMETRY,
        "no",
        "BGR",
        "folder:DIR",
        lambda target, geometry, fps, times: FolderSource(
            target, geometry, fps=fps, timestamps_csv=times
        ),
    ),
    SensorKind(
        "rosbag",
        RosbagSource,
        PLAIN_GEOMETRY,
        "no",
        "BGR",
        "rosbag:BAG[,image=TOPIC,force=TOPIC,width=TOPIC] (docs/ros2.md)",
        lambda target, geometry, *_: RosbagSource(target, geometry),
    ),
)
_BY_NAME = {kind.name: kind for kind in SENSORS}


def parse_spec(spec: str) -> tuple[SensorKind, str]:
    """The kind and target a source spec names; a plain path, index or URL (no known
    prefix) is a ``folder`` when it is a directory, else a ``video``.

    Raises:
        ValueError: an unknown kind, or no target.
    """
    name, sep, target = spec.partition(":")
    if not sep or target.startswith("//") or len(name) < 2:
        # A plain path, index or URL (or a Windows drive letter).
        name, target = ("folder" if Path(spec).is_dir() else "video"), spec
    elif name not in _BY_NAME:
        raise ValueError(
            f"unknown source kind {name!r} in {spec!r}; use one of {', '.join(_BY_NAME)} "
            f"(e.g. mini:0, video:grasp.avi)"
        )
    if not target:
        raise ValueError(f"source spec {spec!r} names no device, file or URL")
    return _BY_NAME[name], target


def open_source(
    spec: str,
    *,
    geometry: FrameGeometry | None = None,
    fps: float | None = None,
    timestamps_csv: str | Path | None = None,
) -> FrameSourceBase:
    """Open the source a spec string names (:data:`SENSORS`; docs/inference.md, "Live
    sensors, calibration and your own grasps"); its ``live`` is the table's.

    Args:
        geometry: replaces the kind's default warp/crop/resize (a calibration's geometry).
        fps, timestamps_csv: the frames' timing for a folder.

    Raises:
        ValueError: an unknown kind; SensorError: nothing to open there.
    """
    kind, target = parse_spec(spec)
    source = kind.opens(
        target, kind.geometry if geometry is None else geometry, fps, timestamps_csv
    )
    source.live = kind.is_live(target)
    return source


def read_on_arrival(source: FrameSourceBase) -> FrameSourceBase:
    """``source`` read by a background thread (:class:`StampedOnArrival`) when it is live,
    so each frame is stamped when it arrives; a replay as it is."""
    if source.live and not isinstance(source, StampedOnArrival):
        return StampedOnArrival(source)
    return source
