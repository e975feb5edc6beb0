"""Calibration to your own sensor: its frame geometry and its no-contact reference frame.

A :class:`SensorCalibration` is one JSON file (``tactile-compliance calibrate SOURCE --out
sensor.json``) holding

* ``geometry``: the warp / crop / resize (:class:`~.sensors.FrameGeometry`) that turns the
  camera frame into the sensor frame, with the camera frame size it was made for;
* ``reference_png_base64``: the no-contact reference frame (after the geometry), the
  per-pixel median of ``n_frames`` frames recorded with nothing touching the gel, as a
  lossless PNG (BGR, uint8) inside the JSON, so one file travels with nothing to lose;
* what it was recorded from (``source``, ``n_frames``, ``created_utc``).

Difference images are ``(frame - GaussianBlur11x11(reference)) / 255 + 0.5``
(``data.image_ops.difference_images``): with a calibration, every grasp uses this
reference instead of its own first frame, so a grasp that starts in contact still gets
correct difference images. Sources opened with a calibration (:meth:`open`) apply its
geometry and refuse frames of another camera size.
"""

from __future__ import annotations

import base64
import json
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from tactile_compliance.data.plausibility import check_size
from tactile_compliance.inference.sensors import (
    FrameError,
    FrameGeometry,
    FrameSourceBase,
    SensorError,
    iter_frames,
    open_source,
)
from tactile_compliance.outputs import atomic_file, check_output_file

__all__ = ["CALIBRATION_FORMAT", "SensorCalibration", "calibrate"]

CALIBRATION_FORMAT = "tactile-compliance-sensor-calibration"
CALIBRATION_VERSION = 1


@dataclass
class SensorCalibration:
    """A sensor's frame geometry and no-contact reference frame.

    Attributes:
        geometry: warp / crop / resize of camera frames; ``input_size`` is the camera
            frame size the calibration was recorded at.
        reference: no-contact frame (H, W, 3) uint8 BGR, after the geometry.
        source: the source spec it was recorded from.
        n_frames: frames whose per-pixel median is the reference.
        created_utc: ISO 8601 time of the recording.
    """

    geometry: FrameGeometry
    reference: np.ndarray
    source: str = ""
    n_frames: int = 0
    created_utc: str = field(
        default_factory=lambda: datetime.now(timezone.utc).isoformat(timespec="seconds")
    )

    def __post_init__(self) -> None:
        ref = np.asarray(self.reference)
        if ref.ndim != 3 or ref.shape[2] != 3 or ref.dtype != np.uint8:
            raise ValueError(
                f"the reference frame must be uint8 (H, W, 3), got {ref.dtype} {ref.shape}"
            )
        problem = reference_problem(ref)
        if problem:
            raise ValueError(problem)
        self.reference = ref

    @property
    def frame_size(self) -> tuple[int, int]:
        """(H, W) px of the sensor frames (the reference's size)."""
        return int(self.reference.shape[0]), int(self.reference.shape[1])

    def to_dict(self) -> dict[str, Any]:
        """The JSON document (reference as base64 PNG)."""
        ok, png = cv2.imencode(".png", self.reference)
        if not ok:  # pragma: no cover - PNG encoding of uint8 never fails
            raise ValueError("cannot encode the reference frame as PNG")
        return {
            "format": CALIBRATION_FORMAT,
            "format_version": CALIBRATION_VERSION,
            "geometry": self.geometry.to_dict(),
            "frame_size": list(self.frame_size),
            "reference_png_base64": base64.b64encode(png.tobytes()).decode("ascii"),
            "source": self.source,
            "n_frames": int(self.n_frames),
            "created_utc": self.created_utc,
        }

    def save(self, path: str | Path) -> Path:
        """Write the JSON file (atomically; refuses to replace a file that is not a
        sensor calibration)."""
        path = Path(path)
        check_output_file(path, "sensor calibration", _is_calibration, option="--out")
        with atomic_file(path, "w") as handle:
            json.dump(self.to_dict(), handle, indent=2)
            handle.write("\n")
        return path

    @classmethod
    def load(cls, path: str | Path) -> SensorCalibration:
        """Read a calibration file.

        Raises:
            ValueError: not a calibration file, or a damaged one.
            OSError: the file cannot be read.
        """
        path = Path(path)
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as err:
            raise ValueError(f"{path}: not a sensor calibration (not JSON: {err})") from err
        except RecursionError:
            raise ValueError(f"{path}: not a sensor calibration (JSON nested too deeply)") from None
        if not isinstance(data, dict) or data.get("format") != CALIBRATION_FORMAT:
            raise ValueError(f"{path}: not a sensor calibration (no format {CALIBRATION_FORMAT})")
        try:
            geometry = FrameGeometry.from_dict(data["geometry"])
            raw = base64.b64decode(data["reference_png_base64"])
            # The header first: a 20000 x 20000 PNG would take 1.2 GB to decode.
            size = check_size(_png_size(raw), "the reference frame")
            if geometry.output_size is not None and size != geometry.output_size:
                raise ValueError(
                    f"the reference frame is {size[0]}x{size[1]} px, the geometry's "
                    f"output_size {geometry.output_size[0]}x{geometry.output_size[1]}"
                )
            reference = cv2.imdecode(np.frombuffer(raw, np.uint8), cv2.IMREAD_COLOR)
            if reference is None:
                raise ValueError("the reference frame is not a PNG")
            return cls(
                geometry=geometry,
                reference=reference,
                source=str(data.get("source", "")),
                n_frames=int(data.get("n_frames", 0)),
                created_utc=str(data.get("created_utc", "")),
            )
        except (KeyError, TypeError, ValueError, AttributeError, base64.binascii.Error) as err:  # type: ignore[attr-defined]
            raise ValueError(f"{path}: damaged sensor calibration ({err})") from err

    def open(self, spec: str, **options: Any) -> FrameSourceBase:
        """Open ``spec`` (see ``sensors.open_source``) with this calibration's geometry."""
        return open_source(spec, geometry=self.geometry, **options)


