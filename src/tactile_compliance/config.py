"""Typed, validated experiment configuration (YAML presets + command-line overrides).

One :class:`ExperimentConfig` describes a run completely. Loading, overrides, ``base:``,
errors and every key: docs/protocol.md, section 7.
"""

from __future__ import annotations

import copy
import importlib.resources
import re
import warnings
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any, Literal, get_args, get_origin

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from tactile_compliance.data.inputs import ANALYTICAL_INPUTS, InputStrategy
from tactile_compliance.data.normalisation import NormalisationConstants
from tactile_compliance.data.plausibility import check_size
from tactile_compliance.data.preprocess import FilterRules
from tactile_compliance.data.splits import N_ROLLING_WINDOWS, Split
from tactile_compliance.devices import DEFAULT_DEVICE
from tactile_compliance.models import known_model_names
from tactile_compliance.outputs import atomic_file
from tactile_compliance.suggest import did_you_mean

__all__ = [
    "AugmentationConfig",
    "ConfigError",
    "DataConfig",
    "ExperimentConfig",
    "FilterConfig",
    "ModelConfig",
    "SamplingConfig",
    "SplitConfig",
    "TrainingConfig",
    "apply_overrides",
    "compose_yaml",
    "config_from_dict",
    "config_template",
    "config_to_dict",
    "list_presets",
    "load_config",
    "parse_yaml",
    "preset_path",
    "save_config",
    "write_yaml",
]

#: ``model.name: auto`` and ``training.lr: auto`` resolve to these, by whether the input
#: strategy has an image input: the paper's Top10NN at its published rate, or the
#: frame-free scalar MLP at the rate it was measured with (docs/models.md, "ScalarMLP").
AUTO = "auto"
AUTO_MODEL = {True: "top10nn", False: "scalar_mlp"}
AUTO_LR = {True: 3e-6, False: 1e-3}
_DEFAULT_NORM = NormalisationConstants()


class ConfigError(ValueError):
    """An experiment configuration is invalid; the message names the key(s) at fault."""


class _Section(BaseModel):
    # extra="forbid": unknown keys are errors; validate_assignment: edits in code are checked.
    model_config = ConfigDict(extra="forbid", validate_assignment=True)


# =========================================================================== sections
class DataConfig(_Section):
    """Which data and how labels/images are scaled."""

    store: str | None = Field(None, description="GraspStore directory (usually given on the CLI)")
    source: Literal["auto", "burgess", "synthetic", "yuan"] = Field(
        "auto", description="data source; auto = read from the store header at run time"
    )
    label_range_pa: tuple[float, float] = Field(
        (1e3, 1e12), description="label log10 min-max range (Pa); [1e3, 1e7] for Shore data"
    )
    image_size: tuple[int, int] | None = Field(
        None, description="(height, width) px to resize frames to; None keeps the store's size"
    )
    fingers: list[Literal["markerless", "markers"]] = Field(
        ["markerless", "markers"], description="sensor fingers whose samples are used"
    )
    image_mean: tuple[float, float, float] = _DEFAULT_NORM.image_mean
    image_std: tuple[float, float, float] = _DEFAULT_NORM.image_std

    @field_validator("label_range_pa")
    @classmethod
    def _range(cls, v: tuple[float, float]) -> tuple[float, float]:
        if not 0 < v[0] < v[1]:
            raise ValueError(f"must be [min, max] in Pa with 0 < min < max, got {list(v)}")
        return v

    @field_validator("image_size", mode="before")
    @classmethod
    def _size(cls, v: Any) -> Any:
        if isinstance(v, int) and not isinstance(v, bool):
            v = (v, v)  # a single number means a square image
        if v is not None and (
            not isinstance(v, (list, tuple))
            or len(v) != 2
            or not all(isinstance(n, int) and not isinstance(n, bool) and n > 0 for n in v)
        ):
            raise ValueError(f"must be null, a positive int or [height, width], got {v!r}")
        # The cap (data.plausibility.MAX_FRAME_SIDE_PX) is checked here, before a run
        # directory is claimed or a frame is resized.
        return v if v is None else check_size(v, "image_size")

    @field_validator("fingers")
    @classmethod
    def _fingers(cls, v: list[str]) -> list[str]:
        if not v:
            raise ValueError("at least one finger is needed")
        if len(set(v)) != len(v):
            raise ValueError(f"duplicate finger in {v}")
        return v

    @field_validator("image_std")
    @classmethod
    def _std(cls, v: tuple[float, float, float]) -> tuple[float, float, float]:
        if min(v) <= 0:
            raise ValueError("standard deviations must be positive")
        return v


