"""Helpers shared by the test modules: the one place a test module imports them from (no
test module imports another). Toy stores are ``toy_store.py``'s."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from typer.testing import CliRunner

from tactile_compliance.acquisition.sensors import PLAIN_GEOMETRY, FrameGeometry, FrameSourceBase

runner = CliRunner()

#: (H, W) px and frames/s of :func:`make_replay_grasp`'s videos (every second frame of the
#: 30 fps simulation).
REPLAY_SIZE = (60, 84)
REPLAY_FPS = 15.0
#: The pad corners of the public dataset's Wedge rig (x,y px, for ``--corners``).
WEDGE_CORNERS = "46,87 439,121 446,368 52,425"


# ---------------------------------------------------------------------- the command line
def cli(*args: Any) -> str:
    """Run ``tactile-compliance ARGS`` in this process; assert it exits 0; its output."""
    from tactile_compliance.cli import app

    result = runner.invoke(app, [str(a) for a in args])
    assert result.exit_code == 0, (args, result.output, result.exception)
    return result.output


def json_lines(output: str) -> list[dict[str, Any]]:
    """The JSON objects of a command's output, one per line starting with ``{``."""
    return [json.loads(line) for line in output.splitlines() if line.startswith("{")]


# ---------------------------------------------------------------------- frames and videos
class ArraySource(FrameSourceBase):
    """Frames from memory, frame i at ``i / fps`` s: a replay, like a video file.

    ``live=True`` serves them like a live camera instead: frame k arrives ``k / fps`` s
    after the first and is stamped with the time it is read (``time.monotonic()`` from
    the first frame), as a device stamps it.
    """

    def __init__(
        self,
        frames: Any,
        geometry: FrameGeometry = PLAIN_GEOMETRY,
        *,
        fps: float = 30.0,
        live: bool = False,
        name: str = "array",
    ) -> None:
        super().__init__(geometry)
        self.frames, self.fps, self.live, self.name = frames, float(fps), live, name
        self.i, self.t0 = 0, None

    def _grab(self) -> tuple[float, np.ndarray] | None:
        if self.i >= len(self.frames):
            return None
        k, self.i = self.i, self.i + 1
        if not self.live:
            return k / self.fps, self.frames[k]
        if self.t0 is None:
            self.t0 = time.monotonic()
        time.sleep(max(0.0, self.t0 + k / self.fps - time.monotonic()))
        return time.monotonic() - self.t0, self.frames[k]


def write_video(path: Path, frames: np.ndarray, fps: float) -> None:
    """``(T, H, W, 3)`` uint8 BGR frames as an MJPG video."""
    h, w = frames.shape[1:3]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (w, h))
    assert writer.isOpened()
    for frame in frames:
        writer.write(frame)
    writer.release()


def write_level_video(path: Path, brightness: list[int], size: tuple[int, int] = (24, 32)) -> None:
    """A 30 fps MJPG video, frame t filled with ``brightness[t]`` but its blue channel,
    which is 10 everywhere (checks a BGR -> RGB flip)."""
    height, width = size
    frames = np.empty((len(brightness), height, width, 3), np.uint8)
    frames[:] = np.asarray(brightness, np.uint8)[:, None, None, None]
    frames[..., 0] = 10
    write_video(path, frames, 30)


def decoded(path: Path) -> np.ndarray:
    """Every frame of a video, as OpenCV decodes it: ``(T, H, W, 3)`` uint8 BGR."""
    capture = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, frame = capture.read()
        if not ok:
            return np.stack(frames)
        frames.append(frame)


