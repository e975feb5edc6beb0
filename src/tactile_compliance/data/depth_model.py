"""A sensor's own depth model (colour and position -> slope, integrated inside the contact
mask), calibrated from presses of a ball of known radius.

See docs/sensors.md, "The model".
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from tactile_compliance.data.photometric import fill_masked, poisson_depth
from tactile_compliance.devices import free_cores, torch_threads
from tactile_compliance.outputs import check_format_version
from tactile_compliance.progress import ProgressBar

__all__ = [
    "BallPress",
    "CalibratedDepthModel",
    "ContactCircle",
    "find_contact_circle",
    "fit_depth_model",
    "grey_frame_problem",
    "largest_region",
    "marker_mask",
    "marker_threshold",
    "prepare_diff",
    "remove_illumination_change",
]

DEPTH_MODEL_FORMAT = "tactile-compliance-depth-model"
DEPTH_MODEL_VERSION = 2
"""2: the illumination change is removed, the zero-change slope subtracted and markers
filled before the regressor (a version-1 model was fitted without them)."""

_HIDDEN = (32, 32)
"""Hidden widths of the slope regressor: enough for the colour wheel's nonlinearity (a
lookup table over colour alone, as the 2018 GelSight code used, cannot see vignetting)."""

_MAGNITUDE_SIGMA_PX = 2.0
"""Gaussian blur [px] of the colour-change magnitude: removes pixel noise, keeps the edge."""

_CIRCLE_FRACTION = 0.5
"""The contact circle is where the colour change exceeds this fraction of its peak. Chosen on
the one sensor with hand-labelled circles (thusight, 22 presses of ~27 px radius: mean radius
error against the labels -3.2 px at 0.6, +2.0 px at 0.5, +5.5 px at 0.4, +9.4 px at 0.3);
the visibly deformed area is wider than the contact."""

_MIN_CONTACT_MAGNITUDE = 3.0 / 255.0
"""A frame whose strongest colour change is below 3 grey levels shows no contact."""

_CONTACT_SAFETY = 0.95
"""Train on slopes inside this fraction of the contact radius (the rim is uncertain)."""

_MAX_TRAIN_TO_BALL = 0.9
"""...and inside this fraction of the ball radius (the cap's slope is 2.1 there, 64 deg)."""

_MAX_CONTACT_TO_BALL = 1.5
"""A contact circle wider than this many ball radii means wrong radius or pixel pitch."""

_BACKGROUND_GAP = 2.0
"""Pixels farther than this many contact radii from the centre are untouched (slope 0)."""

_NOISE_QUANTILE = 99.5
"""The no-contact noise level is this percentile [%] of the colour-change magnitude on the
presses' untouched pixels; the contact mask starts above it."""

_MASK_GROW_MM = 0.3
"""The contact mask is grown by this margin [mm]: the gel's slope fades to 0 outside the
contact while the colour change is already below the noise there."""

_ILLUMINATION_QUIET = 50.0
"""The illumination change is fitted on the quietest this percentage [%] of a frame's
pixels (by colour-change magnitude): a contact covers less than half the frame."""

_ILLUMINATION_STEP_PX = 4
"""The illumination plane is fitted on every this-many-th pixel along each axis."""

_MARKER_SCALE_MM = 0.5
"""Printed markers are smaller than this [mm]: the achromatic change left after a
Gaussian blur of this sigma is a marker's (a contact's colour change is wider)."""

_MARKER_SIGMAS = 6.0
"""A pixel is a marker's when its achromatic high-pass exceeds this many robust standard
deviations (1.4826 x the median absolute deviation) of the presses' untouched pixels."""

_MARKER_SHARE = 0.01
"""The sensor has markers when more than this share of the untouched pixels is above that
level (Gaussian noise puts 2e-9 there, a marker grid 3-10 %)."""

_MARKER_GROW_MM = 0.15
"""Marker pixels are grown by this margin [mm]: the reference's 11 x 11 px blur spreads
each marker's edge into its surroundings in the difference image."""

MAX_WEIGHT = 100.0
"""The largest |weight| or |bias| a loaded depth model may hold: fitted ones stay below 1
(0.9 on the RA-L 2022 sensor's 22 presses); finite but huge values (a tampered or damaged
calibration) would give NaN or 1e30 mm depths."""

MAX_SCALE = 1000.0
"""The largest input scale: 1 / the features' standard deviation, floored at 1e-3."""


def grey_frame_problem(frame: np.ndarray, reference: np.ndarray) -> str | None:
    """Why a sensor's depth model, fitted on colour frames, cannot read ``frame``: it is
    greyscale (its three channels equal) while the sensor's ``reference`` is in colour;
    None when it can. (A GelSight's colour lights are what the model reads slopes from.)"""
    frame = np.asarray(frame)
    if frame.ndim != 3 or frame.shape[2] != 3:
        return f"a frame must be colour (H, W, 3), got {tuple(frame.shape)}"

    def grey(image: np.ndarray) -> bool:
        return bool(
            np.array_equal(image[..., 0], image[..., 1])
            and np.array_equal(image[..., 1], image[..., 2])
        )

    if grey(frame) and not grey(np.asarray(reference)):
        return (
            "the frame is greyscale (its three channels are equal) but the sensor's depth "
            "model was calibrated on colour frames: give the sensor's colour frames"
        )
    return None


@dataclass(frozen=True)
class ContactCircle:
    """A contact circle in pixels: centre (``x_px`` column, ``y_px`` row) and radius."""

    x_px: float
    y_px: float
    radius_px: float


@dataclass(frozen=True)
class BallPress:
    """One press: its difference image (H, W, 3) BGR float centred on 0.5 and its circle."""

    diff: np.ndarray
    circle: ContactCircle
    name: str = ""


def contact_magnitude(diff: np.ndarray) -> np.ndarray:
    """Colour-change magnitude (H, W) of one difference image: the blurred norm of its
    deviation from 0.5 over the three channels (a unitless intensity fraction)."""
    dev = np.asarray(diff, dtype=np.float32) - 0.5
    dev = cv2.GaussianBlur(dev, (0, 0), _MAGNITUDE_SIGMA_PX)
    return np.sqrt((dev * dev).sum(axis=2))


def largest_region(mask: np.ndarray) -> np.ndarray | None:
    """The outline (an OpenCV contour) of the largest region of a binary (H, W) mask, by the
    area its outer edge encloses, so holes count as inside; None for an empty mask."""
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    return max(contours, key=cv2.contourArea) if contours else None


def remove_illumination_change(diff: np.ndarray) -> np.ndarray:
    """Difference images (n, H, W, 3) without their low-frequency illumination change: per
    frame and channel, a plane (offset and tilt across the frame, in intensity fractions)
    fitted by least squares on the quietest half of the pixels is subtracted, so a
    reference taken under other light, or a large press that dims the whole gel, reads as
    no colour change where nothing touches. Returns a new float32 array centred on 0.5.
    """
    diff = np.asarray(diff, dtype=np.float32)
    if diff.ndim == 3:
        diff = diff[None]
    n, h, w, _ = diff.shape
    step = _ILLUMINATION_STEP_PX
    rows, cols = np.mgrid[0:h:step, 0:w:step]
    design = np.stack(
        [np.ones(rows.size), cols.ravel() / w - 0.5, rows.ravel() / h - 0.5], axis=1
    ).astype(np.float32)
    full = (
        np.linspace(-0.5, 0.5, w, dtype=np.float32)[None, :],
        np.linspace(-0.5, 0.5, h, dtype=np.float32)[:, None],
    )
    out = np.empty_like(diff)
    for k in range(n):
        dev = diff[k, ::step, ::step].reshape(-1, 3) - 0.5
        centred = dev - np.median(dev, axis=0)
        magnitude = np.sqrt((centred * centred).sum(axis=1))
        quiet = magnitude <= np.percentile(magnitude, _ILLUMINATION_QUIET)
        coef = np.linalg.lstsq(design[quiet], dev[quiet], rcond=None)[0]  # (3, 3)
        plane = coef[0] + full[0][..., None] * coef[1] + full[1][..., None] * coef[2]
        out[k] = diff[k] - plane.astype(np.float32)
    return out


def _achromatic_highpass(diff: np.ndarray, px_per_mm: float) -> np.ndarray:
    """(n, H, W): the channel mean of the colour change minus its blur at the markers'
    scale (a marker, dark in all three channels and small, stands out; a contact's colour
    change is wider)."""
    grey = np.ascontiguousarray((np.asarray(diff, dtype=np.float32) - 0.5).mean(axis=3))
    sigma = _MARKER_SCALE_MM * px_per_mm
    out = np.empty_like(grey)
    for k in range(grey.shape[0]):
        out[k] = grey[k] - cv2.GaussianBlur(grey[k], (0, 0), sigma)
    return out


def marker_threshold(diffs: np.ndarray, untouched: np.ndarray, px_per_mm: float) -> float:
    """The achromatic high-pass level above which a pixel is a printed marker's, from ball
    presses' difference images (n, H, W, 3) and their untouched pixels (n, H, W); 0 when
    the sensor has no markers (no more than 1 % of the untouched pixels above it)."""
    values = np.abs(_achromatic_highpass(diffs, px_per_mm)[untouched])
    spread = 1.4826 * float(np.median(np.abs(values - np.median(values))))
    level = _MARKER_SIGMAS * max(spread, 1.0 / 255.0)
    return level if float(np.mean(values > level)) > _MARKER_SHARE else 0.0


def marker_mask(diff: np.ndarray, threshold: float, px_per_mm: float) -> np.ndarray:
    """Marker pixels (n, H, W) of difference images (n, H, W, 3): achromatic high-pass
    above ``threshold`` (:func:`marker_threshold`), grown by 0.15 mm; all False for 0."""
    diff = np.asarray(diff, dtype=np.float32)
    if threshold <= 0:
        return np.zeros(diff.shape[:3], dtype=bool)
    grow = max(1, round(_MARKER_GROW_MM * px_per_mm))
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * grow + 1, 2 * grow + 1))
    high = (np.abs(_achromatic_highpass(diff, px_per_mm)) > threshold).astype(np.uint8)
    return np.stack([cv2.dilate(m, kernel) > 0 for m in high])