_RULES = FilterRules()


class FilterConfig(_Section):
    """The sample filter (``data/preprocess.py``); each rule can be switched off.

    The defaults are ``data.preprocess.FilterRules``'s, the rules' one home."""

    drop_missing_estimates: bool = _RULES.drop_missing_estimates
    drop_no_force_increase: bool = _RULES.drop_no_force_increase
    drop_no_width_decrease: bool = _RULES.drop_no_width_decrease
    drop_no_depth_increase: bool = _RULES.drop_no_depth_increase
    drop_single_sample_objects: bool = _RULES.drop_single_sample_objects
    exclude_objects: list[str] = Field(default_factory=lambda: list(_RULES.exclude_objects))
    exclude_materials: list[str] = Field(default_factory=lambda: list(_RULES.exclude_materials))


class SplitConfig(_Section):
    """Split protocol (``data/splits.py``)."""

    condition: Literal["seen", "unseen"] = "seen"
    grouping: Literal["grasp", "per_sample"] = "grasp"
    test_fraction: float = Field(0.2, ge=0.0, lt=1.0)
    val_fraction: float = Field(0.2, ge=0.0, lt=1.0)
    stratify: bool = False
    subset: int | str | None = Field(
        None, description="none | rolling window 0-6 | shape name | soft | hard"
    )
    seed: int | None = Field(None, description="split seed; None = the run's seed")
    file: str | None = Field(
        None,
        description="a saved split (`split --out FILE`) used instead of drawing one; set "
        "with `train --split FILE` (config.use_split_file), which also takes the file's "
        "condition, grouping, seed, fractions and subset",
    )

    @field_validator("subset", mode="before")
    @classmethod
    def _subset(cls, v: Any) -> Any:
        if v is None:
            return None
        if isinstance(v, bool):
            raise ValueError(f"must be none, a window index 0-6, a shape, soft or hard; got {v}")
        if isinstance(v, str):
            s = v.strip()
            if s.lower() in ("", "none", "null"):
                return None
            if s.isdigit():
                v = int(s)
            elif s.lower() in ("soft", "hard"):
                return s.lower()
            else:
                return s  # a shape name; checked against the data when the subset is selected
        if isinstance(v, int):
            if not 0 <= v < N_ROLLING_WINDOWS:
                raise ValueError(f"rolling window index must be 0-{N_ROLLING_WINDOWS - 1}, got {v}")
            return v
        raise ValueError(
            f"must be none, a window index 0-6, a shape, soft or hard; got {type(v).__name__}"
        )


class SamplingConfig(_Section):
    """Random or balanced (oversampled) training / validation sets (``data/balance.py``)."""

    strategy: Literal["random", "balanced"] = "random"
    t_balance: float = Field(
        0.5, ge=0.0, le=1.0, description="bins are raised to int(t_balance * largest bin)"
    )
    n_bins: int = Field(9, ge=1)
    balance_validation: bool = Field(
        True, description="balance the validation set too (the paper does); test never"
    )


class AugmentationConfig(_Section):
    """Training-time augmentation (``data/augment.py``); never applied to val/test."""

    enabled: bool = True
    probability: float = Field(0.9, ge=0.0, le=1.0, description="per-sample pipeline probability")
    hflip: float = Field(0.5, ge=0.0, le=1.0)
    vflip: float = Field(0.5, ge=0.0, le=1.0)
    brightness: float = Field(0.4, ge=0.0)
    contrast: float = Field(0.4, ge=0.0)
    saturation: float = Field(0.5, ge=0.0)
    hue: float = Field(0.3, ge=0.0, le=0.5)
    noise_std: float = Field(15 / 255, ge=0.0, description="Gaussian noise sigma, image units")


