"""``tactile-compliance depth``: depth maps of tactile frames, as ``.npy`` files and
pictures. See docs/sensors.md, "The commands".
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from tactile_compliance.acquisition.calibration import SensorCalibration
from tactile_compliance.data.depth_model import grey_frame_problem
from tactile_compliance.data.image_ops import difference_images
from tactile_compliance.data.photometric import reconstruct_depth
from tactile_compliance.outputs import atomic_file, claim_output_dir

__all__ = ["depth_picture", "write_depth_maps"]


def depth_picture(depth_mm: np.ndarray) -> np.ndarray:
    """A uint8 BGR picture of one depth map (H, W) [mm], its peak written in the corner."""
    peak = float(np.max(depth_mm))
    scaled = np.clip(depth_mm / peak, 0.0, 1.0) if peak > 0 else np.zeros_like(depth_mm)
    picture = cv2.applyColorMap((scaled * 255).astype(np.uint8), cv2.COLORMAP_VIRIDIS)
    cv2.putText(
        picture, f"peak {peak:.2f} mm", (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255)
    )
    return picture


def write_depth_maps(
    frames: Sequence[tuple[str, np.ndarray]],
    out_dir: str | Path,
    *,
    sensor: SensorCalibration | None = None,
    reference: np.ndarray | None = None,
    png: bool = False,
) -> list[tuple[Path, float]]:
    """Write each frame's depth map; returns ``(npy path, peak depth [mm])`` per frame.

    Each frame becomes ``OUT/<stem>.npy``, float32 (H, W) in mm, positive into the gel,
    and with ``png`` also ``OUT/<stem>.png``; every file is written atomically.

    Args:
        frames: ``(file name, uint8 BGR frame)``, sensor frames of the reference's size.
        out_dir: a new or empty directory, or one this command wrote before
            (``outputs.claim_output_dir``, kind ``depth``).
        sensor: its depth model (None: the dataset heuristic) and its reference.
        reference: the no-contact frame, replacing the sensor's.

    Raises:
        ValueError: no reference, a frame of another size, two frames with one stem, a
            greyscale frame for a sensor's (colour) depth model.
    """
    if reference is None:
        if sensor is None:
            raise ValueError("give --reference (a no-contact frame) or --calibration")
        reference = sensor.reference
    stems = [Path(name).stem for name, _ in frames]
    if len(set(stems)) != len(stems):
        raise ValueError("two frames share a file name stem; their depth maps would collide")
    for name, frame in frames:
        if frame.shape != reference.shape:
            raise ValueError(
                f"{name} is {frame.shape[1]}x{frame.shape[0]} px, the reference "
                f"{reference.shape[1]}x{reference.shape[0]} px"
            )
    if sensor is not None and sensor.depth_model is not None:
        for name, frame in frames:
            problem = grey_frame_problem(frame, reference)
            if problem:
                raise ValueError(f"{name}: {problem}")
    model = "dataset" if sensor is None else sensor.depth
    out = claim_output_dir(out_dir, "depth")
    written = []
    for stem, (_, frame) in zip(stems, frames, strict=True):
        depth = reconstruct_depth(difference_images(frame[None], reference), model=model)[0]
        path = out / f"{stem}.npy"
        # Through outputs.atomic_file, never straight to the name (a link planted there is
        # refused, a full disk leaves no truncated file). np.save into memory first: to a
        # real file numpy reports a short write without its errno.
        buffer = io.BytesIO()
        np.save(buffer, depth.astype(np.float32))
        with atomic_file(path, "wb") as handle:
            handle.write(buffer.getbuffer())
        if png:
            ok, encoded = cv2.imencode(".png", depth_picture(depth))
            if not ok:  # pragma: no cover - OpenCV encodes any uint8 BGR image
                raise ValueError(f"cannot encode the picture of {path}")
            with atomic_file(out / f"{stem}.png", "wb") as handle:
                handle.write(encoded.tobytes())
        written.append((path, float(depth.max())))
    return written