def prepare_diff(diff: np.ndarray, marker_level: float, px_per_mm: float) -> np.ndarray:
    """What a calibrated depth model reads, in its fit and in its use: difference images
    (n, H, W, 3) without the illumination change (:func:`remove_illumination_change`) and
    with marker pixels (:func:`marker_mask`) filled from their surroundings."""
    out = remove_illumination_change(diff)
    markers = marker_mask(out, marker_level, px_per_mm)
    if markers.any():
        sigma = _MARKER_SCALE_MM * px_per_mm
        planes = np.ascontiguousarray(out.transpose(3, 0, 1, 2))
        for c in range(3):
            planes[c] = fill_masked(planes[c], markers, sigma)
        out = np.ascontiguousarray(planes.transpose(1, 2, 3, 0))
    return out


def find_contact_circle(diff: np.ndarray, min_radius_px: float = 3.0) -> ContactCircle:
    """The contact circle of a ball press in one difference image (H, W, 3): centroid and
    equivalent-area radius of the largest region above half the peak colour change, holes
    filled (the centre of a ball press is flat, so its colour barely changes).

    Raises:
        ValueError: no region of at least ``min_radius_px`` (nothing presses the gel).
    """
    mag = contact_magnitude(diff)
    peak = float(np.percentile(mag, 99.9))
    if not peak >= _MIN_CONTACT_MAGNITUDE:  # NaN too; else the mask holds the peak's pixels
        raise ValueError("no contact region found (the frame looks like the reference)")
    outline = largest_region(mag > _CIRCLE_FRACTION * peak)
    assert outline is not None  # the mask holds the peak's pixels
    moments = cv2.moments(outline)
    radius = math.sqrt(moments["m00"] / math.pi)
    if radius < min_radius_px:
        raise ValueError(
            f"the largest contact region is {radius:.1f} px in radius (< {min_radius_px} px)"
        )
    x_px, y_px = moments["m10"] / moments["m00"], moments["m01"] / moments["m00"]
    return ContactCircle(float(x_px), float(y_px), radius)