class ModelConfig(_Section):
    """Which model and its hyperparameters (names as in ``models.registry``)."""

    name: str = Field(
        AUTO, description="a registered model; auto: top10nn, or scalar_mlp for frame-free inputs"
    )
    hparams: dict[str, Any] = Field(default_factory=dict)
    backbone_weights: str = Field(
        "none", description="none | imagenet | path to a state dict (sha256-checked)"
    )
    freeze_backbone: bool = False
    finetune: Literal["all", "last_block"] = Field(
        "all",
        description="without freeze_backbone: train the whole backbone (paper) or only its "
        "last block (e.g. ResNet layer4, VGG fc6/fc7)",
    )

    @field_validator("name")
    @classmethod
    def _name(cls, v: str) -> str:
        if not v.strip():
            raise ValueError("model name must not be empty")
        name = v.strip().lower()
        known = known_model_names()
        if name != AUTO and name not in known:  # before torch loads: a typo is one line
            raise ValueError(
                f"unknown model {v!r}{did_you_mean(name, known)}; models: {', '.join(known)}"
            )
        return name


class TrainingConfig(_Section):
    """Optimisation settings (paper: Adam, StepLR per epoch, early stopping on val N-MSE)."""

    max_epochs: int = Field(200, ge=1)
    patience: int = Field(30, ge=0, description="epochs without val N-MSE improvement")
    lr: float = Field(
        AUTO_LR[True], gt=0.0, description="Adam rate; auto: 3e-6, or 1e-3 for frame-free inputs"
    )
    batch_size: int = Field(32, ge=1)
    gamma: float | None = Field(None, gt=0.0, le=1.0, description="StepLR gamma; null = none")
    l2_weight: float = Field(5e-5, ge=0.0)
    estimate_dropout: float = Field(
        0.0,
        ge=0.0,
        lt=1.0,
        description="share of training grasps whose analytical estimates are hidden as "
        "missing, so the model also estimates grasps whose fits failed (NaN estimates)",
    )
    precision: Literal["32", "bf16-mixed"] = "32"
    compile: bool = False
    num_workers: int = Field(0, ge=0)
    device: str = DEFAULT_DEVICE
    tensorboard: bool = Field(False, description="also log to TensorBoard (needs tensorboard)")
    limit_batches: int | None = Field(
        None, ge=1, description="at most this many train/val batches per epoch (smoke runs)"
    )

    @field_validator("precision", mode="before")
    @classmethod
    def _precision(cls, v: Any) -> Any:
        # YAML reads `precision: 32` as an int.
        return str(v) if isinstance(v, int) and not isinstance(v, bool) else v

    @field_validator("device")
    @classmethod
    def _device(cls, v: str) -> str:
        if not re.fullmatch(r"auto|cpu|mps|cuda(:\d+)?", v):
            raise ValueError(f"must be auto, cpu, mps, cuda or cuda:N; got {v!r}")
        return v


