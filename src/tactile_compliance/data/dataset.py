"""From a GraspStore to model-ready tensors: the one preprocessing path that training, the
feature cache, evaluation and inference all call, so a model sees data as it was trained on.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd
import torch
import torch.nn.functional as F
from torch.utils.data import (
    BatchSampler,
    DataLoader,
    Dataset,
    RandomSampler,
    SequentialSampler,
)

from tactile_compliance.data.inputs import InputStrategy
from tactile_compliance.data.normalisation import (
    MISSING_SCALAR,
    NormalisationConstants,
    normalise_depth,
    normalise_images,
    normalise_modulus,
)
from tactile_compliance.data.store import FRAME_DECODE_OFFSET, GraspStore


@dataclass(frozen=True)
class ModelInputs:
    """Normalised per-sample scalar inputs and labels (numpy float32), aligned with
    ``sample_ids``.

    Attributes:
        sample_ids: (N,) int64 store rows (may repeat after balancing).
        scalars: the strategy's scalar inputs by name, each (N, size), normalised by its
            ``data.inputs.INPUTS`` entry (force F / 60 N, width W / 0.08 m, ...).
        label: (N,) normalised log10 modulus.
    """

    sample_ids: np.ndarray
    scalars: dict[str, np.ndarray]
    label: np.ndarray


def model_inputs(
    samples: pd.DataFrame,
    sample_ids: Sequence[int] | np.ndarray,
    constants: NormalisationConstants,
    inputs: InputStrategy | str,
) -> ModelInputs:
    """Normalised scalar inputs of strategy ``inputs`` and labels of ``sample_ids`` (store
    rows); only the strategy's columns are read.

    Missing values (NaN, e.g. no estimates in the Shore-hardness data) become 0 after
    normalisation; the configuration forbids strategies that would use such inputs.
    """
    ids = np.asarray(sample_ids, dtype=np.int64)
    rows = samples.iloc[ids]
    scalars = {}
    for spec in InputStrategy.parse(inputs).scalars:
        assert spec.normalise is not None  # every scalar has one (data.inputs checks)
        values = spec.normalise(rows[list(spec.columns)].to_numpy(dtype=np.float64), constants)
        scalars[spec.name] = np.nan_to_num(np.asarray(values, dtype=np.float32), nan=MISSING_SCALAR)
    label = normalise_modulus(rows["modulus_pa"].to_numpy(dtype=np.float64), constants)
    return ModelInputs(ids, scalars, np.asarray(label, dtype=np.float32))


def prepare_frames(
    frames: torch.Tensor,
    constants: NormalisationConstants,
    image_size: tuple[int, int] | None = None,
    augmentation: torch.nn.Module | None = None,
) -> torch.Tensor:
    """Store frames -> model frames.

    Args:
        frames: (B, 3 frames, H, W, 3 channels), uint8 (store encoding, decoded as
            ``(u + 0.5) / 255``) or float in [0, 1].
        constants: image mean/std (per RGB channel).
        image_size: (height, width) in pixels the model expects; None keeps the size.
        augmentation: applied to [0, 1] frames before normalisation (training only).

    Returns:
        (B, 3 frames, 3 channels, h, w) float32, per-channel normalised.
    """
    if frames.dim() != 5 or frames.shape[1] != 3 or frames.shape[-1] != 3:
        raise ValueError(f"frames must have shape (B, 3, H, W, 3), got {tuple(frames.shape)}")
    x = frames.float()
    if frames.dtype == torch.uint8:
        # The store's decoding (frames_from_uint8), in place: a full-size batch is 100 MB.
        x.add_(FRAME_DECODE_OFFSET).div_(255.0)
    batch, n_frames, height, width, channels = x.shape
    x = x.permute(0, 1, 4, 2, 3)  # (B, T, C, H, W)
    if image_size is not None and (height, width) != tuple(image_size):
        x = F.interpolate(
            x.reshape(batch * n_frames, channels, height, width),
            size=tuple(image_size),
            mode="bilinear",
            align_corners=False,
            antialias=True,
        ).reshape(batch, n_frames, channels, *image_size)
    if augmentation is not None:
        x = augmentation(x)
    return normalise_images(x.contiguous(), constants, channel_axis=2)


def prepare_depth(
    depth_mm: torch.Tensor,
    constants: NormalisationConstants,
    image_size: tuple[int, int] | None = None,
) -> torch.Tensor:
    """Store depth maps -> model images, shaped like :func:`prepare_frames`' output.

    Args:
        depth_mm: (B, 3 frames, h, w) depth in mm; NaN (no depth) counts as 0 mm.
        image_size: (height, width) px the model expects; None keeps the size.

    Returns:
        (B, 3 frames, 3 channels, h, w) float32: ``depth / depth_scale_mm`` on every
        channel, so the image backbones take depth maps unchanged.
    """
    if depth_mm.dim() != 4 or depth_mm.shape[1] != 3:
        raise ValueError(f"depth maps must have shape (B, 3, h, w), got {tuple(depth_mm.shape)}")
    x = torch.nan_to_num(normalise_depth(depth_mm.float(), constants), nan=0.0)
    batch, n_frames, height, width = x.shape
    if image_size is not None and (height, width) != tuple(image_size):
        x = F.interpolate(
            x.reshape(batch * n_frames, 1, height, width),
            size=tuple(image_size),
            mode="bilinear",
            align_corners=False,
            antialias=True,
        ).reshape(batch, n_frames, *image_size)
    return x.unsqueeze(2).expand(-1, -1, 3, -1, -1).contiguous()


def prepare_images(
    name: str,
    images: torch.Tensor,
    constants: NormalisationConstants,
    image_size: tuple[int, int] | None = None,
    augmentation: torch.nn.Module | None = None,
) -> torch.Tensor:
    """The image input ``name`` (``"frames"`` or ``"depth"``, a ``data.inputs.INPUTS``
    image) as the backbone takes it, ``(B, 3, 3, h, w)``; ``augmentation`` (photometric
    and flips of RGB frames) applies to frames only."""
    if name == "frames":
        return prepare_frames(images, constants, image_size, augmentation)
    if name == "depth":
        return prepare_depth(images, constants, image_size)
    raise ValueError(f"{name!r} is no image input")


class GraspDataset(Dataset):
    """Samples of a store as dicts of tensors, with what strategy ``inputs`` takes and
    nothing else: ``sample_id``, ``label``, its scalar inputs, and its image input
    (``frames`` uint8 until the batch transform, or ``depth`` in mm) unless ``features``
    (a cached (N_store, 3, D) array of frozen-backbone features) stands in for it; then no
    image is read at all.
    """

    def __init__(
        self,
        store: GraspStore,
        sample_ids: Sequence[int] | np.ndarray,
        constants: NormalisationConstants,
        inputs: InputStrategy | str,
        features: np.ndarray | None = None,
    ) -> None:
        self.store = store
        self.strategy = InputStrategy.parse(inputs)
        self.inputs = model_inputs(store.samples, sample_ids, constants, self.strategy)
        self.features = features
        if self.strategy.uses("depth") and features is None:
            store.require_depth()

    def __len__(self) -> int:
        return len(self.inputs.sample_ids)

    def __getitem__(self, index: int | Sequence[int]) -> dict[str, torch.Tensor]:
        if not isinstance(index, (int, np.integer)):
            return self.batch(index)  # from batch_loader's sampler: a list of positions
        return {key: value[0] for key, value in self.batch([index]).items()}

    def batch(self, positions: Sequence[int] | np.ndarray) -> dict[str, torch.Tensor]:
        """The items at ``positions`` already stacked, read in one go (a dict per sample
        cost ~0.2 ms on cached features, about as long as a head's training step on it)."""
        pos = np.asarray(positions, dtype=np.int64)
        ids = self.inputs.sample_ids[pos]
        out = {"sample_id": torch.from_numpy(ids.copy())}
        out |= {name: torch.from_numpy(v[pos]) for name, v in self.inputs.scalars.items()}
        out["label"] = torch.from_numpy(self.inputs.label[pos])
        image = self.strategy.image
        if image is None:
            return out
        if self.features is not None:
            order = np.argsort(ids, kind="stable")  # sorted reads are sequential on disk
            features = np.empty((len(ids), *self.features.shape[1:]), dtype=np.float32)
            features[order] = self.features[ids[order]]
            out["features"] = torch.from_numpy(features)
        elif image.name == "frames":
            out["frames"] = torch.from_numpy(self.store.read_samples(ids))
        else:
            out["depth"] = torch.from_numpy(self.store.read_depth(ids))
        return out


def batch_loader(
    dataset: GraspDataset,
    batch_size: int,
    *,
    shuffle: bool = False,
    num_workers: int = 0,
) -> DataLoader:
    """A DataLoader yielding :meth:`GraspDataset.batch` batches (same order and batches
    as ``DataLoader(dataset, batch_size, shuffle)``, without per-sample collation)."""
    base = RandomSampler(dataset) if shuffle else SequentialSampler(dataset)
    return DataLoader(
        dataset,
        sampler=BatchSampler(base, batch_size=batch_size, drop_last=False),
        batch_size=None,  # the dataset returns whole batches
        num_workers=num_workers,
        persistent_workers=num_workers > 0,
    )
