"""The per-model paper settings and tuning search spaces, read from the model classes'
``default_training``, ``tuned_configs`` and ``hpo_space``: the one reader of that data.
See docs/models.md, "Paper settings and search spaces".
"""

from __future__ import annotations

import inspect
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

from tactile_compliance.data.inputs import InputStrategy, scalar_inputs
from tactile_compliance.models.registry import (
    get_model_class,
    model_hyperparameters,
    takes_any_hparam,
)

__all__ = [
    "DIM_CHOICES",
    "DROPOUT_CHOICES",
    "FROM_PAPER",
    "FWE_CHOICES",
    "POW2_32_512",
    "SCALAR_DIM_CHOICES",
    "SIZES_CHOICES",
    "TRAINING_SPACE",
    "SearchDimension",
    "paper_settings",
    "search_dimensions",
]

#: Config section of a model's constructor keyword arguments.
HPARAMS_PREFIX = "model.hparams."
_SCALAR_INPUTS = tuple(spec.name for spec in scalar_inputs())
_TUNED_SECTIONS = frozenset({"model", "training"})

# The value sets of the published search spaces (categorical, as in the published code).
LR_CHOICES = tuple(float(f"{i}e-{j}") for j in range(2, 7) for i in range(1, 10))
GAMMA_CHOICES = (None, *(round(0.95 + 0.005 * k, 3) for k in range(10)))
BATCH_CHOICES = (8, 16, 32, 64, 128)
DROPOUT_CHOICES = (0.0, 0.1, 0.2, 0.3, 0.4)
SIZES_CHOICES = ((32, 32, 16), (64, 64, 32), (128, 128, 64), (256, 256, 128), (512, 512, 256))
DIM_CHOICES = (128, 256, 512, 1024)
FWE_CHOICES = (8, 16, 32, 64, 128)
SCALAR_DIM_CHOICES = (8, 16, 32, 64, 128, 256)
POW2_32_512 = (32, 64, 128, 256, 512)


class _FromPaper:
    """Type of :data:`FROM_PAPER` (a readable sentinel: ``None`` is a real default)."""

    def __repr__(self) -> str:
        return "FROM_PAPER"


#: A :class:`SearchDimension` default meaning "the model's paper setting".
FROM_PAPER: Any = _FromPaper()


def _canonical(value: Any) -> Any:
    # Tuples and lists compare equal once both are JSON values.
    return json.loads(json.dumps(value))


def _magnitude(value: Any) -> float | None:
    """A number to measure distances between choices: the value, or a layer list's first
    (widest) size; None for anything else."""
    if isinstance(value, bool):
        return None
    if isinstance(value, (int, float)):
        return float(value)
    if isinstance(value, (list, tuple)) and value:
        return _magnitude(value[0])
    return None


@dataclass(frozen=True)
class SearchDimension:
    """One hyperparameter a tuner searches: the config key it sets, its choices, the scalar
    inputs it ``needs`` (empty: always searched) and where a search starts (``default``;
    :func:`search_dimensions` fills in :data:`FROM_PAPER`)."""

    key: str
    choices: tuple[Any, ...]
    needs: tuple[str, ...] = ()
    default: Any = FROM_PAPER

    def __post_init__(self) -> None:
        # Accept any sequences in declarations but store tuples (the class is hashable).
        object.__setattr__(self, "choices", tuple(self.choices))
        object.__setattr__(self, "needs", tuple(self.needs))
        if not self.choices:
            raise ValueError(f"search dimension {self.key!r} has no choices")
        unknown = sorted(set(self.needs) - set(_SCALAR_INPUTS))
        if unknown:
            raise ValueError(
                f"search dimension {self.key!r}: unknown input(s) {unknown} in needs; "
                f"valid: {', '.join(_SCALAR_INPUTS)}"
            )
        if self.default is not FROM_PAPER and not self.is_choice(self.default):
            raise ValueError(
                f"search dimension {self.key!r}: default {self.default!r} is no choice"
            )

    @classmethod
    def hparam(
        cls, name: str, choices: Sequence[Any], needs: Sequence[str] = ()
    ) -> SearchDimension:
        """A dimension of the model constructor's keyword argument ``name``."""
        return cls(HPARAMS_PREFIX + name, tuple(choices), tuple(needs))

    def applies_to(self, inputs: InputStrategy | str) -> bool:
        """Whether the dimension is searched for input strategy ``inputs``."""
        strategy = InputStrategy.parse(inputs)
        return not self.needs or bool(set(self.needs) & set(strategy.scalar_names))

    def is_choice(self, value: Any) -> bool:
        """Whether ``value`` is one of the choices (a list equals a tuple of the same sizes)."""
        target = _canonical(value)
        return any(_canonical(choice) == target for choice in self.choices)

    def nearest(self, value: Any) -> Any:
        """The choice equal to ``value``, else the closest one (log scale for positive
        numbers, layer lists by their first size), else the first choice: the paper's
        settings are not always on the published grid (lr 1.1e-4, batch 24)."""
        target = _canonical(value)
        for choice in self.choices:
            if _canonical(choice) == target:
                return choice
        size = _magnitude(value)
        sized = [(choice, m) for choice in self.choices if (m := _magnitude(choice)) is not None]
        if size is None or not sized:
            return self.choices[0]
        log_scale = size > 0 and all(m > 0 for _, m in sized)

        def distance(m: float) -> float:
            return abs(math.log(m / size)) if log_scale else abs(m - size)

        return min(sized, key=lambda item: distance(item[1]))[0]