# =========================================================================== top level
class ExperimentConfig(_Section):
    """A complete, validated experiment configuration."""

    data: DataConfig = Field(default_factory=DataConfig)
    filters: FilterConfig = Field(default_factory=FilterConfig)
    split: SplitConfig = Field(default_factory=SplitConfig)
    sampling: SamplingConfig = Field(default_factory=SamplingConfig)
    inputs: str = Field("ALL", description="input strategy: " + " | ".join(InputStrategy.names()))
    augmentation: AugmentationConfig = Field(default_factory=AugmentationConfig)
    model: ModelConfig = Field(default_factory=ModelConfig)
    training: TrainingConfig = Field(default_factory=TrainingConfig)
    seed: int = Field(0, ge=0)
    output_dir: str = "runs"

    @model_validator(mode="before")
    @classmethod
    def _resolve_auto(cls, data: Any) -> Any:
        # ``auto`` model and rate follow the strategy (AUTO_MODEL, AUTO_LR); resolved here,
        # once, so every reader of the config sees a concrete model name and rate.
        if not isinstance(data, dict):
            return data
        try:
            has_image = InputStrategy.parse(data.get("inputs", "ALL")).image is not None
        except ValueError:
            # The inputs field reports it; the autos take the frames' values meanwhile, so
            # the one mistake is the one line (not "lr: got 'auto'" after it).
            has_image = True
        data = dict(data)
        for section, key, table in (("model", "name", AUTO_MODEL), ("training", "lr", AUTO_LR)):
            values = data.get(section)
            if values is None or isinstance(values, dict):
                values = dict(values or {})
                value = values.get(key, AUTO)
                if isinstance(value, str) and value.strip().lower() == AUTO:
                    values[key] = table[has_image]
                data[section] = values
        return data

    @field_validator("inputs", mode="before")
    @classmethod
    def _inputs(cls, v: Any) -> Any:
        # Any capitalisation and _/- ("image_fw"), stored as the paper's name ("ImageFW").
        return InputStrategy.parse(v).value

    @model_validator(mode="after")
    def _combinations(self) -> ExperimentConfig:
        if self.data.source == "yuan" and self.strategy.input_names != ("frames",):
            raise ValueError(
                f"inputs={self.inputs} takes {', '.join(self.strategy.input_names)}, but "
                "data.source=yuan (Shore-hardness videos) has frames only; use inputs: Image"
            )
        image = self.strategy.image
        if self.model.freeze_backbone and image is None:
            raise ValueError(
                f"model.freeze_backbone caches image features, but inputs={self.inputs} "
                f"takes no images; set it to false"
            )
        if image is None and self.model.finetune != "all":
            raise ValueError(
                f"model.finetune={self.model.finetune} needs a backbone, but "
                f"inputs={self.inputs} takes no images; use finetune: all"
            )
        if self.training.estimate_dropout > 0 and not ANALYTICAL_INPUTS & set(
            self.strategy.input_names
        ):
            raise ValueError(
                f"training.estimate_dropout hides the analytical estimates, but "
                f"inputs={self.inputs} takes none; set it to 0"
            )
        if self.split.condition == "unseen" and self.split.grouping == "per_sample":
            raise ValueError(
                "split.grouping=per_sample only applies to split.condition=seen "
                "(unseen always splits by object)"
            )
        if self.augmentation.enabled and self.model.freeze_backbone:
            warnings.warn(
                "augmentation.enabled with model.freeze_backbone: frozen-backbone runs use "
                "cached image features, which cannot be augmented; augmentation will have "
                "no effect (set augmentation.enabled=false to silence this)",
                UserWarning,
                stacklevel=2,
            )
        return self

    # ------------------------------------------------------------------ derived values
    def normalisation_constants(self) -> NormalisationConstants:
        """The dataset's normalisation constants (label range and image statistics)."""
        return NormalisationConstants.from_label_range(
            self.data.label_range_pa, image_mean=self.data.image_mean, image_std=self.data.image_std
        )

    @property
    def strategy(self) -> InputStrategy:
        """The input strategy (its inputs: ``.inputs``, ``.image``, ``.scalars``)."""
        return InputStrategy.parse(self.inputs)


# =========================================================================== errors
def _submodel(path: Sequence[Any]) -> type[BaseModel] | None:
    """The section model at ``path`` (e.g. ("split",) -> SplitConfig), None if not a section."""
    model: type[BaseModel] = ExperimentConfig
    for part in path:
        field = model.model_fields.get(str(part))
        if field is None:
            return None
        ann = field.annotation
        if isinstance(ann, type) and issubclass(ann, BaseModel):
            model = ann
        else:
            return None
    return model


def _unknown_key_message(dotted: str, parent: Sequence[Any]) -> str:
    where = f" in '{'.'.join(map(str, parent))}'" if parent else ""
    model = _submodel(parent)
    valid = list(model.model_fields) if model is not None else []
    hint = did_you_mean(dotted.rpartition(".")[2], valid)
    return f"unknown key '{dotted}'{hint}; valid keys{where}: {', '.join(valid)}"


def _format_errors(exc: ValidationError, origin: str) -> ConfigError:
    lines = []
    for err in exc.errors():
        loc = list(err["loc"])
        dotted = ".".join(map(str, loc))
        msg = str(err["msg"]).removeprefix("Value error, ")
        if err["type"] == "extra_forbidden":
            lines.append(_unknown_key_message(dotted, loc[:-1]))
        elif not loc:
            lines.append(msg)
        else:
            given = err.get("input")
            shown = "" if isinstance(given, dict) or repr(given) in msg else f" (got {given!r})"
            lines.append(f"{dotted}: {msg}{shown}")
    head = f"invalid configuration ({origin})" if origin else "invalid configuration"
    if len(lines) == 1:  # one mistake, one line
        return ConfigError(f"{head}: {lines[0]}")
    return ConfigError(head + ":\n  " + "\n  ".join(lines))


