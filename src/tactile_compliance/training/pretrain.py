"""Tactile pretraining: a backbone learns contact geometry from the store's depth maps.

Only the training objects of a split are read; the weights file carries its provenance.
See docs/models.md, "Tactile pretraining" (what is learned, data, resume, the file).
"""

from __future__ import annotations

import json
import math
import os
import time
import warnings
from collections.abc import Iterator, Mapping
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from tactile_compliance import __version__
from tactile_compliance.config import ExperimentConfig
from tactile_compliance.data.augment import GraspAugmentation
from tactile_compliance.data.dataset import prepare_frames
from tactile_compliance.data.normalisation import NormalisationConstants
from tactile_compliance.data.preprocess import filter_samples
from tactile_compliance.data.splits import (
    Split,
    check_split_store,
    make_split,
    make_split_from_config,
)
from tactile_compliance.data.store import SAMPLES_FILE, GraspStore
from tactile_compliance.devices import DEFAULT_DEVICE, resolve_device
from tactile_compliance.models import backbone_models, get_model_class
from tactile_compliance.models.backbones import (
    PRETRAIN_KEY,
    create_backbone,
    file_sha256,
    load_mapped,
)
from tactile_compliance.models.top10nn import TOP10_BACKBONE, Top10Encoder
from tactile_compliance.outputs import atomic_file, check_output_file
from tactile_compliance.progress import progress_bar
from tactile_compliance.runs.checkpoint import torch_write_errors
from tactile_compliance.runs.run_inputs import RunInputs

__all__ = [
    "CONTACT_THRESHOLD_MM",
    "PRETRAIN_BACKBONES",
    "DepthDecoder",
    "DepthPretrainNet",
    "PretrainResult",
    "PretrainSettings",
    "is_pretrained_weights_file",
    "pretrain",
    "pretrain_backbone",
]

#: A pixel is in contact where the gel is pressed in at least this deep (mm).
CONTACT_THRESHOLD_MM = 0.1
#: Backbone name -> the model that uses it (whose frame size pretraining uses by default);
#: read from the registered models' ``pretrain_backbones``.
PRETRAIN_BACKBONES: dict[str, str] = backbone_models()
#: Format marker of the provenance record (``PRETRAIN_KEY``) in a weights file.
PRETRAIN_FORMAT = "tactile-compliance-pretrained-backbone"
STATE_KIND = "tactile-compliance-pretrain-state"
STATE_SUFFIX = ".pretrain-state.pt"


@dataclass(frozen=True)
class PretrainSettings:
    """How to pretrain (data, split and augmentation settings come from the config).

    Args:
        backbone: one of :data:`PRETRAIN_BACKBONES`.
        epochs: maximum epochs.
        batch_size: samples per batch (each sample gives three frames).
        lr: AdamW learning rate.
        weight_decay: AdamW weight decay.
        patience: stop after this many epochs without a better validation loss (0: never).
        val_fraction: share of the training objects held out for early stopping.
        image_size: (H, W) px the frames are resized to; None: the size the backbone's
            model uses (VGG-LSTM 224x224, Res-Tf and Top10NN the store's frame size).
        mask_weight: weight of the contact-mask loss next to the depth loss.
        limit_batches: at most this many training batches per epoch (tests; None: all).
    """

    backbone: str
    epochs: int = 30
    batch_size: int = 16
    lr: float = 1e-3
    weight_decay: float = 1e-4
    patience: int = 4
    val_fraction: float = 0.2
    image_size: tuple[int, int] | None = None
    mask_weight: float = 1.0
    limit_batches: int | None = None

    def __post_init__(self) -> None:
        if self.backbone not in PRETRAIN_BACKBONES:
            raise ValueError(
                f"unknown backbone {self.backbone!r}; pretrain takes "
                f"{', '.join(PRETRAIN_BACKBONES)}"
            )
        for name in ("epochs", "batch_size"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.patience < 0:
            raise ValueError(f"patience must be >= 0, got {self.patience}")
        if not 0.0 < self.val_fraction < 1.0:
            raise ValueError(f"val_fraction must be in (0, 1), got {self.val_fraction}")
        if not self.lr > 0:
            raise ValueError(f"lr must be > 0, got {self.lr}")


@dataclass
class PretrainResult:
    """What :func:`pretrain` wrote: the weights file and its provenance record."""

    out: Path
    provenance: dict[str, Any]
    #: Sample ids the training and validation batches were drawn from.
    train_ids: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))
    val_ids: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))
    resumed_from_epoch: int = 0
    #: ``out`` already held a pretrained file and was returned as it is (no --overwrite).
    existing: bool = False


