"""GelSight-like rendering of gel indentation fields into camera frames and difference images.

Intensities in grey levels (0-255), BGR as OpenCV reads the real camera. See
docs/synthetic.md, "Rendering" (the steps below: height map, shading, background, edge
glow, noise) and "The green edge's glow".
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import cv2
import numpy as np

from tactile_compliance.data.image_ops import difference_images
from tactile_compliance.synthetic.geometry import PAD_SIZE_MM, PadGrid
from tactile_compliance.synthetic.rng import log_uniform

__all__ = [
    "SensorLook",
    "difference_images",
    "gel_height_maps",
    "reference_frame",
    "render_frames",
    "sample_edge_glow",
    "sample_sensor_look",
]

FULL_SIZE = (250, 350)
"""Image size (H, W) of the real dataset [px]."""

PIXEL_SIZE_MM_FULL = 35.0 / 400.0
"""Pixel size at full resolution [mm] (400 px over the 35 mm pad, cropped 25 px/side)."""

VISIBLE_SIZE_MM = (FULL_SIZE[1] * PIXEL_SIZE_MM_FULL, FULL_SIZE[0] * PIXEL_SIZE_MM_FULL)
"""Visible crop (x, y) = (30.625, 21.875) mm, centred on the pad."""


def pixel_size_mm(size: tuple[int, int]) -> float:
    """Pixel size [mm] of an output image of ``size`` = (H, W) over the visible crop."""
    return VISIBLE_SIZE_MM[0] / size[1]


def render_size(size: tuple[int, int]) -> tuple[int, int]:
    """The size (H, W) [px] that frames stored at ``size`` are rendered at.

    Pixels are square and the image spans the visible crop's width, so a frame much
    taller than the real 250 x 350 aspect (H/W above the pad's 25.5/35) would need rows
    beyond the pad. Such a frame is rendered wider, with the same rows, and then squeezed
    to ``size``, as resizing a real frame to that size would. Every other size renders
    as it is.
    """
    height, width = int(size[0]), int(size[1])
    while round(PAD_SIZE_MM[1] / pixel_size_mm((height, width))) < height:
        width += 1
    return height, width


def to_stored_size(frames: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Frames (n, H', W', ...) rendered at :func:`render_size` squeezed to ``size`` (H, W)."""
    if frames.shape[1:3] == tuple(size):
        return frames
    target = (size[1], size[0])  # OpenCV's (width, height)
    return np.stack([cv2.resize(frame, target, interpolation=cv2.INTER_AREA) for frame in frames])


@dataclass
class SensorLook:
    """Appearance of one finger's sensor in one recording session.

    Attributes:
        markers: whether the gel has printed markers (the ``*_markers`` finger).
        light_gain: gel slope -> grey-level gain per light (G, R, B) [grey levels per
            unit slope, divided by 255].
        elevation_rad: light elevations (G, R, B) [rad].
        falloff: decay length of each light's strength away from its edge, as a fraction
            of the image size [-].
        background: parameters of the parametric background (grey levels / fractions).
        read_noise: read-noise sigma [grey levels].
        drift: per-frame gain sigma [-] and offset sigma [grey levels].
        jpeg_quality: JPEG quality of the stream (0 disables compression).
        darkening: grey levels lost per mm of imprint (the membrane thins) [1/mm].
        seed_words: 32-bit words seeding the background's fine structure.
        edge_glow: the green edge's glow: ``(gain [grey levels of G per mm of mean
            imprint depth in the left strip], row centre [fraction of H], row sigma
            [fraction of H], fade length [fraction of W])``; gain 0 (the default)
            renders none.
    """

    markers: bool
    light_gain: tuple[float, float, float]
    elevation_rad: tuple[float, float, float]
    falloff: tuple[float, float, float]
    background: dict[str, float]
    read_noise: float
    drift: tuple[float, float]
    jpeg_quality: int
    darkening: tuple[float, float, float]
    seed_words: tuple[int, ...]
    marker_spacing_mm: float = 1.8
    marker_radius_mm: float = 0.3
    edge_glow: tuple[float, float, float, float] = (0.0, 0.6, 0.18, 0.07)
    _cache: dict[tuple[int, int], tuple[np.ndarray, ...]] = field(
        default_factory=dict, repr=False, compare=False
    )


def sample_sensor_look(
    rng: np.random.Generator,
    markers: bool,
    light_jitter: float = 0.08,
    read_noise_grey: tuple[float, float] = (2.0, 3.0),
    background_jitter: float = 1.0,
) -> SensorLook:
    """Draw a sensor appearance (independent of the object's label). ``light_jitter``
    (sd of each light's strength factor [-]), ``read_noise_grey`` (range of the noise
    sigma [grey levels]) and ``background_jitter`` (factor on the spread of the
    background's colours [-]) are a rig's domain randomisation
    (``synthetic.rig.GripperRig``); the defaults are the generator's own."""
    jitter = lambda: float(rng.normal(1.0, light_jitter))  # noqa: E731 - tiny local helper
    bj = float(background_jitter)
    # Where the membrane is pressed it thins and darkens, about equally in every channel
    # (so the photometric inversion, which works on channel differences, is unaffected).
    dark_all = float(rng.uniform(5.0, 12.0))
    background = {
        "centre_b": rng.normal(140.0, 6.0 * bj),
        "centre_g": rng.normal(122.0, 5.0 * bj),
        "centre_r": rng.normal(106.0, 5.0 * bj),
        "blue_band": rng.uniform(55.0, 85.0),
        "blue_width": rng.uniform(0.10, 0.18),
        "red_band": rng.uniform(18.0, 35.0),
        "red_width": rng.uniform(0.12, 0.25),
        "green_band": rng.uniform(10.0, 30.0),
        "green_width": rng.uniform(0.04, 0.10),
        "vignette": rng.uniform(8.0, 18.0),
        "blotch": rng.uniform(2.0, 5.0),
        "specks": float(rng.integers(10, 45)),
    }
    return SensorLook(
        markers=markers,
        light_gain=(0.80 * jitter(), 0.55 * jitter(), 0.35 * jitter()),
        elevation_rad=tuple(np.deg2rad(rng.uniform(25.0, 40.0, size=3)).tolist()),
        falloff=tuple(rng.uniform(0.35, 0.7, size=3).tolist()),
        background=background,
        read_noise=float(rng.uniform(*read_noise_grey)),
        drift=(float(rng.uniform(0.001, 0.004)), float(rng.uniform(0.3, 1.0))),
        jpeg_quality=int(rng.integers(85, 96)) if rng.random() < 0.7 else 0,
        darkening=(
            dark_all,
            dark_all,
            dark_all + float(rng.uniform(0.0, 3.0)),
        ),
        seed_words=tuple(int(x) for x in rng.integers(0, 2**31, size=4)),
    )


def _base_images(look: SensorLook, size: tuple[int, int]) -> tuple[np.ndarray, ...]:
    """(background BGR, light strength maps (3,H,W), marker darkening (H,W)) for a size."""
    cached = look._cache.get(size)
    if cached is not None:
        return cached
    h, w = size
    p = look.background
    y = ((np.arange(h, dtype=np.float32) + 0.5) / h)[:, None]
    x = ((np.arange(w, dtype=np.float32) + 0.5) / w)[None, :]
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence(list(look.seed_words))))
    # Smooth blotches: a low-resolution random field, upsampled (size independent).
    blotch = rng.standard_normal((3, 6, 8)).astype(np.float32) * np.float32(p["blotch"])
    blotches = np.stack(
        [cv2.resize(b, (w, h), interpolation=cv2.INTER_CUBIC) for b in blotch], axis=-1
    )
    radial = (x - 0.5) ** 2 + (y - 0.45) ** 2
    vignette = -np.float32(p["vignette"]) * radial * 4.0
    blue = np.float32(p["blue_band"]) * np.exp(-(1.0 - y) / np.float32(p["blue_width"]))
    red = np.float32(p["red_band"]) * np.exp(-y / np.float32(p["red_width"]))
    green = np.float32(p["green_band"]) * np.exp(-x / np.float32(p["green_width"]))
    bg = np.empty((h, w, 3), dtype=np.float32)
    bg[..., 0] = p["centre_b"] + blue + 0.25 * red + vignette
    bg[..., 1] = p["centre_g"] + green - 0.15 * blue + vignette
    bg[..., 2] = p["centre_r"] + red + 0.1 * blue + vignette
    bg += blotches
    # Bright specks (dust, bubbles in the gel): placed in normalised coordinates so a
    # small render shows the same sensor.
    n_specks = int(p["specks"])
    sx, sy = rng.uniform(0, 1, n_specks), rng.uniform(0, 1, n_specks)
    amp = rng.uniform(15.0, 60.0, n_specks)
    speck_sigma_mm = rng.uniform(0.04, 0.12, n_specks)
    px = pixel_size_mm(size)
    specks = np.zeros((h, w), dtype=np.float32)
    for cx, cy, a, s in zip(sx, sy, amp, speck_sigma_mm, strict=True):
        sig = max(s / px, 0.5)
        r = int(np.ceil(3 * sig))
        ci, cj = int(cy * h), int(cx * w)
        i0, i1, j0, j1 = max(ci - r, 0), min(ci + r + 1, h), max(cj - r, 0), min(cj + r + 1, w)
        ii = np.arange(i0, i1, dtype=np.float32)[:, None] - cy * h
        jj = np.arange(j0, j1, dtype=np.float32)[None, :] - cx * w
        specks[i0:i1, j0:j1] += a * np.exp(-(ii**2 + jj**2) / (2 * sig * sig))
    bg += specks[..., None]
    # Light strength: strongest at its own edge (green left, red top, blue bottom).
    fg, fr, fb = look.falloff
    strength = np.empty((3, h, w), dtype=np.float32)
    strength[0] = 0.75 + 0.5 * np.exp(-x / np.float32(fg))  # green
    strength[1] = 0.75 + 0.5 * np.exp(-y / np.float32(fr))  # red
    strength[2] = 0.75 + 0.5 * np.exp(-(1.0 - y) / np.float32(fb))  # blue
    strength /= strength.mean(axis=(1, 2), keepdims=True)
    markers = np.zeros((h, w), dtype=np.float32)
    if look.markers:
        spacing = look.marker_spacing_mm / px
        radius = look.marker_radius_mm / px
        yy = np.arange(h, dtype=np.float32)[:, None]
        xx = np.arange(w, dtype=np.float32)[None, :]
        phase = rng.uniform(0, spacing, size=2)
        dx = np.mod(xx - phase[0] + spacing / 2, spacing) - spacing / 2
        dy = np.mod(yy - phase[1] + spacing / 2, spacing) - spacing / 2
        dist = np.sqrt(dx * dx + dy * dy)
        markers = np.clip(radius + 0.5 - dist, 0.0, 1.0).astype(np.float32) * 0.75
    result = (bg, strength, markers)
    look._cache[size] = result
    return result