# =========================================================================== YAML
class _Loader(yaml.SafeLoader):
    """SafeLoader that rejects duplicate keys and reads ``1e-4`` as a float (YAML 1.2 style)."""


def _construct_mapping(loader: _Loader, node: yaml.MappingNode, deep: bool = False) -> dict:
    loader.flatten_mapping(node)
    mapping: dict[Any, Any] = {}
    for key_node, value_node in node.value:
        key = loader.construct_object(key_node, deep=deep)
        if key in mapping:
            raise yaml.constructor.ConstructorError(
                None, None, f"duplicate key {key!r}", key_node.start_mark
            )
        mapping[key] = loader.construct_object(value_node, deep=deep)
    return mapping


_Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)
_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"),
)


def parse_yaml(text: str, origin: str) -> Any:
    """Parse the YAML of a config or experiment file (``origin`` names it in errors); the
    one YAML reader of configuration (:class:`_Loader`: a duplicate key would silently drop
    a setting)."""
    try:
        # _Loader derives from SafeLoader: no arbitrary Python objects are constructed.
        return yaml.load(text, Loader=_Loader)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{origin}: invalid YAML: {exc}") from exc


# =========================================================================== presets
def _preset_dir() -> Any:
    return importlib.resources.files("tactile_compliance") / "configs"


def yaml_names(directory: Any) -> list[str]:
    """Sorted names (without ``.yaml``) of the YAML files in a packaged ``directory``."""
    if not directory.is_dir():
        return []
    return sorted(p.name[: -len(".yaml")] for p in directory.iterdir() if p.name.endswith(".yaml"))


def list_presets() -> list[str]:
    """Names of the packaged presets (``tactile_compliance/configs/*.yaml``)."""
    return yaml_names(_preset_dir())


def split_reference(ref: str | Path, relative_to: Path | None) -> tuple[Path, str, bool]:
    """A config or experiment reference as the user wrote it: its path (relative ones
    resolved against ``relative_to``), its name without ``.yaml``, and whether it is a bare
    name (no directory part), which may name a packaged preset."""
    path = Path(ref)
    if relative_to is not None and not path.is_absolute():
        path = relative_to / path
    text = str(ref)
    stem = text[: -len(".yaml")] if text.endswith(".yaml") else text
    return path, stem, isinstance(ref, str) and "/" not in text and "\\" not in text


def preset_path(name: str) -> Any:
    """The packaged preset file ``name`` (a Traversable); ConfigError if there is none."""
    stem = name[: -len(".yaml")] if name.endswith(".yaml") else name
    candidate = _preset_dir() / f"{stem}.yaml"
    if not candidate.is_file():
        raise ConfigError(
            f"no config file or preset named {name!r}{did_you_mean(stem, list_presets())}; "
            f"presets: {', '.join(list_presets())}"
        )
    return candidate


def _read_source(
    ref: str | Path, relative_to: Path | None
) -> tuple[dict[str, Any], str, Path | None]:
    """Raw mapping of a config file or preset, its display name and its directory."""
    path, stem, is_bare_name = split_reference(ref, relative_to)
    is_preset = is_bare_name and (_preset_dir() / f"{stem}.yaml").is_file()
    if path.is_file():
        body, origin, directory = path.read_text(encoding="utf-8"), str(path), path.parent
    elif is_preset or (is_bare_name and not str(ref).endswith((".yaml", ".yml"))):
        # preset_path raises, naming the presets, for a name that is none of them.
        body = preset_path(stem).read_text(encoding="utf-8")
        origin, directory = f"preset {stem}", None
    else:
        raise ConfigError(
            f"config file {path} does not exist (presets: {', '.join(list_presets())})"
        )
    data = parse_yaml(body, origin)
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{origin}: the top level must be a mapping, got {type(data).__name__}")
    return data, origin, directory