#: A reference whose grey levels vary by less than this (standard deviation over the
#: pixels) is uniform: no lit gel looks like that (a GelSight pad shows its LED gradients
#: and the gel's texture; the synthetic sensor's reference varies by tens of levels).
MIN_REFERENCE_STD = 2.0
#: A reference with more than this share of saturated (255 in every channel) pixels is
#: overexposed: contact cannot brighten those pixels, so difference images lose it.
MAX_SATURATED_SHARE = 0.5


def reference_problem(reference: np.ndarray) -> str | None:
    """Why a no-contact reference (H, W, 3) uint8 cannot be a lit sensor's, or None.

    A uniform (grey, black) or overexposed (white) reference gives difference images that
    are the frames themselves or clipped: the model then estimates from garbage (6e8 Pa
    became 2.7e8 Pa, a white one 8.7e11 Pa), so it is refused, naming the consequence.
    """
    grey = reference.astype(np.float32).mean(axis=2)
    std = float(grey.std())
    if std < MIN_REFERENCE_STD:
        return (
            f"the reference frame is uniform (grey-level std {std:.2f} < {MIN_REFERENCE_STD:g}, "
            f"mean {float(grey.mean()):.0f}): not a lit sensor with nothing touching it; "
            f"difference images against it would be wrong and so would every estimate "
            f"(record the calibration again)"
        )
    saturated = float((reference == 255).all(axis=2).mean())
    if saturated > MAX_SATURATED_SHARE:
        return (
            f"the reference frame is overexposed ({100 * saturated:.0f}% of its pixels are "
            f"white): contact cannot show there and every estimate would be wrong (lower the "
            f"camera's exposure and record the calibration again)"
        )
    return None


def _png_size(png: bytes) -> tuple[int, int]:
    """(H, W) px from a PNG's header, read before the image is decoded."""
    if len(png) < 24 or png[:8] != b"\x89PNG\r\n\x1a\n" or png[12:16] != b"IHDR":
        raise ValueError("the reference frame is not a PNG")
    width, height = int.from_bytes(png[16:20], "big"), int.from_bytes(png[20:24], "big")
    return height, width


def _is_calibration(path: Path) -> bool:
    try:
        return json.loads(path.read_text(encoding="utf-8")).get("format") == CALIBRATION_FORMAT
    except (ValueError, AttributeError, UnicodeDecodeError):
        return False


def calibrate(
    spec: str,
    *,
    geometry: FrameGeometry | None = None,
    n_frames: int = 30,
    out: str | Path | None = None,
    **options: Any,
) -> SensorCalibration:
    """Record the no-contact reference of the sensor at ``spec``: the per-pixel median of
    its first ``n_frames`` good frames (nothing may touch the gel meanwhile).

    Args:
        spec: a source spec (``sensors.open_source``).
        geometry: warp / crop / resize; default the source's preset. Its ``input_size``
            is set to the camera frame size seen, so later frames of another size are
            refused.
        n_frames: frames to take the median of (the median removes read noise and a
            passing flicker).
        out: also write the calibration there (JSON).
        options: for ``open_source`` (``fps`` / ``timestamps_csv`` of a folder).

    Raises:
        SensorError: the source cannot be opened or delivers fewer than ``n_frames``.
    """
    if n_frames < 1:
        raise ValueError(f"n_frames must be >= 1, got {n_frames}")
    if out is not None:  # refuse a bad --out before touching the sensor
        check_output_file(Path(out), "sensor calibration", _is_calibration, option="--out")
    skipped: list[FrameError] = []
    frames: list[np.ndarray] = []
    with open_source(spec, geometry=geometry, **options) as source:
        camera_size: tuple[int, int] | None = None
        for _, frame in iter_frames(source, skipped.append):
            frames.append(frame)
            if camera_size is None:
                camera_size = _camera_size(source)
            if len(frames) >= n_frames:
                break
        used = source.geometry
    if len(frames) < n_frames:
        why = f"; {len(skipped)} bad frames, first: {skipped[0]}" if skipped else ""
        raise SensorError(f"{spec}: only {len(frames)} of {n_frames} frames arrived{why}")
    if used.input_size is None and camera_size is not None:
        used = FrameGeometry.from_dict({**used.to_dict(), "input_size": list(camera_size)})
    reference = np.median(np.stack(frames), axis=0).round().astype(np.uint8)
    calibration = SensorCalibration(
        geometry=used, reference=reference, source=spec, n_frames=len(frames)
    )
    if out is not None:
        calibration.save(out)
    return calibration


def _camera_size(source: FrameSourceBase) -> tuple[int, int] | None:
    """The raw camera frame size a source last delivered, when it can tell."""
    size = getattr(source, "last_raw_size", None)
    return None if size is None else (int(size[0]), int(size[1]))