EDGE_GLOW_COLOUR_BGR = (0.3, 1.0, -0.9)
"""Grey-level change of (B, G, R) per unit of the edge glow: the band's colour, measured
on the real Wedge grasps' difference images (green up, red down; any press shows it)."""

EDGE_GLOW_MAX_GREY = 70.0
"""The brightest the glow gets [grey levels of G]: it saturates as the edge's light is
all scattered out. The real Wedge's strongest band, under the soft balls at 23 N, peaks
at ~65 grey levels of G (G - R ~124)."""

EDGE_GLOW_STRIP = 0.06
"""Width of the left strip whose mean imprint depth drives the glow [fraction of W]."""


def sample_edge_glow(
    rng: np.random.Generator, gain_range: tuple[float, float]
) -> tuple[float, float, float, float]:
    """Draw an edge glow (``SensorLook.edge_glow``): the gain log-uniformly from
    ``gain_range`` [grey levels per mm], the band's place and fade around the real
    Wedge's (row centre 0.6 H, sigma 0.18 H, fade 0.07 W)."""
    return (
        log_uniform(rng, *gain_range),
        float(rng.uniform(0.45, 0.7)),
        float(rng.uniform(0.12, 0.25)),
        float(rng.uniform(0.05, 0.1)),
    )


def _add_edge_glow(
    planes: np.ndarray, depth: np.ndarray, look: SensorLook, scale: np.ndarray | None = None
) -> None:
    """Add the green edge's glow to ``planes`` (B, G, R; n, H, W), in place; ``scale``
    (n,) [-] multiplies each frame's gain (None: 1).

    Only the columns where the band is above 1e-3 of its peak (about 7 fade lengths) are
    touched: the glow is a left-edge effect, and the rest of the frame is the hot path's.
    """
    gain, centre, sigma, fade = look.edge_glow
    h, w = depth.shape[1:]
    strip = max(round(EDGE_GLOW_STRIP * w), 1)
    linear = gain * depth[:, :, :strip].mean(axis=(1, 2), dtype=np.float64)  # (n,)
    if scale is not None:
        linear = linear * np.asarray(scale, dtype=np.float64)
    drive = (EDGE_GLOW_MAX_GREY * np.tanh(linear / EDGE_GLOW_MAX_GREY)).astype(np.float32)
    cols = min(w, int(np.ceil(-np.log(1e-3) * fade * w)))
    y = (np.arange(h, dtype=np.float32) + 0.5) / h
    x = (np.arange(cols, dtype=np.float32) + 0.5) / w
    band = np.exp(-0.5 * ((y - centre) / sigma) ** 2)[:, None] * np.exp(-x / fade)[None, :]
    for plane, colour in enumerate(EDGE_GLOW_COLOUR_BGR):
        planes[plane, :, :, :cols] += (np.float32(colour) * drive)[:, None, None] * band


