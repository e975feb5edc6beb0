"""The SMAC side of a model's search space (declared by its class, ``hpo_space``).

Hyperparameter names are the dotted config keys they set (``training.lr``,
``model.hparams.num_layers``), so a SMAC configuration reads back as overrides.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

from tactile_compliance.config import ConfigError
from tactile_compliance.data.inputs import InputStrategy
from tactile_compliance.models import list_models, search_dimensions
from tactile_compliance.models.settings import SearchDimension

__all__ = ["canonical_inputs", "plain", "search_space", "trial_overrides", "trial_values"]

#: ``meta`` flag of a categorical whose choices are encoded as text (see :func:`_encode`).
_ENCODED = "encoded"


def canonical_inputs(inputs: str) -> str:
    """The paper's name of an input strategy; an unknown name is a ConfigError."""
    try:
        return InputStrategy.parse(inputs).value
    except ValueError as exc:
        raise ConfigError(str(exc)) from exc


def plain(value: Any) -> Any:
    """numpy scalars (what ConfigSpace returns) -> Python scalars."""
    return value.item() if hasattr(value, "item") else value


def _encode(value: Any) -> str:
    # ConfigSpace categoricals hold plain scalars, so layer lists and None travel as text:
    # "none" for None (what the published spaces call it), JSON for the rest.
    return "none" if value is None else json.dumps(value)


def _decode(text: str) -> Any:
    return None if text == "none" else json.loads(text)


def _categorical(dimension: SearchDimension) -> Any:
    from ConfigSpace import Categorical

    scalar = (int, float, str)
    if all(isinstance(c, scalar) and not isinstance(c, bool) for c in dimension.choices):
        return Categorical(dimension.key, list(dimension.choices), default=dimension.default)
    return Categorical(
        dimension.key,
        [_encode(choice) for choice in dimension.choices],
        default=_encode(dimension.default),
        meta={_ENCODED: True},
    )


def search_space(model: str, inputs: str = "ALL", seed: int = 0) -> Any:
    """The ConfigSpace space of categoricals that ``model`` declares for ``inputs``.

    One per ``models.search_dimensions(model, inputs)``; defaults are the paper settings.
    """
    from ConfigSpace import ConfigurationSpace

    name = model.strip().lower()
    if name not in list_models():
        raise ConfigError(f"unknown model {model!r}; tunable: {', '.join(list_models())}")
    dimensions = search_dimensions(name, canonical_inputs(inputs))
    space = ConfigurationSpace(seed=seed)
    space.add([_categorical(d) for d in dimensions])
    return space


def trial_values(config: Mapping[str, Any]) -> dict[str, Any]:
    """A SMAC configuration as ``{dotted key: config value}`` (sizes as lists, gamma None)."""
    space = getattr(config, "config_space", None)
    values: dict[str, Any] = {}
    for name, raw in dict(config).items():
        value = plain(raw)
        meta = space[name].meta if space is not None and name in space else None
        values[name] = _decode(value) if meta and meta.get(_ENCODED) else value
    return values


def trial_overrides(config: Mapping[str, Any]) -> list[str]:
    """A SMAC configuration as ``dotted.key=value`` overrides for ``config_from_dict``."""
    return [f"{k}={json.dumps(v)}" for k, v in trial_values(config).items()]
