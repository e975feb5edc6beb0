"""Frozen-backbone feature cache: image features (of the RGB frames or the depth maps)
computed once per store, image input and backbone, under ``STORE/features/KEY/``.

See docs/data.md, "The frozen-backbone feature cache".
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import numpy as np
import torch

from tactile_compliance.data.dataset import prepare_images
from tactile_compliance.data.normalisation import NormalisationConstants
from tactile_compliance.data.store import GraspStore
from tactile_compliance.devices import DEFAULT_DEVICE, resolve_device
from tactile_compliance.outputs import atomic_file, commit_path, exclusive_lock
from tactile_compliance.progress import progress_bar

FEATURES_DIR = "features"
FEATURES_FILE = "features.f16"
META_FILE = "meta.json"
PROGRESS_FILE = "progress.json"
LOCK_FILE = "lock"


def weights_fingerprint(module: torch.nn.Module) -> str:
    """sha256 over a module's parameters and buffers (names, shapes, float32 bytes)."""
    digest = hashlib.sha256()
    for name, tensor in sorted(module.state_dict().items()):
        digest.update(name.encode())
        digest.update(str(tuple(tensor.shape)).encode())
        digest.update(tensor.detach().to(torch.float32).cpu().contiguous().numpy().tobytes())
    return digest.hexdigest()


def cache_key(
    backbone: torch.nn.Module,
    image_size: tuple[int, int],
    constants: NormalisationConstants,
    image: str = "frames",
) -> str:
    """Directory name identifying (backbone, weights, resolution, image input and its
    normalisation): the frames' mean and std, or the depth maps' ``depth_scale_mm``."""
    if image == "frames":
        norm = json.dumps([constants.image_mean, constants.image_std])
    elif image == "depth":
        norm = json.dumps(["depth", constants.depth_scale_mm])
    else:
        raise ValueError(f"{image!r} is no image input")
    digest = hashlib.sha256(norm.encode()).hexdigest()[:8]
    height, width = image_size
    name = type(backbone).__name__.lower()
    kind = "" if image == "frames" else f"{image}-"
    return f"{name}-{weights_fingerprint(backbone)[:16]}-{height}x{width}-{kind}{digest}"


@torch.no_grad()
def cached_features(
    store: GraspStore,
    backbone: torch.nn.Module,
    image_size: tuple[int, int],
    constants: NormalisationConstants,
    *,
    image: str = "frames",
    batch_size: int = 32,
    device: str | torch.device = DEFAULT_DEVICE,
    progress: bool = True,
) -> np.ndarray:
    """Features (N_store, 3, feature_dim) of every store sample, computed once and cached.

    Returns a read-only float16 memmap; callers convert batches to float32.
    ``image`` is the image input the backbone reads (``"frames"`` or ``"depth"``, the
    strategy's ``InputStrategy.image``), prepared as training prepares it
    (``data.dataset.prepare_images``); ``image_size`` (height, width) px is what it is
    resized to (the run's ``RunInputs.image_size``).

    The cache is keyed by :func:`cache_key` (the backbone's weights hash included), so
    other weights never reuse stale features. Safe for several processes at once: one
    computes under the cache's lock while the others wait and then read its result; a
    killed computation is resumed by the next caller. Reading a finished cache takes no
    lock.
    """
    size = tuple(image_size)
    directory = store.path / FEATURES_DIR / cache_key(backbone, size, constants, image)
    if image == "depth":
        store.require_depth()
    final, meta_path = directory / FEATURES_FILE, directory / META_FILE
    feature_dim = int(backbone.feature_dim)
    shape = (len(store), 3, feature_dim)
    if final.exists() and meta_path.exists():
        return np.memmap(final, dtype=np.float16, mode="r", shape=shape)

    directory.mkdir(parents=True, exist_ok=True)
    with exclusive_lock(directory / LOCK_FILE, what="the feature cache"):
        # Another process may have finished the cache while this one waited for the lock.
        if not (final.exists() and meta_path.exists()):
            device = resolve_device(device)
            _compute(
                store,
                backbone,
                image,
                size,
                constants,
                directory,
                shape,
                batch_size,
                device,
                progress,
            )
    return np.memmap(final, dtype=np.float16, mode="r", shape=shape)


def _compute(
    store: GraspStore,
    backbone: torch.nn.Module,
    image: str,
    size: tuple[int, int],
    constants: NormalisationConstants,
    directory: Path,
    shape: tuple[int, int, int],
    batch_size: int,
    device: str | torch.device,
    progress: bool,
) -> None:
    """Fill ``directory`` with the features; the caller holds the cache's lock (and no_grad)."""
    final, meta_path = directory / FEATURES_FILE, directory / META_FILE
    partial, progress_path = directory / (FEATURES_FILE + ".partial"), directory / PROGRESS_FILE
    # Resume only when both the partial array and its progress record survived.
    resumable = (
        partial.exists()
        and partial.stat().st_size == int(np.prod(shape)) * 2
        and progress_path.exists()
    )
    done = int(json.loads(progress_path.read_text())["done"]) if resumable else 0
    array = np.memmap(partial, dtype=np.float16, mode="r+" if resumable else "w+", shape=shape)
    was_training = backbone.training
    backbone.eval().to(device)
    try:
        with progress_bar("Caching features", total=len(store), enabled=progress) as advance:
            advance(done)
            for start in range(done, len(store), batch_size):
                stop = min(start + batch_size, len(store))
                if image == "frames":
                    raw = store.read_block(start, stop)  # uint8, one pread
                else:
                    raw = store.read_depth(np.arange(start, stop))  # mm
                images = torch.from_numpy(np.array(raw, copy=True)).to(device)
                x = prepare_images(image, images, constants, size)  # (B, 3, 3, h, w)
                batch = x.shape[0]
                out = backbone(x.reshape(batch * 3, *x.shape[2:])).reshape(batch, 3, -1)
                array[start:stop] = out.float().cpu().numpy().astype(np.float16)
                array.flush()
                with atomic_file(progress_path) as handle:
                    handle.write(json.dumps({"done": stop}))
                advance(stop - start)
    finally:
        backbone.train(was_training)
    del array
    meta: dict[str, Any] = {
        "backbone": type(backbone).__name__,
        "weights_sha256": weights_fingerprint(backbone),
        "image": image,
        "image_size": list(size),
        "shape": list(shape),
        "dtype": "float16",
        "image_mean": list(constants.image_mean),
        "image_std": list(constants.image_std),
        "depth_scale_mm": constants.depth_scale_mm,
        "store": str(store.path),
        "store_created": store.header.created,
    }
    commit_path(partial, final, replace=True)
    # Readers check for meta.json without the lock: it must appear complete or not at all.
    with atomic_file(meta_path) as handle:
        handle.write(json.dumps(meta, indent=2) + "\n")
    progress_path.unlink(missing_ok=True)
