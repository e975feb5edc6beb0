"""Grasps recorded as ROS 2 (or ROS 1) bags, read with the pure-Python ``rosbags`` library
(the optional ``ros`` extra; no ROS installation). See docs/ros2.md.

A bag holds three topics: the tactile images (``sensor_msgs/Image`` or
``sensor_msgs/CompressedImage``), the force (``geometry_msgs/WrenchStamped``) and the
gripper width (``sensor_msgs/JointState``). This module reads them into arrays, with the
bag's own timestamps; ``sensors.RosbagSource`` (the ``rosbag:PATH`` spec) turns the
images into a frame source and its readings into ``readings.Readings``.

Time: every message's ``header.stamp`` (its capture time), or the time the bag logged it
where that stamp is zero or ``stamps="bag"`` is asked for; in seconds since the bag's
first logged message, the same origin for the three topics.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "FORCE_AXES",
    "FORCE_TYPES",
    "IMAGE_TYPES",
    "WIDTH_TYPES",
    "BagError",
    "BagGrasp",
    "BagTopics",
    "decode_image",
    "open_bag",
    "parse_bag_options",
]

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
FORCE_TYPES = ("geometry_msgs/msg/WrenchStamped",)
WIDTH_TYPES = ("sensor_msgs/msg/JointState",)
FORCE_AXES = ("x", "y", "z", "-x", "-y", "-z", "norm")
STAMPS = ("header", "bag")

#: ``sensor_msgs/Image`` encodings read, with their channel count.
_ENCODINGS = {"bgr8": 3, "rgb8": 3, "bgra8": 4, "rgba8": 4, "mono8": 1}

#: The keys of ``rosbag:PATH,KEY=VALUE,...``.
OPTION_KEYS = ("image", "force", "width", "axis", "joints", "stamps")


class BagError(ValueError):
    """A bag cannot be read as a grasp (no such topic, an unreadable message, rosbags
    missing)."""


@dataclass(frozen=True)
class BagTopics:
    """Which topics of a bag hold the grasp, and how to read them.

    Attributes:
        image: the image topic; None: the bag's only Image or CompressedImage topic.
        force: the WrenchStamped topic; None: the bag's only one.
        width: the JointState topic; None: the bag's only one.
        axis: the wrench's force component that is the normal (grip) force, in N:
            ``x``, ``y``, ``z`` (default), the same negated (``-z``), or ``norm`` (|F|).
        joints: the joint names whose positions (m) add up to the opening width; None:
            every joint whose name holds ``finger`` (a Franka hand's
            ``panda_finger_joint1`` and ``panda_finger_joint2``, each one finger's travel),
            else every joint of the message.
        stamps: ``header`` (the messages' own stamps; the log time where a stamp is zero)
            or ``bag`` (the time the bag logged each message).
    """

    image: str | None = None
    force: str | None = None
    width: str | None = None
    axis: str = "z"
    joints: tuple[str, ...] | None = None
    stamps: str = "header"

    def __post_init__(self) -> None:
        if self.axis not in FORCE_AXES:
            raise BagError(f"force axis {self.axis!r}: use one of {', '.join(FORCE_AXES)}")
        if self.stamps not in STAMPS:
            raise BagError(f"stamps {self.stamps!r}: use header or bag")


def parse_bag_options(target: str) -> tuple[Path, BagTopics]:
    """``PATH[,KEY=VALUE...]`` (the part after ``rosbag:``) -> (bag path, topics).

    Keys: ``image``, ``force``, ``width`` (topic names), ``axis`` (see :class:`BagTopics`),
    ``joints`` (names joined by ``+``), ``stamps`` (``header`` or ``bag``). E.g.
    ``grasp_bag,image=/gelsight/image_raw,force=/ft/wrench,axis=-z``.

    Raises:
        BagError: an unknown key or a malformed option.
    """
    path, *options = target.split(",")
    values: dict[str, Any] = {}
    for option in options:
        key, sep, value = option.partition("=")
        key = key.strip()
        if not sep or key not in OPTION_KEYS or not value:
            raise BagError(
                f"rosbag option {option!r}: expected KEY=VALUE with KEY one of "
                f"{', '.join(OPTION_KEYS)} (e.g. rosbag:grasp_bag,image=/gelsight/image_raw)"
            )
        values[key] = tuple(v for v in value.split("+") if v) if key == "joints" else value
    return Path(path), BagTopics(**values)


def _rosbags() -> Any:
    """The ``rosbags`` modules, or a one-line BagError saying how to install them."""
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError as err:
        raise BagError(
            "reading ROS bags needs the optional package rosbags, which is not installed: "
            "pip install 'tactile-compliance[ros]' (or pip install rosbags; pure Python, "
            "no ROS installation)"
        ) from err
    return AnyReader, get_typestore(Stores.LATEST)


def _stamp_ns(message: Any, logged_ns: int, stamps: str) -> int:
    """A message's time in ns: its header stamp (unless zero or ``stamps="bag"``)."""
    header = getattr(message, "header", None)
    if stamps == "header" and header is not None:
        ns = int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)
        if ns:
            return ns
    return int(logged_ns)


def decode_image(message: Any, msgtype: str) -> np.ndarray:
    """A ``sensor_msgs/Image`` (bgr8, rgb8, bgra8, rgba8, mono8) or
    ``sensor_msgs/CompressedImage`` (JPEG, PNG) message, from a bag or an rclpy
    subscription -> uint8 BGR (H, W, 3).

    Raises:
        BagError: another encoding, or data that does not decode.
    """
    import cv2

    raw = message.data  # rosbags: a numpy array; rclpy: an array.array or bytes
    try:
        data = np.frombuffer(memoryview(raw).cast("B"), dtype=np.uint8)
    except TypeError:  # a list of ints
        data = np.asarray(raw, dtype=np.uint8)
    if msgtype.endswith("CompressedImage"):
        image = cv2.imdecode(data, cv2.IMREAD_COLOR)
        if image is None:
            raise BagError(f"a CompressedImage ({message.format!r}) does not decode")
        return image
    encoding = str(message.encoding).lower()
    channels = _ENCODINGS.get(encoding)
    if channels is None:
        raise BagError(
            f"image encoding {message.encoding!r} is not read; use one of "
            f"{', '.join(_ENCODINGS)} or a CompressedImage"
        )
    height, width, step = int(message.height), int(message.width), int(message.step)
    if data.size < height * step or step < width * channels:
        raise BagError(
            f"an Image of {height}x{width} {encoding} holds {data.size} bytes, "
            f"expected {height} rows of {step}"
        )
    rows = data[: height * step].reshape(height, step)[:, : width * channels]
    image = rows.reshape(height, width, channels)
    if encoding == "mono8":
        return np.ascontiguousarray(np.repeat(image, 3, axis=2))
    if encoding.startswith("rgb"):
        image = image[..., 2::-1]
    return np.ascontiguousarray(image[..., :3])


class BagGrasp:
    """An open bag: its image messages one by one, and its force and width readings.

    Args:
        path: the bag (a rosbag2 directory, or a ROS 1 ``.bag`` file).
        topics: which topics to read (:class:`BagTopics`).

    Raises:
        BagError: not a bag, rosbags missing, a topic missing or ambiguous.
    """

    def __init__(self, path: str | Path, topics: BagTopics = BagTopics()) -> None:
        self.path = Path(path)
        self.topics = topics
        if not self.path.exists():
            raise BagError(f"{self.path}: no such bag (a rosbag2 directory or a .bag file)")
        AnyReader, typestore = _rosbags()
        try:
            self._reader = AnyReader([self.path], default_typestore=typestore)
            self._reader.open()
        except Exception as err:  # rosbags raises its own errors for a damaged bag
            raise BagError(f"{self.path}: not a readable ROS bag ({err})") from err
        try:
            self.image = self._connection("image", topics.image, IMAGE_TYPES)
            self.force = self._connection("force", topics.force, FORCE_TYPES)
            self.width = self._connection("width", topics.width, WIDTH_TYPES)
            #: The origin of every time, in ns: the bag's first logged message.
            self.origin_ns = int(self._reader.start_time)
        except BaseException:
            self.close()
            raise

    def _connection(self, what: str, topic: str | None, types: tuple[str, ...]) -> Any:
        connections = list(self._reader.connections)
        found = sorted({c.topic: c.msgtype for c in connections}.items())
        listed = ", ".join(f"{t} ({m})" for t, m in found) or "none"
        wanted = " or ".join(t.replace("/msg/", "/") for t in types)
        if topic is None:
            matching = sorted({c.topic for c in connections if c.msgtype in types})
            if len(matching) != 1:
                which = "no" if not matching else f"{len(matching)}"
                raise BagError(
                    f"{self.path}: {which} {wanted} topics; name the {what} topic "
                    f"(rosbag:{self.path},{what}=TOPIC). The bag's topics: {listed}"
                )
            topic = matching[0]
        chosen = [c for c in connections if c.topic == topic]
        if not chosen:
            raise BagError(f"{self.path}: no topic {topic!r}; the bag's topics: {listed}")
        if chosen[0].msgtype not in types:
            raise BagError(
                f"{self.path}: topic {topic} holds {chosen[0].msgtype}, not {wanted} (the {what})"
            )
        return chosen

    def _seconds(self, ns: int) -> float:
        return (ns - self.origin_ns) / 1e9

    def _messages(self, connections: Any) -> Iterator[tuple[int, Any, str]]:
        for connection, logged_ns, raw in self._reader.messages(connections=connections):
            try:
                message = self._reader.deserialize(raw, connection.msgtype)
            except Exception as err:
                raise BagError(
                    f"{self.path}: a {connection.msgtype} message on {connection.topic} does "
                    f"not deserialise ({err})"
                ) from err
            yield _stamp_ns(message, logged_ns, self.topics.stamps), message, connection.msgtype

    def images(self) -> Iterator[tuple[float, np.ndarray]]:
        """``(timestamp_s, uint8 BGR frame)`` of every image message, in the bag's order."""
        for ns, message, msgtype in self._messages(self.image):
            yield self._seconds(ns), decode_image(message, msgtype)

    def readings(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(timestamp_s, force_n, width_m)`` at the force messages' times: the force
        component ``topics.axis`` [N], and the width [m] (the named joints' positions
        added) linearly interpolated from the joint states to those times. Force
        messages outside the joint states' time range are left out; repeated times keep
        the first message.

        Raises:
            BagError: no force or width message, no named joint, no overlap in time.
        """
        axis = self.topics.axis
        times, forces = [], []
        for ns, message, _ in self._messages(self.force):
            f = message.wrench.force
            vector = np.array([f.x, f.y, f.z], dtype=np.float64)
            if axis == "norm":
                value = float(np.linalg.norm(vector))
            else:
                value = float(vector["xyz".index(axis[-1])]) * (-1.0 if axis[0] == "-" else 1.0)
            times.append(self._seconds(ns))
            forces.append(value)
        width_times, widths = [], []
        for ns, message, _ in self._messages(self.width):
            width_times.append(self._seconds(ns))
            widths.append(self._width(message))
        for what, values in (("force", times), ("width", width_times)):
            if not values:
                raise BagError(f"{self.path}: no {what} message")
        t, f = _sorted_unique(np.asarray(times), np.asarray(forces))
        wt, w = _sorted_unique(np.asarray(width_times), np.asarray(widths))
        inside = (t >= wt[0]) & (t <= wt[-1])
        if not inside.any():
            raise BagError(
                f"{self.path}: the force messages ({t[0]:.3f}..{t[-1]:.3f} s) and the joint "
                f"states ({wt[0]:.3f}..{wt[-1]:.3f} s) do not overlap in time"
            )
        t, f = t[inside], f[inside]
        return t, f, np.interp(t, wt, w)

    def _width(self, message: Any) -> float:
        names = [str(n) for n in message.name]
        positions = np.asarray(message.position, dtype=np.float64)
        if self.topics.joints is not None:
            missing = [j for j in self.topics.joints if j not in names]
            if missing:
                raise BagError(
                    f"{self.path}: joint(s) {missing} not in the joint states "
                    f"(joints: {', '.join(names)})"
                )
            chosen = [names.index(j) for j in self.topics.joints]
        else:
            chosen = [i for i, n in enumerate(names) if "finger" in n] or list(range(len(names)))
        if not chosen or len(positions) < len(names):
            raise BagError(f"{self.path}: a joint state without positions for {names}")
        return float(positions[chosen].sum())

    def close(self) -> None:
        """Close the bag (idempotent)."""
        reader = getattr(self, "_reader", None)
        if reader is not None:
            self._reader = None
            reader.close()


def _sorted_unique(t: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    order = np.argsort(t, kind="stable")
    t, v = t[order], v[order]
    keep = np.concatenate([[True], np.diff(t) > 0])
    return t[keep], v[keep]


def open_bag(target: str) -> BagGrasp:
    """Open the bag ``PATH[,KEY=VALUE...]`` names (:func:`parse_bag_options`)."""
    path, topics = parse_bag_options(target)
    return BagGrasp(path, topics)