def _deep_merge(base: Mapping[str, Any], update: Mapping[str, Any]) -> dict[str, Any]:
    out = copy.deepcopy(dict(base))
    for key, value in update.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = _deep_merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


#: Reads a reference (relative to a directory, or None): mapping, origin, its directory.
YamlReader = Callable[[str | Path, Path | None], tuple[dict[str, Any], str, Path | None]]
#: Puts a file's mapping over its parent's.
YamlMerge = Callable[[Mapping[str, Any], Mapping[str, Any]], dict[str, Any]]


def compose_yaml(
    ref: str | Path,
    read: YamlReader,
    merge: YamlMerge,
    key: str,
    what: str,
    relative_to: Path | None = None,
    stack: tuple[str, ...] = (),
) -> tuple[dict[str, Any], str]:
    """A YAML file composed over the parent it names under ``key``: the one composition.

    Config files name theirs with ``base:``, experiment files with ``extends:``; the
    parent is read relative to the child's directory, composed the same way first, and
    ``merge`` puts the child over it. ``what`` says what the key must name (for the
    error). Returns the mapping (without ``key``) and the origin of ``ref``.

    Raises:
        ConfigError: a circular chain, or a parent that is not a string.
    """
    data, origin, directory = read(ref, relative_to)
    if origin in stack:
        raise ConfigError(f"circular {key!r} chain: {' -> '.join((*stack, origin))}")
    parent = data.pop(key, None)
    if parent is None:
        return data, origin
    if not isinstance(parent, str):
        raise ConfigError(f"{origin}: {key!r} must be {what}, got {parent!r}")
    base, _ = compose_yaml(parent, read, merge, key, what, directory, (*stack, origin))
    return merge(base, data), origin


# =========================================================================== overrides
def _annotation_is_mapping(ann: Any) -> bool:
    return (
        ann is dict
        or get_origin(ann) is dict
        or (get_origin(ann) is not None and any(_annotation_is_mapping(a) for a in get_args(ann)))
    )


def _check_override_key(dotted: str) -> None:
    """Raise ConfigError unless ``dotted`` names a field (or lies inside a free mapping)."""
    parts = dotted.split(".")
    model: type[BaseModel] = ExperimentConfig
    for i, part in enumerate(parts):
        field = model.model_fields.get(part)
        if field is None:
            raise ConfigError(_unknown_key_message(dotted, parts[:i]))
        ann = field.annotation
        if isinstance(ann, type) and issubclass(ann, BaseModel):
            model = ann
        elif i == len(parts) - 1 or _annotation_is_mapping(ann):
            return  # a value, or a key inside a free mapping such as model.hparams
        else:
            raise ConfigError(
                f"'{'.'.join(parts[: i + 1])}' is a value, not a section; cannot set '{dotted}'"
            )


def _parse_override(item: str) -> tuple[str, Any]:
    if "=" not in item:
        raise ConfigError(f"override {item!r} must look like section.key=value")
    key, _, text = item.partition("=")
    key = key.strip()
    if not re.fullmatch(r"[A-Za-z_][\w-]*(\.[\w-]+)*", key):
        raise ConfigError(f"override {item!r}: {key!r} is not a dotted key")
    value = parse_yaml(text, f"override {item!r}") if text.strip() else None
    return key, value


def _set_dotted(data: dict[str, Any], dotted: str, value: Any) -> None:
    parts = dotted.split(".")
    node = data
    for part in parts[:-1]:
        if not isinstance(node.get(part), dict):
            node[part] = {}
        node = node[part]
    node[parts[-1]] = value


