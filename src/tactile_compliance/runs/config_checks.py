"""A valid configuration checked against the data it will run on: frames large enough
for the model (before torch loads) and store columns that can feed the inputs. Torch-free,
like ``config``: the command line runs the first check before a model is built.
"""

from __future__ import annotations

from typing import Any

from tactile_compliance.config import ConfigError, ExperimentConfig
from tactile_compliance.data.store import StoreError, read_store_header
from tactile_compliance.models.frame_rules import (
    RECOMMENDED_FRAME_SIZE,
    min_frame_side,
    too_small_message,
)

__all__ = ["check_config_against_samples", "check_frame_size_early"]


def check_frame_size_early(cfg: ExperimentConfig) -> None:
    """Refuse, before torch and the store's frames load, frames smaller than a built-in
    model takes (``models.frame_rules.min_frame_side``): the size ``RunInputs.resolve``
    will take, ``data.image_size``, else the model's recommended size, else the store
    header's. A frame-free strategy, a model of a program's own, or a store whose header
    cannot be read is left to the run's own check (``training.train.check_frame_size``).

    Raises:
        ConfigError: one line naming the model, its minimum, the size and the fix.
    """
    minimum = min_frame_side(cfg.model.name)
    if minimum is None or cfg.strategy.image is None:
        return
    size = cfg.data.image_size or RECOMMENDED_FRAME_SIZE.get(cfg.model.name)
    origin = "data.image_size is"
    if size is None:
        if cfg.data.store is None:
            return
        try:
            size = read_store_header(cfg.data.store).image_size
        except (OSError, ValueError, StoreError):
            return  # the run opens the store and says what is wrong with it
        origin = "the store's frames are"
    height, width = (int(n) for n in size)
    if min(height, width) < minimum:
        raise ConfigError(too_small_message(cfg.model.name, minimum, origin, (height, width)))


def check_config_against_samples(
    cfg: ExperimentConfig, samples: Any, source: str | None = None
) -> None:
    """Raise ConfigError when the data cannot feed the configured inputs (their columns
    hold no data) or ``data.source`` (when not ``auto``) is not the store's ``source``."""
    if source is not None and cfg.data.source not in ("auto", source):
        raise ConfigError(f"data.source={cfg.data.source} but the store's source is {source!r}")
    for spec in cfg.strategy.scalars:
        empty = [c for c in spec.columns if c not in samples.columns or samples[c].isna().all()]
        if empty:
            raise ConfigError(
                f"inputs={cfg.inputs} needs {spec.name}, but column(s) {empty} are missing or "
                f"all NaN in this data (source {source or 'unknown'}); use inputs: Image"
            )