#: The training settings every model's search space starts with.
TRAINING_SPACE: tuple[SearchDimension, ...] = (
    SearchDimension("training.lr", LR_CHOICES),
    SearchDimension("training.gamma", GAMMA_CHOICES),
    SearchDimension("training.batch_size", BATCH_CHOICES),
)


def _tuned(cls: type, strategy: InputStrategy) -> Mapping[str, Mapping[str, Any]]:
    """The class's ``tuned_configs`` entry of ``strategy`` (empty when it has none)."""
    for name, entry in getattr(cls, "tuned_configs", {}).items():
        if InputStrategy.parse(name) is not strategy:
            continue
        unknown = sorted(set(entry) - _TUNED_SECTIONS)
        if unknown:
            raise ValueError(
                f"{cls.__name__}.tuned_configs[{name!r}]: unknown section(s) {unknown}; "
                f"valid: {', '.join(sorted(_TUNED_SECTIONS))}"
            )
        return entry
    return {}


def paper_settings(model: str, inputs: InputStrategy | str) -> dict[str, Any]:
    """The paper's settings of registered ``model`` for ``inputs``, as dotted overrides:
    ``default_training`` as ``training.*``, overlaid with the strategy's ``tuned_configs``
    (``training.*`` and ``model.hparams.*``). A ValueError for an unknown model or input
    strategy."""
    cls = get_model_class(model)
    tuned = _tuned(cls, InputStrategy.parse(inputs))
    training = {**getattr(cls, "default_training", {}), **tuned.get("training", {})}
    settings = {f"training.{key}": _canonical(value) for key, value in training.items()}
    for key, value in tuned.get("model", {}).items():
        settings[HPARAMS_PREFIX + key] = _canonical(value)
    return settings


def search_dimensions(model: str, inputs: InputStrategy | str) -> list[SearchDimension]:
    """The search space that registered ``model`` declares (``hpo_space``) for ``inputs``,
    with the defaults filled in (docs/models.md, "Paper settings and search spaces");
    a dimension that ``needs`` scalar inputs is left out when the strategy uses none of them.

    Raises:
        ValueError: unknown model or strategy, or a declaration that names a keyword
            the constructor does not take, or one key twice.
    """
    cls = get_model_class(model)
    strategy = InputStrategy.parse(inputs)
    paper = paper_settings(model, strategy)
    constructor = model_hyperparameters(model)
    takes_any = takes_any_hparam(model)
    dimensions: list[SearchDimension] = []
    seen: set[str] = set()
    # A class without a declaration still tunes its training settings.
    for dimension in getattr(cls, "hpo_space", TRAINING_SPACE):
        hparam = dimension.key.removeprefix(HPARAMS_PREFIX)
        if dimension.key.startswith(HPARAMS_PREFIX) and hparam not in constructor and not takes_any:
            raise ValueError(
                f"{cls.__name__}.hpo_space: {hparam!r} is not a constructor hyperparameter of "
                f"{model!r}; valid: {', '.join(sorted(constructor))}"
            )
        if dimension.key in seen:
            raise ValueError(f"{cls.__name__}.hpo_space declares {dimension.key!r} twice")
        seen.add(dimension.key)
        if not dimension.applies_to(strategy):
            continue
        if dimension.default is FROM_PAPER:
            reference = paper.get(dimension.key, constructor.get(hparam, inspect.Parameter.empty))
            default = (
                dimension.choices[0]
                if reference is inspect.Parameter.empty
                else dimension.nearest(reference)
            )
            dimension = replace(dimension, default=default)
        dimensions.append(dimension)
    return dimensions
