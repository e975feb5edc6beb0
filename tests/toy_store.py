"""A tiny, learnable GraspStore for training tests (seconds on a CPU).

The log modulus is encoded weakly in the frames (the radius and depth of a pressed blob),
in the width change and in the estimates, so a model that learns anything beats the
median predictor. It passes every filter rule (F rises, W falls, depth rises).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tactile_compliance.data.image_ops import resize_frames
from tactile_compliance.data.store import GraspStore, depth_size_for, frames_from_uint8
from tactile_compliance.data.store_writer import GraspStoreWriter

MATERIALS = ("Foam", "Rubber", "Plastic", "Metal")
SHAPES = ("Sphere", "Cylinder")


def make_sample(
    rng: np.random.Generator,
    log_e: float,
    size: tuple[int, int],
    *,
    time_shift: float = 0.0,
    period: float = 3.0,
) -> tuple[np.ndarray, dict[str, float]]:
    """One learnable sample of an object with log10 modulus ``log_e`` (Pa): its three
    frames (float32 in [0, 1], (3, H, W, 3)) and its physical columns (modulus, force,
    width, the two estimates, contact depth).

    The object is pressed into a blob whose radius and contrast grow with softness over
    the frames; ``time_shift`` moves the frames later in the press by that many frame
    steps (a time-shifted copy of a grasp), and the blob reaches its full radius after
    ``period`` steps. The random draws (frame noise, force noise, estimate noise) come
    from ``rng`` in this order, so a store is reproducible from its seed.
    """
    height, width = size
    yy, xx = np.mgrid[0:height, 0:width]
    radius_sq = (yy - height / 2) ** 2 + (xx - width / 2) ** 2
    softness = (11.0 - log_e) / 7.0  # 1 for soft (1e4 Pa), 0 for hard (1e11 Pa)
    frames = np.empty((3, height, width, 3), np.float32)
    for t in range(3):
        blob_radius = 3 + 8 * softness * (t + 1 + time_shift) / period
        blob = np.exp(-radius_sq / (2 * blob_radius**2))
        for c in range(3):
            frames[t, ..., c] = 0.5 + (0.05 + 0.1 * softness) * blob * (c + 1) / 3
    frames += rng.normal(0, 0.01, frames.shape).astype(np.float32)
    force_n = np.array([8.0, 30.0, 58.0]) + rng.normal(0, 0.5, 3)
    squeeze_m = 0.002 + 0.01 * softness
    widths_m = 0.05 - np.array([0.0, 0.5, 1.0]) * squeeze_m
    estimate_pa = 10 ** (log_e * 0.4 + 3.0 + rng.normal(0, 0.2))
    columns = {
        "modulus_pa": 10**log_e,
        **{f"force_n_{i}": force_n[i] for i in range(3)},
        **{f"width_m_{i}": widths_m[i] for i in range(3)},
        "elastic_estimate_pa": estimate_pa,
        "hertz_estimate_pa": estimate_pa * 2,
        **{f"depth_max_mm_{i}": 0.3 * (i + 1) for i in range(3)},
    }
    return np.clip(frames, 0, 1), columns


def toy_depth(log_e: float, size: tuple[int, int]) -> np.ndarray:
    """Depth maps (3, h, w) mm at the store's depth size for frames of ``size``: a dome
    whose depth grows with softness over the press (no random draw, so a store with depth
    maps has the same frames and columns as one without)."""
    height, width = depth_size_for(size)
    yy, xx = np.mgrid[0:height, 0:width]
    radius_sq = ((yy - height / 2) / height) ** 2 + ((xx - width / 2) / width) ** 2
    softness = (11.0 - log_e) / 7.0
    peaks = 0.2 + 1.2 * softness * np.array([1.0, 2.0, 3.0]) / 3
    return (peaks[:, None, None] * np.exp(-radius_sq / 0.05)).astype(np.float32)


def make_toy_store(
    path: Path,
    n_objects: int = 16,
    grasps: int = 4,
    size: tuple[int, int] = (32, 32),
    seed: int = 0,
    depth: bool = False,
    units: dict[str, object] | None = None,
) -> GraspStore:
    """The toy store; ``depth`` adds depth maps (:func:`toy_depth`) to every sample;
    ``units``: the rows' unit columns (``store.UNIT_COLUMNS``); default the dataset's. Units
    with a ``rig_stiffness_n_per_m`` add rig-corrected estimates (the estimates x 3, drawing
    nothing, so the other columns stay those of a store without them)."""
    rng = np.random.default_rng(seed)
    depth_size = depth_size_for(size) if depth else None
    with GraspStoreWriter(path, size, "toy", depth_size=depth_size) as writer:
        for index in range(n_objects):
            log_e = 4.0 + 7.0 * index / max(1, n_objects - 1)  # 1e4 .. 1e11 Pa
            for grasp in range(grasps):
                for finger in ("markerless", "markers"):
                    frames, columns = make_sample(rng, log_e, size)
                    if (units or {}).get("rig_stiffness_n_per_m") is not None:
                        for name in ("elastic", "hertz"):
                            columns[f"{name}_rig_estimate_pa"] = 3 * columns[f"{name}_estimate_pa"]
                    writer.append(
                        frames,
                        {
                            "object": f"toy_{index:02d}",
                            "grasp": grasp,
                            "augmentation": 0,
                            "finger": finger,
                            "material": MATERIALS[index * len(MATERIALS) // n_objects],
                            "shape": SHAPES[index % 2],
                            **columns,
                            "source_path": f"toy/{index}/{grasp}",
                            **(units or {}),
                        },
                        toy_depth(log_e, size) if depth else None,
                    )
    return GraspStore.open(path)


def tiny_run_config(store_path, out, model, extra=()):  # type: ignore[no-untyped-def]
    """A config for a seconds-long training run on the toy store (``extra`` applied last)."""
    from tactile_compliance.config import load_config

    return load_config(
        "default",
        [
            f"data.store={store_path}",
            f"output_dir={out}",
            f"model.name={model}",
            "augmentation.enabled=false",
            "training.batch_size=16",
            *extra,
        ],
    )


def depth_toy_store(path, **kwargs):  # type: ignore[no-untyped-def]
    """``make_toy_store`` with depth maps: each frame's pressed blob (its deviation from
    0.5, scaled to the sample's ``depth_max_mm``), area-averaged to the store's depth size."""
    toy = make_toy_store(path.with_name(path.name + "-plain"), **kwargs)
    size = depth_size_for(toy.image_size)
    maxima = toy.samples[[f"depth_max_mm_{i}" for i in range(3)]].to_numpy(dtype=np.float64)
    with GraspStoreWriter(path, toy.image_size, "toy", depth_size=size) as writer:
        for index in range(len(toy)):
            frames = toy.read_sample(index)
            deviation = np.abs(frames_from_uint8(frames) - 0.5).mean(axis=-1)  # (3, H, W)
            shape = deviation / deviation.max(axis=(1, 2), keepdims=True)
            depth = resize_frames(shape.astype(np.float32), size) * maxima[index, :, None, None]
            row = toy.samples.iloc[index].drop("sample_id").to_dict()
            writer.append(frames, row, depth)
    return GraspStore.open(path)
