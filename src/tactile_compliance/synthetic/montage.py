"""A montage of synthetic grasps for the documentation (docs/synthetic.md, the top image).

Regenerate it with::

    python -m tactile_compliance.synthetic.montage docs/images/synthetic_montage.png
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from tactile_compliance.outputs import atomic_file
from tactile_compliance.synthetic.grasp import SimulationOptions, make_context, simulate_grasp
from tactile_compliance.synthetic.objects import default_objects

__all__ = ["render_montage"]

_TILE = (78, 110)  # (H, W) of one tile [px]
_CAPTION_PX = 16


def _write(
    image: np.ndarray, text: str, origin: tuple[int, int], scale: float, colour: int
) -> None:
    """Anti-aliased text in a grey ``colour``, in place."""
    font = cv2.FONT_HERSHEY_SIMPLEX
    cv2.putText(image, text, origin, font, scale, (colour,) * 3, 1, cv2.LINE_AA)


def _diff_tile(diff_bgr: np.ndarray) -> np.ndarray:
    stretched = np.clip((diff_bgr - 0.5) * 3.0 + 0.5, 0.0, 1.0)
    tile = (stretched * 255).astype(np.uint8)
    return cv2.resize(tile, (_TILE[1], _TILE[0]), interpolation=cv2.INTER_AREA)


def _depth_tile(depth_mm: np.ndarray) -> np.ndarray:
    peak = max(float(depth_mm.max()), 1e-3)
    grey = np.clip(depth_mm / peak * 255.0, 0, 255).astype(np.uint8)
    tile = cv2.applyColorMap(grey, cv2.COLORMAP_VIRIDIS)
    tile = cv2.resize(tile, (_TILE[1], _TILE[0]), interpolation=cv2.INTER_AREA)
    _write(tile, f"max {peak:.2f} mm", (4, _TILE[0] - 6), 0.35, 255)
    return tile


def render_montage(out_png: str | Path, *, seed: int = 0, n_objects: int = 6) -> Path:
    """Render the documentation montage to ``out_png`` (PNG) and return its path."""
    out = Path(out_png)
    out.parent.mkdir(parents=True, exist_ok=True)
    options = SimulationOptions()
    rows = []
    for spec in default_objects(n_objects, seed):
        ctx = make_context(spec, seed, options)
        result = None
        for grasp in range(spec.n_grasps):
            result = simulate_grasp(ctx, grasp)
            if result.samples:
                break
        if result is None or not result.samples:
            continue
        sample = result.samples[0]
        tiles = [_diff_tile(sample.rgb[k]) for k in range(3)]
        tiles.append(_diff_tile(sample.rgb_markers[2]))
        tiles.append(_depth_tile(sample.depth[2]))
        row = np.concatenate(tiles, axis=1)
        caption = np.full((_CAPTION_PX, row.shape[1], 3), 255, dtype=np.uint8)
        text = (
            f"{spec.material} {spec.shape}, E = {spec.modulus_pa:.2g} Pa | F = "
            + "/".join(f"{f:.0f}" for f in sample.forces)
            + " N | W = "
            + "/".join(f"{w * 1e3:.1f}" for w in sample.widths)
            + " mm"
        )
        _write(caption, text, (4, _CAPTION_PX - 4), 0.38, 0)
        rows.append(np.concatenate([caption, row], axis=0))
    header = np.full((_CAPTION_PX, rows[0].shape[1], 3), 255, dtype=np.uint8)
    labels = ["frame 1", "frame 2", "frame 3", "marker finger, frame 3", "depth, frame 3"]
    for i, label in enumerate(labels):
        _write(header, label, (i * _TILE[1] + 4, _CAPTION_PX - 4), 0.38, 0)
    image = np.concatenate([header, *rows], axis=0)
    # 5 bits per channel: barely visible here, and it keeps the PNG under 300 KB.
    image = (image & 0xF8) | 0x04
    ok, encoded = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    if not ok:  # pragma: no cover - OpenCV encodes any uint8 BGR image
        raise ValueError(f"cannot encode {out}")
    with atomic_file(out, "wb") as handle:  # whole, never through a link
        handle.write(encoded.tobytes())
    return out


def main(argv: list[str] | None = None) -> None:
    """``python -m tactile_compliance.synthetic.montage OUT.png [--seed S] [--objects N]``."""
    parser = argparse.ArgumentParser(description="Render the synthetic-data montage.")
    parser.add_argument("out", nargs="?", default="docs/images/synthetic_montage.png")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--objects", type=int, default=6)
    args = parser.parse_args(argv)
    path = render_montage(args.out, seed=args.seed, n_objects=args.objects)
    print(f"wrote {path} ({path.stat().st_size / 1024:.0f} KB)")


if __name__ == "__main__":
    main()