# ---------------------------------------------------------------------- grasps
def make_replay_grasp(root: Path, size: tuple[int, int]) -> dict[str, Any]:
    """A replayable synthetic grasp in ``root``: ``grasp.avi`` (at :data:`REPLAY_FPS`), a
    no-contact ``still.avi``, ``readings.csv``, and the ground truth."""
    from tactile_compliance.acquisition.readings import write_readings_csv
    from tactile_compliance.synthetic.grasp import SimulationOptions, make_context
    from tactile_compliance.synthetic.objects import default_objects
    from tactile_compliance.synthetic.trajectories import camera_recording

    spec = default_objects(3, seed=4)[1]
    recording = camera_recording(make_context(spec, 4, SimulationOptions(image_size=size)), 0)
    root.mkdir(exist_ok=True)
    frames = recording.frames[::2]
    write_video(root / "grasp.avi", frames, REPLAY_FPS)
    rng = np.random.default_rng(0)
    still = recording.reference[None] + rng.integers(-2, 3, (5, *recording.reference.shape))
    write_video(root / "still.avi", np.clip(still, 0, 255).astype(np.uint8), REPLAY_FPS)
    times = np.arange(len(frames)) / REPLAY_FPS
    force, width = recording.force_n[::2], recording.width_m[::2]
    write_readings_csv(root / "readings.csv", times, force, width)
    return {
        "root": root,
        "video": root / "grasp.avi",
        "still": root / "still.avi",
        "readings": root / "readings.csv",
        "name": spec.name,
        "modulus_pa": recording.modulus_pa,
        "force": force,
        "width": width,
    }