def sphere_slopes(
    shape: tuple[int, int], circle: ContactCircle, ball_radius_mm: float, px_per_mm: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(slope_x, slope_y, inside)``: d depth / d x and d depth / d y [mm/mm] of a pressed
    ball's spherical cap (positive into the gel) on an (H, W) grid, x along columns, and the
    mask of pixels inside the contact.

    Raises:
        ValueError: the contact circle is not smaller than the ball.
    """
    a_mm = circle.radius_px / px_per_mm
    if a_mm >= ball_radius_mm:
        raise ValueError(
            f"contact radius {a_mm:.2f} mm is not below the ball radius {ball_radius_mm} mm: "
            "check --ball-radius-mm and --px-per-mm"
        )
    rows, cols = np.mgrid[0 : shape[0], 0 : shape[1]].astype(np.float32)
    x_mm = (cols - circle.x_px) / px_per_mm
    y_mm = (rows - circle.y_px) / px_per_mm
    rho2 = x_mm * x_mm + y_mm * y_mm
    inside = rho2 < a_mm * a_mm
    height = np.sqrt(np.maximum(ball_radius_mm**2 - rho2, 1e-12))
    slope_x = np.where(inside, -x_mm / height, 0.0).astype(np.float32)
    slope_y = np.where(inside, -y_mm / height, 0.0).astype(np.float32)
    return slope_x, slope_y, inside


def _features(diff: np.ndarray) -> np.ndarray:
    """Per-pixel regressor inputs (n, H, W, 5): colour change (B, G, R) and position."""
    diff = np.asarray(diff, dtype=np.float32)
    if diff.ndim == 3:
        diff = diff[None]
    n, h, w, _ = diff.shape
    feats = np.empty((n, h, w, 5), dtype=np.float32)
    feats[..., :3] = diff - 0.5
    feats[..., 3] = np.linspace(-1.0, 1.0, w, dtype=np.float32)[None, None, :]
    feats[..., 4] = np.linspace(-1.0, 1.0, h, dtype=np.float32)[None, :, None]
    return feats


@dataclass
class CalibratedDepthModel:
    """A sensor's colour-and-position -> slope regressor, and how to integrate it.

    Attributes:
        px_per_mm: the sensor's pixel density [px/mm] (of the frames the model is used on).
        frame_size: (H, W) px of those frames.
        ball_radius_mm: radius [mm] of the calibration ball.
        noise_level: colour-change magnitude (unitless) of untouched pixels; the contact
            mask starts above it.
        layers: the regressor's (weight (in, out), bias (out,)) pairs, float32.
        input_scale: per-feature scale applied before the first layer.
        report: how the fit went (residuals, presses used), for the JSON and the docs.
        marker_level: achromatic high-pass level (unitless) above which a pixel is a printed
            marker's (:func:`marker_threshold`); 0 for a sensor without markers.
    """

    px_per_mm: float
    frame_size: tuple[int, int]
    ball_radius_mm: float
    noise_level: float
    layers: list[tuple[np.ndarray, np.ndarray]]
    input_scale: np.ndarray
    report: dict[str, Any] = field(default_factory=dict)
    marker_level: float = 0.0
    _zero_slopes: tuple[np.ndarray, np.ndarray] | None = field(
        default=None, repr=False, compare=False
    )

    def __post_init__(self) -> None:
        if not (math.isfinite(self.px_per_mm) and 0 < self.px_per_mm < 1000):
            raise ValueError(f"px_per_mm must be in (0, 1000) px/mm, got {self.px_per_mm}")
        if not (math.isfinite(self.noise_level) and 0 <= self.noise_level < 1):
            raise ValueError(f"noise_level must be in [0, 1), got {self.noise_level}")
        if not (math.isfinite(self.marker_level) and 0 <= self.marker_level < 1):
            raise ValueError(f"marker_level must be in [0, 1), got {self.marker_level}")
        h, w = (int(v) for v in self.frame_size)
        if not (8 <= h <= 4096 and 8 <= w <= 4096):
            raise ValueError(f"frame_size must be 8..4096 px a side, got {self.frame_size}")
        self.frame_size = (h, w)
        if not (math.isfinite(self.ball_radius_mm) and 0 < self.ball_radius_mm < 100):
            raise ValueError(f"ball_radius_mm must be in (0, 100) mm, got {self.ball_radius_mm}")
        for k, (weight, bias) in enumerate(self.layers):
            if not (np.all(np.isfinite(weight)) and np.all(np.isfinite(bias))):
                raise ValueError("the depth model's weights are not finite")
            largest = max(float(np.abs(weight).max(initial=0)), float(np.abs(bias).max(initial=0)))
            if largest > MAX_WEIGHT:
                raise ValueError(
                    f"layer {k} of the depth model holds a weight or bias of {largest:.3g}, "
                    f"beyond the plausible +-{MAX_WEIGHT:g} (a fitted model's are below 1): "
                    f"the calibration was altered or damaged; calibrate the sensor again"
                )
        scale = np.asarray(self.input_scale, dtype=np.float64)
        if not (np.all(np.isfinite(scale)) and np.all(scale > 0) and scale.max() <= MAX_SCALE):
            raise ValueError(
                f"input_scale must be 5 numbers in (0, {MAX_SCALE:g}] (1 / the features' "
                f"std, at most 1 / 1e-3), got {scale.tolist()}: the calibration was altered "
                f"or damaged; calibrate the sensor again"
            )

    # -- use -------------------------------------------------------------------------

    def slopes(self, diff: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Raw regressor slopes ``(d depth/dx, d depth/dy)`` [mm/mm], each (n, H, W)."""
        feats = _features(diff)
        n, h, w, _ = feats.shape
        hidden = feats.reshape(-1, 5) * self.input_scale
        for k, (weight, bias) in enumerate(self.layers):
            hidden = hidden @ weight + bias
            if k < len(self.layers) - 1:
                np.maximum(hidden, 0.0, out=hidden)
        out = hidden.reshape(n, h, w, 2)
        return out[..., 0], out[..., 1]

    def zero_change_slopes(self) -> tuple[np.ndarray, np.ndarray]:
        """The regressor's slopes [mm/mm] (each (H, W)) for no colour change at all: its
        bias at small differences, subtracted from every frame's slopes."""
        if self._zero_slopes is None:
            flat = np.full((1, *self.frame_size, 3), 0.5, dtype=np.float32)
            zero_x, zero_y = self.slopes(flat)
            self._zero_slopes = (zero_x[0], zero_y[0])
        return self._zero_slopes

    def prepare(self, diff: np.ndarray) -> np.ndarray:
        """Difference images (n, H, W, 3) as the regressor reads them
        (:func:`prepare_diff`: no illumination change, markers filled)."""
        return prepare_diff(diff, self.marker_level, self.px_per_mm)

    def contact_mask(self, diff: np.ndarray) -> np.ndarray:
        """Pixels (n, H, W) of difference images (n, H, W, 3) whose colour change, once
        :meth:`prepare` d, is above the noise, grown by 0.3 mm."""
        return self._contact_mask(self.prepare(diff))

    def _contact_mask(self, prepared: np.ndarray) -> np.ndarray:
        grow = max(1, round(_MASK_GROW_MM * self.px_per_mm))
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * grow + 1, 2 * grow + 1))
        masks = np.empty(prepared.shape[:3], dtype=bool)
        for k in range(prepared.shape[0]):
            above = (contact_magnitude(prepared[k]) > self.noise_level).astype(np.uint8)
            masks[k] = cv2.dilate(above, kernel) > 0
        return masks

    def depth_mm(self, diff: np.ndarray) -> np.ndarray:
        """Depth maps [mm] (n, H, W), positive into the gel, from difference images
        (n, H, W, 3) BGR centred on 0.5 of this sensor. Outside the contact mask
        (:meth:`contact_mask`) the depth is exactly 0: drift, a change of light and noise
        away from the contact cannot integrate into bowls.

        Raises:
            ValueError: frames of another size than the model was calibrated on.
        """
        diff = np.asarray(diff, dtype=np.float32)
        if diff.ndim == 3:
            diff = diff[None]
        if tuple(diff.shape[1:3]) != self.frame_size:
            raise ValueError(
                f"frames are {diff.shape[1]}x{diff.shape[2]} px, the depth model was "
                f"calibrated on {self.frame_size[0]}x{self.frame_size[1]} px"
            )
        prepared = self.prepare(diff)
        slope_x, slope_y = self.slopes(prepared)
        zero_x, zero_y = self.zero_change_slopes()
        mask = self._contact_mask(prepared)
        mm_per_px = np.float32(1.0 / self.px_per_mm)
        gx = np.where(mask, slope_x - zero_x, 0.0).astype(np.float32) * mm_per_px
        gy = np.where(mask, slope_y - zero_y, 0.0).astype(np.float32) * mm_per_px
        depth = poisson_depth(gx, gy)
        # Where no pixel shows contact nothing touches: the Poisson solution's leak there
        # (the fitted slopes are not exactly integrable) is not depth.
        depth *= mask
        if not np.all(np.isfinite(depth)):
            raise ValueError(
                "the depth model gives non-finite depths (NaN or infinite) for these frames: "
                "its weights are damaged; calibrate the sensor again"
            )
        return depth

    # -- files -----------------------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        """The JSON document."""
        return {
            "format": DEPTH_MODEL_FORMAT,
            "format_version": DEPTH_MODEL_VERSION,
            "px_per_mm": float(self.px_per_mm),
            "frame_size": list(self.frame_size),
            "ball_radius_mm": float(self.ball_radius_mm),
            "noise_level": float(self.noise_level),
            "marker_level": float(self.marker_level),
            "input_scale": [float(v) for v in self.input_scale],
            "layers": [
                {"weight": weight.tolist(), "bias": bias.tolist()} for weight, bias in self.layers
            ],
            "report": self.report,
        }

    @classmethod
    def from_dict(cls, data: Any) -> CalibratedDepthModel:
        """Read :meth:`to_dict`'s document.

        Raises:
            ValueError: not a depth model, another version, or damaged values.
        """
        if not isinstance(data, dict) or data.get("format") != DEPTH_MODEL_FORMAT:
            raise ValueError(f"not a depth model (no format {DEPTH_MODEL_FORMAT})")
        check_format_version(data.get("format_version"), DEPTH_MODEL_VERSION, "depth model")
        try:
            layers = []
            width = 5
            for layer in data["layers"]:
                weight = np.asarray(layer["weight"], dtype=np.float32)
                bias = np.asarray(layer["bias"], dtype=np.float32)
                if weight.ndim != 2 or weight.shape[0] != width or bias.shape != weight.shape[1:]:
                    raise ValueError(f"layer shapes {weight.shape} / {bias.shape} do not chain")
                width = weight.shape[1]
                layers.append((weight, bias))
            if width != 2 or not layers:
                raise ValueError("the regressor must end in 2 slopes")
            scale = np.asarray(data["input_scale"], dtype=np.float32)
            if scale.shape != (5,) or not np.all(np.isfinite(scale)):
                raise ValueError("input_scale must be 5 finite numbers")
            return cls(
                px_per_mm=float(data["px_per_mm"]),
                frame_size=(int(data["frame_size"][0]), int(data["frame_size"][1])),
                ball_radius_mm=float(data["ball_radius_mm"]),
                noise_level=float(data["noise_level"]),
                marker_level=float(data["marker_level"]),
                layers=layers,
                input_scale=scale,
                report=dict(data.get("report") or {}),
            )
        except (KeyError, TypeError, IndexError) as err:
            raise ValueError(f"damaged depth model ({err!r})") from err