@lru_cache(maxsize=8)
def _noise_bank(size: tuple[int, int]) -> np.ndarray:
    """Unit-normal read-noise bank for an image size (fixed content, process-local).

    Drawing 3 x H x W normals per frame costs more than rendering it; frames take
    randomly offset, randomly flipped windows of this bank instead. The bank is the
    same in every process, so outputs stay deterministic.
    """
    h, w = size
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([0x5EED, h, w])))
    return rng.standard_normal((3, 2 * h, 2 * w), dtype=np.float32)


def _noise(size: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    h, w = size
    bank = _noise_bank(size)
    i, j = int(rng.integers(0, h)), int(rng.integers(0, w))
    window = bank[:, i : i + h, j : j + w]
    flip = int(rng.integers(0, 4))
    if flip & 1:
        window = window[:, ::-1]
    if flip & 2:
        window = window[:, :, ::-1]
    return window


def gel_height_maps(
    fields_mm: np.ndarray,
    grid: PadGrid,
    size: tuple[int, int],
    gel_thickness_mm: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Imprint depth on the visible crop (with skirt) and the contact weight.

    The skirt's wide blurs run on a 2x coarser copy of the pad grid with the frames as
    the channels of one image (OpenCV takes up to 128; one call for all frames); the
    full-size resampling runs frame by frame, because stacked full-size outputs would
    need a strided transpose that costs more than the resampling itself.

    Args:
        fields_mm: gel compression fields on the pad grid, (n, rows, cols) [mm].
        grid: the pad grid of the fields.
        size: output size (H, W) [px].
        gel_thickness_mm: gel thickness h [mm] (sets the skirt width).

    Returns:
        ``(depth (n, H, W) [mm], contact (n, H, W) in [0, 1])``, float32.
    """
    n = fields_mm.shape[0]
    h, w = size
    out_depth = np.zeros((n, h, w), dtype=np.float32)
    out_contact = np.zeros((n, h, w), dtype=np.float32)
    active = np.flatnonzero(fields_mm.reshape(n, -1).max(axis=1) > 0)
    px = pixel_size_mm(size)
    pad_w, pad_h = round(PAD_SIZE_MM[0] / px), round(PAD_SIZE_MM[1] / px)  # the whole pad
    off_y, off_x = (pad_h - h) // 2, (pad_w - w) // 2  # the visible crop, centred
    crop = (slice(off_y, off_y + h), slice(off_x, off_x + w))
    for start in range(0, active.size, 128):
        chunk = active[start : start + 128]
        stack = np.asarray(fields_mm[chunk], dtype=np.float32)
        rows, cols = stack.shape[1:]
        even = stack[:, : 2 * (rows // 2), : 2 * (cols // 2)]
        coarse = 0.25 * (
            even[:, 0::2, 0::2] + even[:, 1::2, 0::2] + even[:, 0::2, 1::2] + even[:, 1::2, 1::2]
        )
        coarse = np.ascontiguousarray(coarse.transpose(1, 2, 0))  # frames as channels
        core = coarse > 0.4 * coarse.max(axis=(0, 1), keepdims=True)
        core_values = coarse[core]
        skirt = coarse
        for factor in (1.0, 0.5, 0.25, 0.12):
            sigma = gel_thickness_mm * factor / (2 * grid.cell_mm)
            skirt = cv2.GaussianBlur(skirt, (0, 0), sigma, borderType=cv2.BORDER_REPLICATE)
            skirt = skirt.reshape(coarse.shape)
            skirt[core] = core_values
        skirt = skirt.transpose(2, 0, 1)
        for i, k in enumerate(chunk):
            field = stack[i]
            fine = cv2.resize(field, (pad_w, pad_h), interpolation=cv2.INTER_CUBIC)[crop]
            smooth = cv2.resize(
                np.ascontiguousarray(skirt[i]), (pad_w, pad_h), interpolation=cv2.INTER_LINEAR
            )[crop]
            np.maximum(fine, smooth, out=out_depth[k])
            np.maximum(out_depth[k], 0.0, out=out_depth[k])
            touching = cv2.resize(
                (field > 0).astype(np.float32), (pad_w, pad_h), interpolation=cv2.INTER_LINEAR
            )[crop]
            np.clip(touching, 0.0, 1.0, out=out_contact[k])
    return out_depth, out_contact


def _soft_clip(image: np.ndarray) -> np.ndarray:
    """Soft saturation of the camera near 0 and 255 (grey levels, in place)."""
    # One SIMD min/max pass decides whether the masked (slow) paths are needed at all.
    low, high, _, _ = cv2.minMaxLoc(image.reshape(-1, image.shape[-1]))
    if high > 225.0:
        hi = image > 225.0
        image[hi] = 225.0 + 30.0 * np.tanh((image[hi] - 225.0) / 30.0)
    if low < 15.0:
        lo = image < 15.0
        image[lo] = 15.0 * np.exp((image[lo] - 15.0) / 15.0)
    return image


def _contact_box(depth: np.ndarray, margin: int = 3) -> tuple[slice, slice] | None:
    """Rows and columns holding every non-zero imprint pixel, grown by ``margin``.

    Outside this box the imprint and its central-difference slopes are exactly zero,
    so shading there adds nothing. A margin of 3 px keeps the box's edge-replicated
    slopes zero too (the slope next to the edge only sees zero depth).
    """
    touched = depth.max(axis=0) > 0
    rows = np.flatnonzero(touched.any(axis=1))
    if rows.size == 0:
        return None
    cols = np.flatnonzero(touched.any(axis=0))
    h, w = touched.shape
    return (
        slice(max(int(rows[0]) - margin, 0), min(int(rows[-1]) + margin + 1, h)),
        slice(max(int(cols[0]) - margin, 0), min(int(cols[-1]) + margin + 1, w)),
    )


def _shading(depth: np.ndarray, look: SensorLook, gain_maps: np.ndarray, px: float) -> np.ndarray:
    """Grey-level change (3, n, h, w) of planes B, G, R caused by the imprint ``depth`` [mm].

    ``gain_maps`` (3, h, w) are the lights' (G, R, B) slope gains over the same pixels.
    """
    # Central differences (edges replicated): slope = dD/dx [mm/mm].
    sx = np.empty_like(depth)
    sy = np.empty_like(depth)
    np.subtract(depth[:, :, 2:], depth[:, :, :-2], out=sx[:, :, 1:-1])
    sx[:, :, 0], sx[:, :, -1] = sx[:, :, 1], sx[:, :, -2]
    np.subtract(depth[:, 2:, :], depth[:, :-2, :], out=sy[:, 1:-1, :])
    sy[:, 0, :], sy[:, -1, :] = sy[:, 1, :], sy[:, -2, :]
    sx *= np.float32(0.5 / px)
    sy *= np.float32(0.5 / px)
    nz = sx * sx
    nz += sy * sy
    nz += 1.0
    np.sqrt(nz, out=nz)
    np.reciprocal(nz, out=nz)
    nz_minus_1 = nz - 1.0
    shades = np.empty((3, *depth.shape), dtype=np.float32)
    # (n.L - sin e) / cos e = s_L nz + tan(e) (nz - 1): ~ the slope towards the light
    # for small slopes, darker on steep walls. Planes are B, G, R.
    for plane, (light, slope, sign, dark) in enumerate(
        ((2, sy, 1.0, 0), (0, sx, 1.0, 1), (1, sy, -1.0, 2))
    ):
        shade = shades[plane]
        np.multiply(slope, nz, out=shade)
        if sign < 0:
            np.negative(shade, out=shade)
        shade += np.float32(np.tan(look.elevation_rad[light])) * nz_minus_1
        shade *= gain_maps[light]
        shade -= np.float32(look.darkening[dark]) * depth
    return shades


def render_frames(
    depth_mm: np.ndarray,
    look: SensorLook,
    rng: np.random.Generator,
    glow_scale: np.ndarray | None = None,
) -> np.ndarray:
    """Camera frames (n, H, W, 3) uint8 BGR for imprint depth maps (n, H, W) [mm];
    ``glow_scale`` (n,) [-] multiplies the edge glow's gain frame by frame (None: 1).

    Computed on planar (channel, frame, H, W) arrays - interleaved channels would
    make every operation strided - and interleaved once, as uint8, at the end. The
    shading is computed only inside the box that the imprint touches.
    """
    depth = np.asarray(depth_mm, dtype=np.float32)
    n, h, w = depth.shape
    size = (h, w)
    bg, strength, markers = _base_images(look, size)
    planes = np.empty((3, n, h, w), dtype=np.float32)
    planes[:] = bg.transpose(2, 0, 1)[:, None]
    box = _contact_box(depth)
    if box is not None:
        gain_maps = (
            strength[(slice(None), *box)]
            * (np.asarray(look.light_gain, dtype=np.float32) * 255.0)[:, None, None]
        )
        region = (slice(None), slice(None), *box)
        planes[region] += _shading(depth[region[1:]], look, gain_maps, pixel_size_mm(size))
    if look.edge_glow[0] > 0:
        _add_edge_glow(planes, depth, look, glow_scale)
    if look.markers:
        planes *= 1.0 - markers
    drift_gain, drift_offset = look.drift
    gains = (1.0 + rng.normal(0.0, drift_gain, n)).astype(np.float32)
    offsets = rng.normal(0.0, drift_offset, (3, n)).astype(np.float32)
    planes *= gains[None, :, None, None]
    planes += offsets[:, :, None, None]
    sigma = np.float32(look.read_noise)
    for k in range(n):
        planes[:, k] += sigma * _noise(size, rng)
    _soft_clip(planes)
    # Round and saturate to uint8 in one OpenCV pass (values are >= 0 after the clip),
    # then interleave each frame's planes with cv2.merge (SIMD, no strided copy).
    quantised = cv2.convertScaleAbs(planes.reshape(-1, w)).reshape(3, n, h, w)
    frames = np.empty((n, h, w, 3), dtype=np.uint8)
    for k in range(n):
        cv2.merge([quantised[0, k], quantised[1, k], quantised[2, k]], dst=frames[k])
    if look.jpeg_quality:
        params = [cv2.IMWRITE_JPEG_QUALITY, look.jpeg_quality]
        for k in range(n):
            ok, buf = cv2.imencode(".jpg", frames[k], params)
            if ok:
                frames[k] = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    return frames


def reference_frame(
    look: SensorLook, size: tuple[int, int], rng: np.random.Generator
) -> np.ndarray:
    """The contact-free first frame (H, W, 3) uint8, and nothing else."""
    return render_frames(np.zeros((1, *size), dtype=np.float32), look, rng)[0]