# =========================================================================== public API
def config_from_dict(
    data: Mapping[str, Any],
    overrides: Iterable[str] = (),
    origin: str = "",
    values: Mapping[str, Any] | None = None,
) -> ExperimentConfig:
    """Validate a raw mapping (+ ``values``, then overrides) into an :class:`ExperimentConfig`.

    ``values``: already parsed ``dotted.key -> value`` pairs (a command's options), set
    before the ``dotted.key=value`` overrides, which win."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"configuration must be a mapping, got {type(data).__name__}")
    overrides = list(overrides)
    raw = copy.deepcopy(dict(data))
    for key, value in (values or {}).items():
        _set_dotted(raw, key, value)
    for item in overrides:
        key, value = _parse_override(item)
        try:
            _check_override_key(key)
        except ConfigError as exc:
            raise ConfigError(f"override {item!r}: {exc}") from None
        _set_dotted(raw, key, value)
    if overrides:
        origin = f"{origin} + overrides" if origin else "overrides"
    if "base" in raw:
        raise ConfigError("'base' is only allowed at the top of a YAML file")
    try:
        return ExperimentConfig.model_validate(raw)
    except ValidationError as exc:
        raise _format_errors(exc, origin) from None


def load_config(
    path_or_preset_name: str | Path = "default",
    overrides: Iterable[str] = (),
    values: Mapping[str, Any] | None = None,
) -> ExperimentConfig:
    """Load a YAML file or packaged preset (``list_presets()``), set ``values`` (already
    parsed ``dotted.key -> value`` pairs, e.g. ``{"data.image_size": (224, 224)}``), apply
    ``dotted.key=value`` overrides (values parsed as YAML; they win), validate.

    Raises:
        ConfigError: (a ``ValueError``) for missing files, invalid YAML, unknown keys, wrong
            types or impossible combinations; the message names the dotted key(s).
    """
    raw, origin = compose_yaml(
        path_or_preset_name, _read_source, _deep_merge, "base", "a preset name or a path"
    )
    return config_from_dict(raw, overrides, origin, values)


def config_template(path_or_preset_name: str | Path = "default") -> dict[str, Any]:
    """The validated configuration as a dict to derive others from (a grid's cells), with
    ``model.name`` and ``training.lr`` left ``auto`` where the file leaves them so: each
    derived configuration resolves them for its own input strategy.

    Raises:
        ConfigError: as :func:`load_config`.
    """
    raw, _ = compose_yaml(
        path_or_preset_name, _read_source, _deep_merge, "base", "a preset name or a path"
    )
    data = config_to_dict(load_config(path_or_preset_name))
    for section, key in (("model", "name"), ("training", "lr")):
        value = (raw.get(section) or {}).get(key, AUTO)
        if isinstance(value, str) and value.strip().lower() == AUTO:
            data[section][key] = AUTO
    return data


def apply_overrides(cfg: ExperimentConfig, overrides: Iterable[str]) -> ExperimentConfig:
    """A new config equal to ``cfg`` with ``dotted.key=value`` overrides applied."""
    return config_from_dict(config_to_dict(cfg), overrides, "overrides")


def use_split_file(cfg: ExperimentConfig, path: str | Path) -> ExperimentConfig:
    """``cfg`` training on the saved split at ``path`` (``split.file``), its ``split``
    section describing that split (condition, grouping, seed, fractions, subset, as the
    file records them), so the run's name and ``config.yaml`` say what it was trained on.

    Raises:
        FileNotFoundError, ValueError: ``path`` is no split file (one line, naming it).
    """
    saved = Split.load(path)
    data = config_to_dict(cfg)
    data["split"] = {
        **data["split"],
        "condition": saved.condition,
        "grouping": saved.grouping,
        "seed": saved.seed,
        "test_fraction": saved.test_fraction,
        "val_fraction": saved.val_fraction,
        "stratify": saved.stratify,
        "subset": saved.subset,
        "file": str(Path(path).resolve()),
    }
    return config_from_dict(data, origin=str(path))


def config_to_dict(cfg: ExperimentConfig) -> dict[str, Any]:
    """Plain JSON/YAML-serialisable dict (tuples become lists); round-trips through YAML."""
    return cfg.model_dump(mode="json")


def write_yaml(path: str | Path, header: str, data: Mapping[str, Any]) -> Path:
    """Write ``header`` (comment lines) and ``data`` as YAML, atomically. Returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = header + yaml.safe_dump(dict(data), sort_keys=False, default_flow_style=None)
    with atomic_file(path) as handle:
        handle.write(text)
    return path


def save_config(cfg: ExperimentConfig, path: str | Path) -> Path:
    """Write the fully resolved configuration as YAML (atomically). Returns the path."""
    header = "# tactile-compliance experiment configuration (fully resolved)\n"
    return write_yaml(path, header, config_to_dict(cfg))