# ============================================================================ the networks
def pretrain_backbone(name: str) -> nn.Module:
    """A randomly initialised backbone ``(N, 3, H, W) -> (N, feature_dim)`` by name
    (:data:`PRETRAIN_BACKBONES`), with the parameter names its model loads."""
    if name == TOP10_BACKBONE:
        return Top10Encoder()
    if name not in PRETRAIN_BACKBONES:
        raise ValueError(
            f"unknown backbone {name!r}; pretrain takes {', '.join(PRETRAIN_BACKBONES)}"
        )
    return create_backbone(name)


class DepthDecoder(nn.Module):
    """Feature vector -> (depth, contact logit) maps of ``depth_size`` (h, w) px.

    Linear to a (width, h/8, w/8) grid, three (upsample x2, 3x3 conv, ReLU) stages
    halving the channels, a 1x1 convolution to two channels, and a bilinear resize to the
    exact size.
    """

    def __init__(self, feature_dim: int, depth_size: tuple[int, int], width: int = 64) -> None:
        super().__init__()
        self.depth_size = (int(depth_size[0]), int(depth_size[1]))
        self.grid = (math.ceil(self.depth_size[0] / 8), math.ceil(self.depth_size[1] / 8))
        self.width = int(width)
        self.project = nn.Sequential(
            nn.Linear(feature_dim, self.width * self.grid[0] * self.grid[1]), nn.ReLU()
        )
        layers: list[nn.Module] = []
        channels = self.width
        for _ in range(3):
            layers += [
                nn.Upsample(scale_factor=2, mode="bilinear", align_corners=False),
                nn.Conv2d(channels, channels // 2, 3, padding=1),
                nn.ReLU(),
            ]
            channels //= 2
        layers.append(nn.Conv2d(channels, 2, 1))
        self.upsample = nn.Sequential(*layers)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        """``(N, feature_dim) -> (N, 2, h, w)``: channel 0 depth (scaled), 1 contact logit."""
        grid = self.project(features).reshape(-1, self.width, *self.grid)
        out = self.upsample(grid)
        return F.interpolate(out, size=self.depth_size, mode="bilinear", align_corners=False)


class DepthPretrainNet(nn.Module):
    """Backbone + :class:`DepthDecoder`, and the pretraining loss."""

    def __init__(
        self,
        backbone: nn.Module,
        depth_size: tuple[int, int],
        depth_scale_mm: float,
        mask_weight: float = 1.0,
    ) -> None:
        super().__init__()
        self.backbone = backbone
        self.decoder = DepthDecoder(int(backbone.feature_dim), depth_size)
        self.depth_scale_mm = float(depth_scale_mm)
        self.mask_weight = float(mask_weight)

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        """``(N, 3, H, W)`` normalised frames -> ``(N, 2, h, w)`` maps."""
        return self.decoder(self.backbone(frames))

    def losses(self, frames: torch.Tensor, depth_mm: torch.Tensor) -> dict[str, torch.Tensor]:
        """``loss`` (what is minimised), ``depth_mse_mm2`` and ``mask_bce`` of a batch.

        Args:
            frames: ``(N, 3, H, W)`` normalised difference images.
            depth_mm: ``(N, h, w)`` their depth maps in mm. Not masked: a NaN target makes
                the loss NaN, so a sample without depth can never pass unnoticed.
        """
        out = self(frames)
        depth_mse = F.mse_loss(out[:, 0], depth_mm / self.depth_scale_mm)
        contact = (depth_mm >= CONTACT_THRESHOLD_MM).to(out.dtype)
        mask_bce = F.binary_cross_entropy_with_logits(out[:, 1], contact)
        return {
            "loss": depth_mse + self.mask_weight * mask_bce,
            "depth_mse_mm2": depth_mse.detach() * self.depth_scale_mm**2,
            "mask_bce": mask_bce.detach(),
        }


# ============================================================================ files
def is_pretrained_weights_file(path: Path) -> bool:
    """Whether ``path`` is a weights file written by :func:`pretrain` (safe to replace)."""
    loaded = load_mapped(path)
    record = loaded.get(PRETRAIN_KEY) if isinstance(loaded, Mapping) else None
    return isinstance(record, Mapping) and record.get("format") == PRETRAIN_FORMAT


def _is_state_file(path: Path) -> bool:
    loaded = load_mapped(path)
    return isinstance(loaded, Mapping) and loaded.get("kind") == STATE_KIND


def _set_aside_corrupt_state(path: Path) -> None:
    """Move a truncated torch archive at ``path`` (full disk, crash) to ``NAME.corrupt``
    with a warning, as ``train`` does with its checkpoints, so that the re-run starts
    afresh; any other file is left for ``check_output_file`` (it may be the user's)."""
    if not path.is_file():
        return
    try:
        _is_state_file(path)
        return  # readable: ours or not, the callers decide
    except Exception as err:  # truncated, not a zip, unpickling failed
        problem = (str(err).strip().splitlines() or [type(err).__name__])[0][:200]
    with open(path, "rb") as handle:
        head = handle.read(512)
    if not (head.startswith(b"PK\x03\x04") and b"data.pkl" in head):
        return  # no torch archive: not ours
    aside = path.with_name(path.name + ".corrupt")
    os.replace(path, aside)
    warnings.warn(
        f"{path} is corrupt ({problem}); moved it to {aside.name} and starting from epoch 0",
        stacklevel=3,
    )


# ============================================================================ data
def _split_of(
    store: GraspStore, cfg: ExperimentConfig, split_file: Path | None
) -> tuple[Split, dict[str, Any]]:
    """The split whose training objects pretraining may use, and how it was had."""
    if split_file is not None:
        split = Split.load(split_file)
        check_split_store(split, split_file, store, store.samples)
        record = {
            "file": str(Path(split_file).resolve()),
            "sha256": file_sha256(Path(split_file)),
            "condition": split.condition,
            "seed": split.seed,
        }
        return split, record
    # Exactly what `train` draws for this configuration (filters, then the one split).
    samples, _ = filter_samples(store.samples, cfg)
    if samples.empty:
        raise ValueError(f"no samples left after filtering {store.path}")
    split = make_split_from_config(samples, cfg)
    record = {
        "file": None,
        "sha256": None,
        "condition": split.condition,
        "grouping": split.grouping,
        "seed": split.seed,
        "test_fraction": split.test_fraction,
        "val_fraction": split.val_fraction,
    }
    return split, record


def _pretrain_parts(
    store: GraspStore, split: Split, val_fraction: float, seed: int
) -> tuple[np.ndarray, np.ndarray, int]:
    """(train ids, validation ids, samples dropped for lacking depth) among the split's
    training ids; validation = a share of its *objects* (``make_split``, unseen)."""
    ids = np.asarray(split.train_ids, dtype=np.int64)
    # Only the training ids' depth maps are read: a test sample is never touched.
    has_depth = np.isfinite(store.read_depth(ids)).all(axis=(1, 2, 3)) if len(ids) else ids
    kept = ids[has_depth.astype(bool)]
    if len(kept) == 0:
        raise ValueError(f"{store.path}: no training sample of the split has depth maps")
    rows = store.samples.iloc[kept]
    inner = make_split(
        rows, condition="unseen", seed=seed, test_fraction=0.0, val_fraction=val_fraction
    )
    return inner.train_ids, inner.val_ids, int(len(ids) - len(kept))


def _batches(
    store: GraspStore, ids: np.ndarray, batch_size: int
) -> Iterator[tuple[np.ndarray, torch.Tensor, torch.Tensor]]:
    """(sample ids, uint8 frames (B, 3, H, W, 3), depth mm (B, 3, h, w)) in ``ids`` order."""
    for start in range(0, len(ids), batch_size):
        chunk = ids[start : start + batch_size]
        frames = torch.from_numpy(store.read_samples(chunk))
        depth = torch.from_numpy(store.read_depth(chunk))
        yield chunk, frames, depth


def _flip(
    frames: torch.Tensor, depth: torch.Tensor, cfg: ExperimentConfig, generator: torch.Generator
) -> tuple[torch.Tensor, torch.Tensor]:
    """Random horizontal/vertical flips, the same for a sample's frames and depth maps
    (with the config's pipeline probability and flip probabilities; none when the
    config's augmentation is off)."""
    aug = cfg.augmentation
    if not aug.enabled:
        return frames, depth
    batch = frames.shape[0]
    applied = torch.rand(batch, generator=generator) < aug.probability
    hflip = applied & (torch.rand(batch, generator=generator) < aug.hflip)
    vflip = applied & (torch.rand(batch, generator=generator) < aug.vflip)
    frames, depth = frames.clone(), depth.clone()
    # frames (B, T, H, W, C): W is dim 3, H dim 2; depth (B, T, h, w): w dim 3, h dim 2.
    frames[hflip] = frames[hflip].flip(3)
    depth[hflip] = depth[hflip].flip(3)
    frames[vflip] = frames[vflip].flip(2)
    depth[vflip] = depth[vflip].flip(2)
    return frames, depth


def _model_frames(
    frames: torch.Tensor,
    constants: NormalisationConstants,
    image_size: tuple[int, int],
    augmentation: nn.Module | None,
) -> torch.Tensor:
    x = prepare_frames(frames, constants, image_size, augmentation)  # (B, 3, 3, h, w)
    return x.reshape(-1, *x.shape[2:])


# ============================================================================ pretrain
def _cpu_copy(module: nn.Module) -> dict[str, torch.Tensor]:
    """A copy of ``module``'s state dict on the CPU (what the weights file holds)."""
    return {k: v.detach().to("cpu", copy=True) for k, v in module.state_dict().items()}


def pretrain(
    cfg: ExperimentConfig,
    settings: PretrainSettings,
    out: str | Path,
    *,
    split_file: str | Path | None = None,
    progress: bool = True,
    overwrite: bool = False,
    device: str = DEFAULT_DEVICE,
) -> PretrainResult:
    """Pretrain ``settings.backbone`` on the depth maps of ``cfg.data.store``'s training
    objects and write its weights (+ provenance) to ``out``.

    Args:
        cfg: the configuration whose store, filters, split (condition, fractions; seed
            ``cfg.split.seed`` or ``cfg.seed``), augmentation and image normalisation
            apply: the same as the downstream ``train`` run's, so the pretraining sees
            only that run's training objects. ``cfg.seed`` also seeds the initialisation.
        settings: what and how long to train.
        out: the weights file to write (``.pt``).
        split_file: a saved split (``tactile-compliance split``, a run's ``split.json``)
            instead of drawing one from ``cfg``.
        device: ``auto`` (a CUDA GPU when torch sees one, else the CPU), ``cpu`` or
            ``cuda[:N]``.
        overwrite: retrain when ``out`` already holds a pretrained weights file.

    Returns:
        The written file and its provenance. An existing pretrained file at ``out`` is
        returned as it is unless ``overwrite``.

    Raises:
        OutputExistsError: ``out`` (or its state file) exists and is not this command's.
        StoreError: the store has no depth maps.
        ValueError: a bad split, or no training object with depth maps.
    """
    started = time.perf_counter()
    out = check_output_file(out, "pretrained backbone", is_pretrained_weights_file)
    state_path = out.with_name(out.name + STATE_SUFFIX)
    _set_aside_corrupt_state(state_path)
    check_output_file(state_path, "pretrain state", _is_state_file)
    if out.exists() and not overwrite:
        return PretrainResult(
            out=out, provenance=dict(load_mapped(out)[PRETRAIN_KEY]), existing=True
        )
    if cfg.data.store is None:
        raise ValueError("no store: pass STORE (data.store)")
    store = GraspStore.open(cfg.data.store)
    store.require_depth()
    assert store.depth_size is not None  # require_depth checked it (for type checkers)
    split, split_record = _split_of(store, cfg, Path(split_file) if split_file else None)
    train_ids, val_ids, no_depth = _pretrain_parts(store, split, settings.val_fraction, cfg.seed)
    model_class = get_model_class(PRETRAIN_BACKBONES[settings.backbone])
    run_inputs = RunInputs.resolve(cfg, store, model_class, image_size=settings.image_size)
    image_size = run_inputs.image_size
    minimum = int(getattr(pretrain_backbone(settings.backbone), "min_input_size", 1))
    if min(image_size) < minimum:
        raise ValueError(
            f"{settings.backbone} needs frames of at least {minimum}x{minimum} px, got "
            f"{image_size[0]}x{image_size[1]}: pass --size {max(image_size[0], minimum)}x"
            f"{max(image_size[1], minimum)} or larger"
        )
    constants = run_inputs.constants
    # What must match for a state file to be resumed.
    arguments = {
        "settings": {
            k: list(v) if isinstance(v, tuple) else v for k, v in asdict(settings).items()
        },
        "store": str(store.path.resolve()),
        "store_created": store.header.created,
        "split": split_record,
        "image_size": list(image_size),
        "seed": cfg.seed,
        "augmentation": cfg.augmentation.model_dump(),
        "image_mean": list(cfg.data.image_mean),
        "image_std": list(cfg.data.image_std),
    }

    # The depth scale: the training part's depth spread (recorded; a fixed unit per file).
    sample_depth = store.read_depth(train_ids[:: max(1, len(train_ids) // 256)])
    depth_scale_mm = float(np.nanstd(sample_depth)) or 1.0

    with torch.random.fork_rng():
        torch.manual_seed(cfg.seed)
        net = DepthPretrainNet(
            pretrain_backbone(settings.backbone),
            store.depth_size,
            depth_scale_mm,
            settings.mask_weight,
        )
    optimiser = torch.optim.AdamW(
        net.parameters(), lr=settings.lr, weight_decay=settings.weight_decay
    )
    generator = torch.Generator().manual_seed(cfg.seed)
    photometric = GraspAugmentation(
        probability=cfg.augmentation.probability if cfg.augmentation.enabled else 0.0,
        hflip=0.0,  # flips are drawn in _flip, for the frames and the depth maps alike
        vflip=0.0,
        brightness=cfg.augmentation.brightness,
        contrast=cfg.augmentation.contrast,
        saturation=cfg.augmentation.saturation,
        hue=cfg.augmentation.hue,
        noise_std=cfg.augmentation.noise_std,
        seed=cfg.seed + 1,
    )
    history: list[dict[str, float]] = []
    best_loss, best_epoch, bad_epochs = float("inf"), -1, 0
    device = str(resolve_device(device))
    net.to(device)
    best_state = _cpu_copy(net.backbone)
    first_epoch, seconds_before = 0, 0.0
    if state_path.exists():
        state = torch.load(state_path, map_location="cpu", weights_only=True)
        if state.get("arguments") == json.loads(json.dumps(arguments)):
            net.load_state_dict(state["net"])
            optimiser.load_state_dict(state["optimiser"])
            best_state = state["best_backbone"]
            best_loss, best_epoch = float(state["best_loss"]), int(state["best_epoch"])
            bad_epochs, first_epoch = int(state["bad_epochs"]), int(state["epochs_done"])
            history = list(state["history"])
            seconds_before = float(state["seconds"])
            generator.set_state(state["generator"])
            if photometric.generator is not None:
                photometric.generator.set_state(state["augmentation_generator"])
            torch.set_rng_state(state["torch_rng"])
    resumed_from = first_epoch
    batches_per_epoch = math.ceil(len(train_ids) / settings.batch_size)
    if settings.limit_batches:
        batches_per_epoch = min(batches_per_epoch, settings.limit_batches)
    stopped = first_epoch > 0 and settings.patience > 0 and bad_epochs >= settings.patience

    with progress_bar(
        f"Pretraining {settings.backbone}",
        total=settings.epochs * batches_per_epoch,
        enabled=progress,
        fields={"val": "-"},
        fields_format="val depth MSE {task.fields[val]} mm²",
    ) as bar:
        bar.update(completed=first_epoch * batches_per_epoch)
        for epoch in range(first_epoch, settings.epochs):
            if stopped:
                break
            net.train()
            photometric.train()
            order = train_ids[torch.randperm(len(train_ids), generator=generator).numpy()]
            sums = {"loss": 0.0, "depth_mse_mm2": 0.0, "mask_bce": 0.0}
            n_batches = 0
            for _, frames, depth in _batches(store, order, settings.batch_size):
                if n_batches >= batches_per_epoch:
                    break
                frames, depth = _flip(frames, depth, cfg, generator)
                x = _model_frames(frames.to(device), constants, image_size, photometric)
                losses = net.losses(x, depth.to(device).reshape(-1, *depth.shape[2:]))
                optimiser.zero_grad(set_to_none=True)
                losses["loss"].backward()
                optimiser.step()
                for key in sums:
                    sums[key] += float(losses[key].detach())
                n_batches += 1
                bar()
            val = _evaluate(net, store, val_ids, constants, image_size, settings.batch_size, device)
            row = {
                "epoch": epoch,
                **{f"train_{k}": v / max(1, n_batches) for k, v in sums.items()},
                **{f"val_{k}": v for k, v in val.items()},
            }
            history.append(row)
            bar.update(val=f"{val['depth_mse_mm2']:.4f}")
            if val["loss"] < best_loss:
                best_loss, best_epoch, bad_epochs = val["loss"], epoch, 0
                best_state = _cpu_copy(net.backbone)
            else:
                bad_epochs += 1
            stopped = settings.patience > 0 and bad_epochs >= settings.patience
            with atomic_file(state_path, "wb") as handle, torch_write_errors(state_path):
                torch.save(
                    {
                        "kind": STATE_KIND,
                        "arguments": json.loads(json.dumps(arguments)),
                        "net": net.state_dict(),
                        "optimiser": optimiser.state_dict(),
                        "best_backbone": best_state,
                        "best_loss": best_loss,
                        "best_epoch": best_epoch,
                        "bad_epochs": bad_epochs,
                        "epochs_done": epoch + 1,
                        "history": history,
                        "seconds": seconds_before + time.perf_counter() - started,
                        "generator": generator.get_state(),
                        "augmentation_generator": (
                            photometric.generator.get_state()
                            if photometric.generator is not None
                            else torch.empty(0, dtype=torch.uint8)
                        ),
                        "torch_rng": torch.get_rng_state(),
                    },
                    handle,
                )

    best_row = history[best_epoch] if 0 <= best_epoch < len(history) else {}
    provenance = {
        "format": PRETRAIN_FORMAT,
        "version": 1,
        "backbone": settings.backbone,
        "model": PRETRAIN_BACKBONES[settings.backbone],
        "store": str(store.path.resolve()),
        "store_created": store.header.created,
        "store_num_samples": len(store),
        "store_samples_sha256": file_sha256(store.path / SAMPLES_FILE),
        "split": split_record,
        "n_train_samples": len(train_ids),
        "n_val_samples": len(val_ids),
        "n_train_objects": int(store.samples.iloc[train_ids]["object"].nunique()),
        "n_val_objects": int(store.samples.iloc[val_ids]["object"].nunique()),
        "samples_without_depth": no_depth,
        "image_size": list(image_size),
        "depth_size": list(store.depth_size),
        "depth_scale_mm": depth_scale_mm,
        "contact_threshold_mm": CONTACT_THRESHOLD_MM,
        "image_mean": list(constants.image_mean),
        "image_std": list(constants.image_std),
        "settings": arguments["settings"],
        "seed": cfg.seed,
        "epochs": len(history),
        "best_epoch": best_epoch,
        "first_depth_loss_mm2": history[0]["val_depth_mse_mm2"] if history else None,
        "final_depth_loss_mm2": best_row.get("val_depth_mse_mm2"),
        "final_mask_bce": best_row.get("val_mask_bce"),
        "history": history,
        "seconds": round(seconds_before + time.perf_counter() - started, 2),
        "package_version": __version__,
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
    }
    with atomic_file(out, "wb") as handle, torch_write_errors(out):
        torch.save({"state_dict": best_state, PRETRAIN_KEY: provenance}, handle)
    state_path.unlink(missing_ok=True)
    return PretrainResult(
        out=out,
        provenance=provenance,
        train_ids=train_ids,
        val_ids=val_ids,
        resumed_from_epoch=resumed_from,
    )


@torch.no_grad()
def _evaluate(
    net: DepthPretrainNet,
    store: GraspStore,
    ids: np.ndarray,
    constants: NormalisationConstants,
    image_size: tuple[int, int],
    batch_size: int,
    device: str | torch.device,
) -> dict[str, float]:
    """Mean losses over ``ids`` (eval mode, no augmentation), weighted by batch size."""
    net.eval()
    sums = {"loss": 0.0, "depth_mse_mm2": 0.0, "mask_bce": 0.0}
    count = 0
    for chunk, frames, depth in _batches(store, ids, batch_size):
        x = _model_frames(frames.to(device), constants, image_size, None)
        losses = net.losses(x, depth.to(device).reshape(-1, *depth.shape[2:]))
        for key in sums:
            sums[key] += float(losses[key]) * len(chunk)
        count += len(chunk)
    return {key: value / max(1, count) for key, value in sums.items()}