def _noise_level(presses: list[BallPress]) -> float:
    """Colour-change magnitude of untouched pixels (``_NOISE_QUANTILE`` over every press)."""
    values = [contact_magnitude(p.diff)[_far_mask(p.diff.shape[:2], p.circle)] for p in presses]
    return float(np.percentile(np.concatenate(values), _NOISE_QUANTILE))


def _far_mask(shape: tuple[int, int], circle: ContactCircle) -> np.ndarray:
    rows, cols = np.mgrid[0 : shape[0], 0 : shape[1]]
    dist = np.hypot(cols - circle.x_px, rows - circle.y_px)
    return dist > _BACKGROUND_GAP * circle.radius_px


def fit_depth_model(
    presses: list[BallPress],
    ball_radius_mm: float,
    px_per_mm: float,
    *,
    epochs: int = 40,
    seed: int = 0,
    background_per_press: int = 4000,
    threads: int | None = None,
    progress: ProgressBar | None = None,
) -> CalibratedDepthModel:
    """Fit the colour-and-position -> slope regressor on ball presses.

    Args:
        presses: difference images of one sensor, all the same size, with their circles.
        seed: for the initial weights, the background sample and the batch order.
        background_per_press: untouched pixels (slope 0) sampled from each press.
        threads: torch threads for the fit (restored after it); None: the free cores,
            at most 4 (``devices.free_cores``). The result does not depend on it beyond
            float rounding.
        progress: advanced once per epoch (``progress.progress_bar``).

    Raises:
        ValueError: no presses, frames of different sizes, or a circle as large as the ball.
    """
    import torch

    if not presses:
        raise ValueError("no ball presses to fit")
    shape = presses[0].diff.shape[:2]
    if any(p.diff.shape[:2] != shape for p in presses):
        raise ValueError("all presses must have the same frame size")
    rng = np.random.default_rng(seed)
    # What the regressor reads (prepare_diff): the marker level from the raw presses'
    # untouched pixels, then every press without its illumination change and markers.
    raw = np.stack([p.diff for p in presses]).astype(np.float32)
    untouched = np.stack([_far_mask(shape, p.circle) for p in presses])
    marker_level = marker_threshold(raw, untouched, px_per_mm)
    prepared = prepare_diff(raw, marker_level, px_per_mm)
    presses = [BallPress(diff, p.circle, p.name) for diff, p in zip(prepared, presses, strict=True)]
    inputs, targets, in_contact = [], [], []
    for press in presses:
        feats = _features(press.diff)[0]
        radius_mm = press.circle.radius_px / px_per_mm
        if radius_mm > _MAX_CONTACT_TO_BALL * ball_radius_mm:
            raise ValueError(
                f"{press.name or 'a press'}: contact radius {radius_mm:.2f} mm is far above "
                f"the ball radius {ball_radius_mm} mm: check --ball-radius-mm and --px-per-mm"
            )
        # A deep press can show a contact as wide as the ball; train where the cap's slope
        # is still finite and the circle certain.
        train_px = min(_CONTACT_SAFETY * radius_mm, _MAX_TRAIN_TO_BALL * ball_radius_mm)
        safe = ContactCircle(press.circle.x_px, press.circle.y_px, train_px * px_per_mm)
        slope_x, slope_y, inside = sphere_slopes(shape, safe, ball_radius_mm, px_per_mm)
        far = np.flatnonzero(_far_mask(shape, press.circle))
        far = rng.choice(far, size=min(background_per_press, far.size), replace=False)
        for idx, contact in ((np.flatnonzero(inside), True), (far, False)):
            inputs.append(feats.reshape(-1, 5)[idx])
            targets.append(np.stack([slope_x.ravel()[idx], slope_y.ravel()[idx]], axis=1))
            in_contact.append(np.full(len(idx), contact))
    x = np.concatenate(inputs)
    y = np.concatenate(targets).astype(np.float32)
    input_scale = (1.0 / np.maximum(x.std(axis=0), 1e-3)).astype(np.float32)

    with torch_threads(free_cores() if threads is None else threads):
        net = _fit_regressor(x * input_scale, y, epochs, seed, progress or ProgressBar())
        with torch.no_grad():
            residual = (net(torch.from_numpy(x * input_scale)) - torch.from_numpy(y)).numpy()
    layers = [
        (m.weight.detach().numpy().T.copy(), m.bias.detach().numpy().copy())
        for m in net
        if isinstance(m, torch.nn.Linear)
    ]
    return _fitted_model(
        presses,
        in_contact,
        residual,
        layers,
        input_scale,
        shape,
        ball_radius_mm=ball_radius_mm,
        px_per_mm=px_per_mm,
        marker_level=marker_level,
    )