def pressed_frames(
    n_frames: int = 46,
    onset: int = 9,
    release: int = 38,
    seed: int = 0,
    size: tuple[int, int] = (40, 48),
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An in-memory grasp: force (N) ramps up, holds with ripple, releases; ``(T, H, W, 3)``
    uint8 frames follow it (a blob growing with the force); width in m."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_frames, dtype=np.float64)
    u = np.clip((t - onset) / 14.0, 0.0, 1.0)
    force = 60.0 * (1 - (1 - u) ** 2) * (t >= onset)
    hold = (t > onset + 14) & (t < release)
    force[hold] *= 1 + 0.01 * np.sin(t[hold] * 1.7)
    force[t >= release] *= np.clip(1 - (t[t >= release] - release + 1) / 3, 0, 1)
    force = force + rng.normal(0, 0.05, n_frames)
    width = 0.05 - 0.004 * force / 60 + rng.normal(0, 1e-5, n_frames)
    yy, xx = np.mgrid[0 : size[0], 0 : size[1]]
    r2 = (yy - size[0] / 2) ** 2 + (xx - size[1] / 2) ** 2
    frames = np.empty((n_frames, *size, 3), np.uint8)
    for i, f in enumerate(force):
        blob = np.exp(-r2 / (2 * (2 + 8 * max(f, 0) / 60) ** 2)) * max(f, 0) / 60
        image = 0.5 + 0.2 * blob[..., None] * np.array([1.0, 0.6, 0.3])
        frames[i] = np.clip(np.rint((image + rng.normal(0, 0.004, image.shape)) * 255), 0, 255)
    return frames, force, width


def captured_press(width_m: float = 0.05, n: int = 40, seed: int = 0) -> Any:
    """A ``CapturedGrasp``: a press to 60 N over ``n`` frames of 24 x 32 px at 30 fps."""
    from tactile_compliance.acquisition.capture import CapturedGrasp

    t = np.arange(n, dtype=np.float64)
    force = 60.0 * np.clip((t - 6) / 20, 0, 1) ** 1.5
    rng = np.random.default_rng(seed)
    frames = rng.integers(100, 140, (n, 24, 32, 3), dtype=np.uint8)
    return CapturedGrasp(t / 30.0, frames, force, np.full(n, width_m))


# ---------------------------------------------------------------------- models, sensors
def top10nn_checkpoint(
    path: Path,
    inputs: str = "ImageFW",
    seed: int = 0,
    size: tuple[int, int] = (72, 72),
    sensor_units: dict[str, Any] | None = None,
) -> Path:
    """An untrained Top10NN ``best.pt`` (seeded) for ``inputs`` at ``size``, trained (as
    its record says) on estimates in ``sensor_units`` (None: the Wedge's)."""
    import torch

    from tactile_compliance.data.normalisation import NormalisationConstants
    from tactile_compliance.models import create_model
    from tactile_compliance.physics.estimators import SensorUnits
    from tactile_compliance.runs.checkpoint import save_checkpoint
    from tactile_compliance.runs.run_inputs import RunInputs

    torch.manual_seed(seed)
    model = create_model("top10nn", inputs=inputs)
    sensor = SensorUnits.from_dict(sensor_units)
    return save_checkpoint(
        path,
        model,
        run_inputs=RunInputs(size, size, NormalisationConstants(), inputs, sensor=sensor),
        config={},
        seed=0,
    )


def wedge_calibration(tmp_path: Path, video: Path) -> Path:
    """``calibrate wedge:VIDEO`` with the rig's pad corners: ``tmp_path/sensor.json``."""
    out = tmp_path / "sensor.json"
    cli(
        "calibrate",
        f"wedge:{video}",
        "--out",
        out,
        "--corners",
        WEDGE_CORNERS,
        "--warp-size",
        "300x400",
        "--frames",
        3,
    )
    return out


# ---------------------------------------------------------------------- ROS bags
#: The bags' clock origin: a real epoch time (their stamps are absolute), ns.
ORIGIN_NS = 1_701_869_000_123_456_789


def _bag_stamp(typestore, t_s):
    ns = ORIGIN_NS + round(t_s * 1e9)
    Time = typestore.types["builtin_interfaces/msg/Time"]
    Header = typestore.types["std_msgs/msg/Header"]
    return Header(stamp=Time(sec=ns // 10**9, nanosec=ns % 10**9), frame_id="gel"), ns


def write_bag(
    path,
    frames,
    frame_times_s,
    reading_times_s,
    force_n,
    width_m,
    *,
    image="raw",
    force_sign=1.0,
    image_topic="/gelsight/image_raw",
    extra_topics=(),
    width_times_s=None,
):
    """A rosbag2 directory: Image (bgr8) or CompressedImage (PNG) frames, WrenchStamped
    force (``force_sign`` x F along z), JointState of a Franka hand's two finger joints
    (half the width each), stamped ``ORIGIN_NS + t``."""
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    msgtype = "sensor_msgs/msg/Image" if image == "raw" else "sensor_msgs/msg/CompressedImage"
    messages = []
    for t, frame in zip(frame_times_s, frames, strict=True):
        header, ns = _bag_stamp(ts, t)
        if image == "raw":
            h, w = frame.shape[:2]
            msg = T[msgtype](header=header, height=h, width=w, encoding="bgr8",
                             is_bigendian=0, step=w * 3, data=frame.reshape(-1).copy())  # fmt: skip
        else:
            ok, png = cv2.imencode(".png", frame)
            assert ok
            msg = T[msgtype](header=header, format="png", data=png.reshape(-1))
        messages.append((image_topic, msgtype, ns, msg))
    Vector3, Wrench = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Wrench"]
    for t, f in zip(reading_times_s, force_n, strict=True):
        header, ns = _bag_stamp(ts, t)
        wrench = Wrench(
            force=Vector3(x=0.1, y=-0.2, z=force_sign * f), torque=Vector3(x=0, y=0, z=0)
        )
        stamped = T["geometry_msgs/msg/WrenchStamped"](header=header, wrench=wrench)
        messages.append(("/ft/wrench", "geometry_msgs/msg/WrenchStamped", ns, stamped))
    width_times = reading_times_s if width_times_s is None else width_times_s
    widths = (
        width_m if width_times_s is None else np.interp(width_times_s, reading_times_s, width_m)
    )
    for t, w in zip(width_times, widths, strict=True):
        header, ns = _bag_stamp(ts, t)
        state = T["sensor_msgs/msg/JointState"](
            header=header,
            name=["panda_finger_joint1", "panda_finger_joint2"],
            position=np.array([w / 2, w / 2]),
            velocity=np.zeros(0),
            effort=np.zeros(0),
        )
        messages.append(("/franka_gripper/joint_states", "sensor_msgs/msg/JointState", ns, state))
    for topic in extra_topics:
        header, ns = _bag_stamp(ts, 0.0)
        messages.append((topic, msgtype, ns, messages[0][3]))
    with Writer(path, version=8) as writer:
        connections = {}
        for topic, kind, ns, msg in sorted(messages, key=lambda m: m[2]):
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, kind, typestore=ts)
            writer.write(connections[topic], ns, ts.serialize_cdr(msg, kind))
    return path
