"""Calibration to your own sensor: frame geometry, no-contact reference, pixel pitch and
depth model, in one JSON file. See docs/inference.md, "Calibration", and docs/sensors.md.
"""

from __future__ import annotations

import base64
import json
import math
import re
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from tactile_compliance.acquisition.sensors import (
    IMAGE_SUFFIXES,
    FrameError,
    FrameGeometry,
    FrameSizeError,
    FrameSourceBase,
    SensorError,
    iter_frames,
    open_source,
)
from tactile_compliance.data.depth_model import (
    BallPress,
    CalibratedDepthModel,
    ContactCircle,
    find_contact_circle,
    fit_depth_model,
)
from tactile_compliance.data.image_ops import difference_images, read_image_file
from tactile_compliance.data.photometric import reconstruct_depth
from tactile_compliance.data.plausibility import check_size
from tactile_compliance.outputs import (
    atomic_file,
    check_format_version,
    check_output_file,
    check_output_folder,
)
from tactile_compliance.physics.estimators import SensorUnits
from tactile_compliance.progress import progress_bar

__all__ = [
    "CALIBRATION_FORMAT",
    "DepthCalibration",
    "SensorCalibration",
    "calibrate",
    "calibrate_depth",
    "read_circles",
    "read_image",
    "read_images",
]

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
        px_per_mm: pixel density [px/mm] of the sensor frames; None: not calibrated.
        depth_model: the sensor's calibrated depth model; None: the dataset heuristic.
        created_utc: ISO 8601 time of the recording.
    """

    geometry: FrameGeometry
    reference: np.ndarray
    source: str = ""
    n_frames: int = 0
    px_per_mm: float | None = None
    depth_model: CalibratedDepthModel | None = None
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
        if self.px_per_mm is not None and not (
            math.isfinite(self.px_per_mm) and 0 < self.px_per_mm < 1000
        ):
            raise ValueError(f"px_per_mm must be in (0, 1000) px/mm, got {self.px_per_mm}")
        if self.depth_model is not None:
            if self.depth_model.frame_size != self.frame_size:
                raise ValueError(
                    f"the depth model is for {self.depth_model.frame_size} px frames, the "
                    f"reference is {self.frame_size}"
                )
            if self.px_per_mm is None:
                self.px_per_mm = self.depth_model.px_per_mm
            elif not math.isclose(self.px_per_mm, self.depth_model.px_per_mm, rel_tol=1e-6):
                raise ValueError(
                    f"px_per_mm {self.px_per_mm} differs from the depth model's "
                    f"{self.depth_model.px_per_mm}"
                )

    @property
    def depth(self) -> str | CalibratedDepthModel:
        """The depth model for ``data.photometric.reconstruct_depth``."""
        return "dataset" if self.depth_model is None else self.depth_model

    @property
    def units(self) -> SensorUnits:
        """The units its analytical estimates come out in (recorded by stores)."""
        return SensorUnits("dataset" if self.depth_model is None else "calibrated", self.px_per_mm)

    @property
    def frame_size(self) -> tuple[int, int]:
        """(H, W) px of the sensor frames (the reference's size)."""
        return int(self.reference.shape[0]), int(self.reference.shape[1])

    def to_dict(self) -> dict[str, Any]:
        """The JSON document (reference as base64 PNG)."""
        _, png = cv2.imencode(".png", self.reference)  # never fails for uint8 (H, W, 3)
        return {
            "format": CALIBRATION_FORMAT,
            "format_version": CALIBRATION_VERSION,
            "geometry": self.geometry.to_dict(),
            "frame_size": list(self.frame_size),
            "reference_png_base64": base64.b64encode(png.tobytes()).decode("ascii"),
            "source": self.source,
            "n_frames": int(self.n_frames),
            "created_utc": self.created_utc,
            "px_per_mm": self.px_per_mm,
            "depth_model": None if self.depth_model is None else self.depth_model.to_dict(),
        }

    def save(self, path: str | Path) -> Path:
        """Write the JSON file (atomically; refuses to replace a file that is not a
        sensor calibration)."""
        path = Path(path)
        check_output_file(path, "sensor calibration", is_calibration_file, option="--out")
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
        check_format_version(
            data.get("format_version"), CALIBRATION_VERSION, f"{path}: calibration"
        )
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
            px_per_mm = data.get("px_per_mm")
            if px_per_mm is not None and (
                isinstance(px_per_mm, bool) or not isinstance(px_per_mm, (int, float))
            ):
                raise ValueError(f"px_per_mm must be a number, got {px_per_mm!r}")
            depth_model = data.get("depth_model")
            return cls(
                geometry=geometry,
                reference=reference,
                source=str(data.get("source", "")),
                n_frames=int(data.get("n_frames", 0)),
                created_utc=str(data.get("created_utc", "")),
                px_per_mm=None if px_per_mm is None else float(px_per_mm),
                depth_model=(
                    None if depth_model is None else CalibratedDepthModel.from_dict(depth_model)
                ),
            )
        except (KeyError, TypeError, ValueError, AttributeError, base64.binascii.Error) as err:  # type: ignore[attr-defined]
            raise ValueError(f"{path}: damaged sensor calibration ({err})") from err

    def open(self, spec: str, **options: Any) -> FrameSourceBase:
        """Open ``spec`` (see ``sensors.open_source``) with this calibration's geometry.

        The source's frames are warped, cropped and resized as at calibration time, and a
        camera frame of another size than ``geometry.input_size`` raises ``FrameSizeError``
        (another camera, or the same one at another resolution, would be differenced
        against a reference it does not match).
        """
        return open_source(spec, geometry=self.geometry, **options)


#: A reference whose grey levels vary by less than this (standard deviation over the
#: pixels) is uniform: no lit gel looks like that (a GelSight pad shows its LED gradients
#: and the gel's texture; the synthetic sensor's reference varies by tens of levels).
MIN_REFERENCE_STD = 2.0
#: A reference with more than this share of saturated (255 in every channel) pixels is
#: overexposed: contact cannot brighten those pixels, so difference images lose it.
MAX_SATURATED_SHARE = 0.5


def reference_problem(reference: np.ndarray) -> str | None:
    """Why a no-contact reference (H, W, 3) uint8 cannot be a lit sensor's (uniform or
    overexposed), or None."""
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


def is_calibration_file(path: Path) -> bool:
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
    its first ``n_frames`` good frames (the median removes read noise and a passing
    flicker).

    Args:
        geometry: default the source's preset; its ``input_size`` becomes the camera
            frame size seen.
        out: also write the calibration there (JSON).
        options: for ``open_source`` (``fps`` / ``timestamps_csv`` of a folder).

    Raises:
        SensorError: the source cannot be opened or delivers fewer than ``n_frames``.
    """
    if n_frames < 1:
        raise ValueError(f"n_frames must be >= 1, got {n_frames}")
    if out is not None:  # refuse a bad --out before touching the sensor
        check_output_file(Path(out), "sensor calibration", is_calibration_file, option="--out")
        check_output_folder(out, option="--out")
    picture = None if out is None else picture_path(out)
    if picture is not None:
        check_output_file(picture, "calibration picture", is_calibration_picture, option="--out")
    skipped: list[FrameError] = []
    frames: list[np.ndarray] = []
    warped: list[np.ndarray] = []  # the same frames before the crop, for the picture
    with open_source(spec, geometry=geometry, **options) as source:
        camera_size: tuple[int, int] | None = None
        for _, frame in iter_frames(source, skipped.append):
            frames.append(frame)
            if picture is not None and source.last_raw is not None:
                warped.append(source.geometry.warp(source.last_raw))
            if camera_size is None:
                camera_size = source.last_raw_size
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
        if warped and camera_size is not None:
            write_picture(picture, np.median(np.stack(warped), axis=0), used, camera_size)
    return calibration


#: The PNG text key that marks a picture as ``calibrate``'s (so a re-run may replace it).
_PICTURE_KEY = b"tactile-compliance"


def picture_path(out: str | Path) -> Path:
    """Where ``calibrate --out OUT.json`` puts its picture: ``OUT.png`` next to it."""
    return Path(out).with_suffix(".png")


def is_calibration_picture(path: Path) -> bool:
    """Whether ``path`` is a PNG that :func:`write_picture` wrote (its text chunk)."""
    with open(path, "rb") as handle:
        head = handle.read(256)
    return head.startswith(b"\x89PNG") and b"tEXt" + _PICTURE_KEY + b"\x00" in head


def write_picture(
    path: Path, warped_reference: np.ndarray, geometry: FrameGeometry, size: tuple[int, int]
) -> Path:
    """The warped no-contact reference (BGR, before the crop) with the crop drawn on it in
    green and its size written in, as a PNG at ``path`` (atomically; marked as ours with a
    PNG text chunk, :func:`is_calibration_picture`). ``size``: the camera frame (H, W) px.
    So the corners and the crop can be checked by eye (docs/sensors.md)."""
    image = np.ascontiguousarray(warped_reference.round().clip(0, 255).astype(np.uint8))
    top, left, h, w = geometry.crop_box(size)
    cv2.rectangle(image, (left, top), (left + w - 1, top + h - 1), (0, 255, 0), 1)
    label = f"crop {w}x{h} px at ({left}, {top})"
    cv2.putText(image, label, (left + 3, top + 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 255, 0))
    ok, encoded = cv2.imencode(".png", image)
    if not ok:  # pragma: no cover - OpenCV encodes any uint8 BGR image
        raise OSError(f"{path}: the picture could not be encoded")
    png = encoded.tobytes()
    text = _PICTURE_KEY + b"\x00calibrate: the warped reference and the crop"
    chunk = len(text).to_bytes(4, "big") + b"tEXt" + text
    chunk += zlib.crc32(b"tEXt" + text).to_bytes(4, "big")
    end_of_header = 8 + 25  # the signature, then IHDR (length, type, 13 bytes, crc)
    with atomic_file(path, "wb") as handle:
        handle.write(png[:end_of_header] + chunk + png[end_of_header:])
    return path


# ---------------------------------------------------------------------- depth calibration
_CIRCLE_LINE = re.compile(
    r"^\s*(?P<name>[^\s,]+)[\s,]+\(?\s*(?P<x>[-\d.eE+]+)\s*,\s*(?P<y>[-\d.eE+]+)\s*\)?"
    r"[\s,]+(?P<r>[-\d.eE+]+)\s*$"
)


def _natural_key(path: Path) -> list[Any]:
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", path.name)]


def read_image(path: str | Path) -> np.ndarray:
    """One image file as a uint8 BGR array (OpenCV's order, like the frames), its size
    checked before it is decoded and a truncated file refused
    (``data.image_ops.read_image_file``).

    Raises:
        ValueError: not an image OpenCV can read, too large, cut short. OSError: no such
            file.
    """
    return read_image_file(path)


def read_images(paths: Sequence[str | Path]) -> list[tuple[str, np.ndarray]]:
    """``(file name, uint8 BGR frame)`` of image files, folders expanded in natural order.

    Raises:
        ValueError: a file that is not an image, or no image at all.
        OSError: a path that does not exist.
    """
    files: list[Path] = []
    for item in paths:
        path = Path(item)
        if path.is_dir():
            found = [p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES]
            files.extend(sorted(found, key=_natural_key))
        elif path.is_file():
            files.append(path)
        else:
            raise FileNotFoundError(f"{path}: no such image file or folder")
    if not files:
        raise ValueError(f"no image files ({', '.join(IMAGE_SUFFIXES)}) in {list(map(str, paths))}")
    return [(path.name, read_image(path)) for path in files]


def read_circles(path: str | Path) -> dict[str, ContactCircle]:
    """Given contact circles by image file name: lines ``NAME (x, y) r`` (the format of the
    RA-L 2022 sphere presses' labels) or ``NAME,x,y,r``; pixels; ``#`` starts a comment.

    Raises:
        ValueError: not a text file, a line in neither format, a centre or radius that is
            not a finite number, a radius that is not positive, a name listed twice.
    """
    path = Path(path)
    try:
        content = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as err:
        raise ValueError(
            f"{path}: not a text file of circles (byte {err.start} is not UTF-8): expected "
            f"lines 'NAME (x, y) r' or 'NAME,x,y,r'"
        ) from None
    circles: dict[str, ContactCircle] = {}
    lines: dict[str, int] = {}
    for number, line in enumerate(content.splitlines(), 1):
        text = line.split("#", 1)[0].strip()
        if not text or text.lower().startswith("file"):
            continue
        match = _CIRCLE_LINE.match(text)
        if match is None:
            raise ValueError(f"{path}:{number}: expected 'NAME (x, y) r' or 'NAME,x,y,r'")
        try:
            x_px, y_px, radius = float(match["x"]), float(match["y"]), float(match["r"])
        except ValueError:
            raise ValueError(f"{path}:{number}: x, y and r must be numbers (px)") from None
        if not (math.isfinite(x_px) and math.isfinite(y_px)):
            raise ValueError(f"{path}:{number}: the centre must be finite numbers (px)")
        if not (math.isfinite(radius) and radius > 0):
            raise ValueError(f"{path}:{number}: the radius must be > 0 px")
        name = Path(match["name"]).name
        if name in lines:
            raise ValueError(
                f"{path}:{number}: {name} already has a circle (line {lines[name]}); give "
                f"each press one"
            )
        lines[name] = number
        circles[name] = ContactCircle(x_px, y_px, radius)
    return circles


#: A given contact circle smaller than this radius [px] is no visible contact (what
#: ``find_contact_circle`` finds at least).
MIN_CIRCLE_RADIUS_PX = 3.0


def _circle_problem(circle: ContactCircle, size: tuple[int, int]) -> str | None:
    """Why a given circle cannot be a press's contact on an (H, W) frame, or None."""
    height, width = size
    if not (0 <= circle.x_px <= width - 1 and 0 <= circle.y_px <= height - 1):
        return (
            f"its centre ({circle.x_px:g}, {circle.y_px:g}) px lies outside the "
            f"{width}x{height} px frame"
        )
    if circle.radius_px < MIN_CIRCLE_RADIUS_PX:
        return (
            f"its radius {circle.radius_px:g} px is below {MIN_CIRCLE_RADIUS_PX:g} px (no "
            f"visible contact)"
        )
    if circle.radius_px > max(height, width) / 2:
        return (
            f"its radius {circle.radius_px:g} px is larger than half the {width}x{height} px frame"
        )
    return None


@dataclass
class DepthCalibration:
    """What :func:`calibrate_depth` fitted, and how each press came out.

    Attributes:
        calibration: the sensor calibration carrying the depth model and ``px_per_mm``.
        presses: one row per press: ``name``, ``x_px``, ``y_px``, ``radius_px``,
            ``radius_mm``, ``circle`` ("given" or "found"), ``cap_depth_mm`` (the
            spherical cap's depth implied by the circle, None when the circle is as wide
            as the ball), ``peak_depth_mm`` (the fitted model's depth at the press) and
            ``verdict`` (:func:`press_verdict`).
        verdict: ``ok`` when every press is, else ``suspect: K of N presses (...)``.
    """

    calibration: SensorCalibration
    presses: list[dict[str, Any]]
    verdict: str = "ok"

    def format(self) -> str:
        """A few lines for the terminal: the fit's residuals, each press with its verdict,
        and the overall verdict."""
        model = self.calibration.depth_model
        assert model is not None
        rep = model.report
        lines = [
            f"Depth model fitted on {rep['presses']} presses "
            f"({rep['contact_pixels']} contact + {rep['background_pixels']} background px); "
            f"slope RMSE {rep['slope_rmse_contact']:.3f} in contact, "
            f"{rep['slope_rmse_background']:.3f} outside; noise level {model.noise_level:.3f}; "
            + (
                f"printed markers found and masked (level {model.marker_level:.3f})"
                if model.marker_level > 0
                else "no printed markers"
            ),
            "press                        circle (x, y, r px)      r [mm]  cap [mm]  peak [mm]"
            "  verdict",
        ]
        for row in self.presses:
            cap = row["cap_depth_mm"]
            lines.append(
                f"{row['name'][-28:]:28s} {row['circle']:5s} ({row['x_px']:6.1f}, "
                f"{row['y_px']:6.1f}, {row['radius_px']:5.1f})  {row['radius_mm']:6.2f}"
                f"  {'r >= R' if cap is None else f'{cap:.3f}':>8s}  "
                f"{row['peak_depth_mm']:9.3f}  {row['verdict']}"
            )
        if any(row["cap_depth_mm"] is None for row in self.presses):
            lines.append(
                "cap: the spherical cap's depth that the contact circle implies for the ball "
                "(R - sqrt(R^2 - r^2)); 'r >= R': the circle is as wide as the ball or wider, "
                "so it implies none"
            )
        lines.append(f"Verdict: {self.verdict}")
        return "\n".join(lines)


#: A press's peak depth may be this many times its contact circle's cap depth, or this
#: fraction of it, before the press is suspect: a factor of 2 either way, wide because the
#: visibly deformed area of a real gel is wider than the ideal contact circle (thusight's
#: notes), so the cap of the found circle overstates the depth of a deep press.
PEAK_TO_CAP_FACTOR = 2.0


def press_verdict(
    radius_mm: float, cap_depth_mm: float | None, peak_depth_mm: float, ball_radius_mm: float
) -> str:
    """``ok``, or ``suspect: REASON``, for one ball press against the ball's radius R [mm].

    Suspect when the fitted model's peak depth exceeds R (a ball cannot press deeper than
    its radius and stay a sphere cap), when the contact radius is R or more (the circle
    implies no cap: a found circle wider than the contact, or a wrong ``--px-per-mm``), or
    when the peak is more than :data:`PEAK_TO_CAP_FACTOR` times above or below the cap
    depth the circle implies.
    """
    reasons = []
    if peak_depth_mm > ball_radius_mm:
        reasons.append(f"peak {peak_depth_mm:.2f} mm is deeper than the ball's radius")
    if cap_depth_mm is None:
        reasons.append(
            f"contact radius {radius_mm:.2f} mm >= the ball's {ball_radius_mm:g} mm "
            "(check the circle or --px-per-mm)"
        )
    elif not (
        cap_depth_mm / PEAK_TO_CAP_FACTOR <= peak_depth_mm <= cap_depth_mm * PEAK_TO_CAP_FACTOR
    ):
        reasons.append(
            f"peak {peak_depth_mm:.2f} mm vs the {cap_depth_mm:.2f} mm cap its circle implies"
        )
    return "ok" if not reasons else "suspect: " + "; ".join(reasons)


def calibrate_depth(
    presses: Sequence[tuple[str, np.ndarray]],
    *,
    ball_radius_mm: float,
    px_per_mm: float,
    reference: np.ndarray | None = None,
    sensor: SensorCalibration | None = None,
    circles: dict[str, ContactCircle] | None = None,
    source: str = "",
    epochs: int = 40,
    seed: int = 0,
    progress: bool = True,
    threads: int | None = None,
) -> DepthCalibration:
    """Fit a sensor's depth model on presses of a ball of known radius.

    Shows a progress bar on stderr (``progress``): one step per epoch of the fit and per
    press checked. ``threads``: torch threads for the fit (``fit_depth_model``; None: the
    free cores, at most 4).

    Args:
        presses: ``(name, uint8 BGR frame)`` sensor frames (after the geometry).
        ball_radius_mm: the ball's radius [mm].
        px_per_mm: the sensor frames' pixel density [px/mm].
        reference: the no-contact frame; default the ``sensor``'s, else the per-pixel
            median of the presses.
        sensor: a calibration to extend: its geometry and reference carry over.
        circles: given contact circles [px] by press name; the others are found.
        epochs, seed: of the regressor fit.

    Raises:
        ValueError: bad radius or pitch, frames of another size than the reference, a press
            without a visible contact, a circle far wider than the ball.
    """
    if not (math.isfinite(ball_radius_mm) and 0 < ball_radius_mm < 100):
        raise ValueError(f"--ball-radius-mm must be in (0, 100) mm, got {ball_radius_mm}")
    if not (math.isfinite(px_per_mm) and 0 < px_per_mm < 1000):
        raise ValueError(f"--px-per-mm must be in (0, 1000) px/mm, got {px_per_mm}")
    if len(presses) < 2:
        raise ValueError(f"need at least 2 ball presses, got {len(presses)}")
    shapes = {frame.shape for _, frame in presses}
    if len(shapes) != 1:
        raise ValueError(f"the presses have different sizes: {sorted(shapes)}")
    frames = np.stack([frame for _, frame in presses])
    if reference is None:
        reference = sensor.reference if sensor is not None else None
    if reference is None:
        reference = np.median(frames, axis=0).round().astype(np.uint8)
    if reference.shape != frames.shape[1:]:
        raise ValueError(
            f"the reference frame is {reference.shape[1]}x{reference.shape[0]} px, the presses "
            f"{frames.shape[2]}x{frames.shape[1]} px"
        )
    for name, frame in presses:
        if np.array_equal(frame, reference):
            raise ValueError(
                f"{name} is the no-contact reference itself (the same pixels): give a "
                f"frame with nothing touching the gel as --reference, not a press"
            )
    given = circles or {}
    for name, circle in given.items():
        problem = _circle_problem(circle, frames.shape[1:3])
        if problem:
            raise ValueError(f"--circles: the circle of {name}: {problem}")
    diffs = difference_images(frames, reference)
    fitted: list[BallPress] = []
    for (name, _), diff in zip(presses, diffs, strict=True):
        try:
            circle = given.get(name) or find_contact_circle(diff)
        except ValueError as err:
            raise ValueError(f"{name}: {err}") from err
        fitted.append(BallPress(diff, circle, name))
    rows = []
    total = epochs + len(fitted)
    with progress_bar("Fitting the depth model", total=total, enabled=progress) as advance:
        model = fit_depth_model(
            fitted,
            ball_radius_mm,
            px_per_mm,
            epochs=epochs,
            seed=seed,
            threads=threads,
            progress=advance,
        )
        depths = []
        for diff in diffs:
            depths.append(reconstruct_depth(diff[None], model=model)[0])
            advance()
    for press, depth in zip(fitted, depths, strict=True):
        c = press.circle
        a_mm = c.radius_px / px_per_mm
        cap = (
            ball_radius_mm - math.sqrt(ball_radius_mm**2 - a_mm**2)
            if a_mm < ball_radius_mm
            else None
        )
        peak = float(depth.max())
        rows.append(
            {
                "name": press.name,
                "circle": "given" if press.name in given else "found",
                "x_px": c.x_px,
                "y_px": c.y_px,
                "radius_px": c.radius_px,
                "radius_mm": a_mm,
                "cap_depth_mm": cap,
                "peak_depth_mm": peak,
                "verdict": press_verdict(a_mm, cap, peak, ball_radius_mm),
            }
        )
    suspect = [row for row in rows if row["verdict"] != "ok"]
    verdict = (
        "ok: every press's depth agrees with the ball's radius"
        if not suspect
        else f"suspect: {len(suspect)} of {len(rows)} presses ("
        + ", ".join(row["name"] for row in suspect[:5])
        + (", ..." if len(suspect) > 5 else "")
        + "); check their circles (--circles) and --px-per-mm, or leave them out"
    )
    geometry = sensor.geometry if sensor is not None else FrameGeometry()
    calibration = SensorCalibration(
        geometry=geometry,
        reference=np.ascontiguousarray(reference),
        source=sensor.source if sensor is not None else source,
        n_frames=sensor.n_frames if sensor is not None else 0,
        px_per_mm=float(px_per_mm),
        depth_model=model,
    )
    model.report["press_checks"] = rows
    model.report["verdict"] = verdict
    return DepthCalibration(calibration, rows, verdict)


def capture_presses(
    spec: str,
    n_presses: int,
    *,
    sensor: SensorCalibration | None = None,
    reference: np.ndarray | None = None,
    max_frames: int = 10_000,
    **options: Any,
) -> list[tuple[str, np.ndarray]]:
    """Frames of a live source that show a new ball press, until ``n_presses`` are taken
    (a press held still gives one frame: a new centre must be a contact radius away).

    Raises:
        ValueError: no reference (give ``sensor`` or ``reference``).
        SensorError: the source ends before ``n_presses`` presses.
    """
    if reference is None:
        if sensor is None:
            raise ValueError("a live source needs a reference: give --calibration or --reference")
        reference = sensor.reference
    taken: list[tuple[str, np.ndarray]] = []
    centres: list[ContactCircle] = []
    opened = sensor.open(spec, **options) if sensor is not None else open_source(spec, **options)
    with opened as frames:
        for index, (_, frame) in enumerate(iter_frames(frames, lambda err: None)):
            if index >= max_frames or len(taken) >= n_presses:
                break
            if frame.shape != reference.shape:
                raise FrameSizeError(
                    f"frame {frame.shape} differs from the reference {reference.shape}"
                )
            try:
                circle = find_contact_circle(difference_images(frame[None], reference)[0], 5.0)
            except ValueError:
                continue
            if any(
                math.hypot(circle.x_px - c.x_px, circle.y_px - c.y_px) < c.radius_px
                for c in centres
            ):
                continue
            centres.append(circle)
            taken.append((f"{spec}#{index}", frame))
    if len(taken) < n_presses:
        raise SensorError(f"{spec}: only {len(taken)} of {n_presses} presses seen")
    return taken