def _fit_regressor(
    x: np.ndarray, y: np.ndarray, epochs: int, seed: int, progress: ProgressBar
) -> Any:
    """The MLP from scaled features ``x`` to slopes ``y``: Adam, cosine rate, ``epochs``."""
    import torch

    torch.manual_seed(seed)
    sizes = (5, *_HIDDEN, 2)
    net = torch.nn.Sequential()
    for k in range(len(sizes) - 1):
        net.append(torch.nn.Linear(sizes[k], sizes[k + 1]))
        if k < len(sizes) - 2:
            net.append(torch.nn.ReLU())
    xt = torch.from_numpy(x)
    yt = torch.from_numpy(y)
    optimiser = torch.optim.Adam(net.parameters(), lr=3e-3)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, T_max=epochs)
    generator = torch.Generator().manual_seed(seed)
    batch = 1024
    for _ in range(epochs):
        order = torch.randperm(len(xt), generator=generator)
        for start in range(0, len(xt), batch):
            idx = order[start : start + batch]
            loss = torch.nn.functional.mse_loss(net(xt[idx]), yt[idx])
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
        schedule.step()
        progress()
    return net


def _fitted_model(
    presses: list[BallPress],
    in_contact: list[np.ndarray],
    residual: np.ndarray,
    layers: list[tuple[np.ndarray, np.ndarray]],
    input_scale: np.ndarray,
    shape: tuple[int, int],
    *,
    ball_radius_mm: float,
    px_per_mm: float,
    marker_level: float,
) -> CalibratedDepthModel:
    """The fitted regressor as a :class:`CalibratedDepthModel`, with its fit report."""
    contact = np.concatenate(in_contact)
    report = {
        "presses": len(presses),
        "contact_pixels": int(contact.sum()),
        "background_pixels": int((~contact).sum()),
        "slope_rmse_contact": float(np.sqrt(np.mean(residual[contact] ** 2))),
        "slope_rmse_background": float(np.sqrt(np.mean(residual[~contact] ** 2))),
        "markers": marker_level > 0,
    }
    return CalibratedDepthModel(
        px_per_mm=float(px_per_mm),
        frame_size=(int(shape[0]), int(shape[1])),
        ball_radius_mm=float(ball_radius_mm),
        noise_level=_noise_level(presses),
        layers=layers,
        input_scale=input_scale,
        report=report,
        marker_level=marker_level,
    )
