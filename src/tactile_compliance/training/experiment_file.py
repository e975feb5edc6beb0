"""Experiment files: a small YAML format that expands into one validated config per cell.

The packaged ones live in ``tactile_compliance/configs/experiments``. See
docs/experiments.md, "Experiment files".
"""

from __future__ import annotations

import copy
import importlib.resources
import itertools
import json
import warnings
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from tactile_compliance.config import (
    ConfigError,
    ExperimentConfig,
    compose_yaml,
    config_from_dict,
    config_template,
    config_to_dict,
    list_presets,
    load_config,
    parse_yaml,
    split_reference,
    yaml_names,
)
from tactile_compliance.models import paper_settings
from tactile_compliance.runs.layout import config_hash, run_name
from tactile_compliance.suggest import did_you_mean

__all__ = [
    "Cell",
    "ExperimentSpec",
    "expand_experiment",
    "experiment_preset_descriptions",
    "list_experiment_presets",
    "load_experiment",
]

EXPERIMENTS_DIR = "experiments"
#: Keys of an experiment file; a YAML file with any of them (but output_dir) is an
#: experiment, not a config.
SPEC_KEYS = frozenset(
    {
        "description",
        "extends",
        "config",
        "set",
        "grid",
        "seeds",
        "paper_settings",
        "rules",
        "quick",
        "output_dir",
    }
)
_QUICK_KEYS = SPEC_KEYS - {"extends", "quick"}
_RULE_KEYS = frozenset({"when", "set", "include"})
DEFAULT_RUNS_DIR = "runs"


@dataclass(frozen=True)
class Rule:
    """Overrides applied to the cells whose values match ``when`` (all keys must match)."""

    when: dict[str, list[Any]]
    set: dict[str, Any]


@dataclass
class ExperimentSpec:
    """A parsed experiment file (``quick`` already applied when requested)."""

    name: str
    description: str
    config: str
    set: dict[str, Any] = field(default_factory=dict)
    grid: dict[str, list[Any]] = field(default_factory=dict)
    seeds: list[int] = field(default_factory=lambda: [0])
    rules: list[Rule] = field(default_factory=list)
    quick: bool = False
    origin: str = ""
    output_dir: str | None = None
    paper_settings: bool = False

    @property
    def is_plain_config(self) -> bool:
        """Whether the experiment only names a config (one cell, nothing changed)."""
        return not (self.grid or self.rules or self.set or self.paper_settings)

    @property
    def default_output_dir(self) -> Path:
        """``runs/NAME`` (``runs/NAME-quick`` for the quick variant) unless the file says."""
        if self.output_dir:
            return Path(self.output_dir)
        return Path(DEFAULT_RUNS_DIR) / (f"{self.name}-quick" if self.quick else self.name)

    def to_dict(self) -> dict[str, Any]:
        """The resolved experiment as plain data (saved next to the results)."""
        return {
            "name": self.name,
            "description": self.description,
            "quick": self.quick,
            "origin": self.origin,
            "config": self.config,
            "set": self.set,
            "grid": self.grid,
            "seeds": self.seeds,
            "paper_settings": self.paper_settings,
            "rules": [{"when": r.when, "set": r.set} for r in self.rules],
        }


@dataclass(frozen=True)
class Cell:
    """One run of a grid: its validated config, its key in the results store, its axes."""

    index: int
    key: str
    cfg: ExperimentConfig
    axes: dict[str, Any]

    @property
    def run_dir(self) -> Path:
        """Where ``train`` writes this cell (``cfg.output_dir / run_name(cfg)``)."""
        return Path(self.cfg.output_dir) / run_name(self.cfg)

    @property
    def label(self) -> str:
        """E.g. ``res_tf ALL seen random seed 3`` (``... seen per_sample ...`` for that split)."""
        cfg = self.cfg
        parts = [cfg.model.name, cfg.inputs, cfg.split.condition]
        if cfg.split.condition == "seen" and cfg.split.grouping == "per_sample":
            parts.append("per_sample")  # grasp grouping is the default and stays unsaid
        parts.append(cfg.sampling.strategy)
        if cfg.split.subset is not None:
            parts.append(f"subset {cfg.split.subset}")
        parts.append(f"seed {cfg.seed}")
        return " ".join(str(p) for p in parts)


# =========================================================================== presets
def _experiments_dir() -> Any:
    return importlib.resources.files("tactile_compliance") / "configs" / EXPERIMENTS_DIR


def list_experiment_presets() -> list[str]:
    """Names of the packaged experiment presets (each also has a ``--quick`` variant)."""
    return yaml_names(_experiments_dir())


def experiment_preset_descriptions(quick: bool = False) -> dict[str, str]:
    """``{name: description}`` of the packaged experiment presets (for ``presets``)."""
    return {
        name: load_experiment(name, quick=quick).description for name in list_experiment_presets()
    }


# =========================================================================== loading
def _locate(ref: str | Path, relative_to: Path | None) -> tuple[Any, str, Path | None, str]:
    """(file, origin, directory for relative paths, name) of an experiment reference."""
    path, stem, bare = split_reference(ref, relative_to)
    if bare and (_experiments_dir() / f"{stem}.yaml").is_file():
        return _experiments_dir() / f"{stem}.yaml", f"experiment preset {stem}", None, stem
    if path.is_file():
        return path, str(path), path.parent.resolve(), path.stem
    if bare and stem in list_presets():
        return None, f"config preset {stem}", None, stem
    presets = ", ".join(list_experiment_presets())
    hint = did_you_mean(stem, [*list_experiment_presets(), *list_presets()])
    raise ConfigError(
        f"no experiment file or preset named {str(ref)!r}{hint} (experiment presets: {presets})"
    )


def _as_dotted_mapping(value: Any, where: str) -> dict[str, Any]:
    if value is None:
        return {}
    if not isinstance(value, Mapping) or not all(isinstance(k, str) for k in value):
        raise ConfigError(f"{where} must be a mapping of dotted keys to values, got {value!r}")
    return dict(value)


def _as_list(value: Any) -> list[Any]:
    return list(value) if isinstance(value, (list, tuple)) else [value]


def _parse_seeds(value: Any, where: str) -> list[int]:
    if isinstance(value, bool):
        raise ConfigError(f"{where}: seeds must be a count or a list of ints, got {value!r}")
    if isinstance(value, int):
        if value < 1:
            raise ConfigError(f"{where}: seeds must be >= 1, got {value}")
        return list(range(value))
    if (
        isinstance(value, list)
        and value
        and all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in value)
    ):
        if len(set(value)) != len(value):
            raise ConfigError(f"{where}: duplicate seed in {value}")
        return list(value)
    raise ConfigError(f"{where}: seeds must be a count or a list of ints >= 0, got {value!r}")


def _merge_spec(base: Mapping[str, Any], update: Mapping[str, Any]) -> dict[str, Any]:
    """``update`` over ``base``: set/grid merged by key, rules appended, the rest replaced."""
    out = copy.deepcopy(dict(base))
    for key, value in update.items():
        if key in ("set", "grid") and isinstance(value, Mapping):
            out[key] = {**(out.get(key) or {}), **copy.deepcopy(dict(value))}
        elif key == "rules":
            out[key] = [*(out.get(key) or []), *copy.deepcopy(list(value or []))]
        elif (
            key == "quick" and isinstance(value, Mapping) and isinstance(out.get("quick"), Mapping)
        ):
            out[key] = _merge_spec(out["quick"], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def _absolutise(raw: Mapping[str, Any], directory: Path | None) -> dict[str, Any]:
    """Make the file-relative references of one file (config, include) absolute."""
    if directory is None:
        return dict(raw)

    def fix_rule(rule: Any) -> Any:
        if isinstance(rule, Mapping) and "include" in rule:
            return {**rule, "include": str(directory / str(rule["include"]))}
        return rule

    raw = dict(raw)
    config = raw.get("config")
    # A bare preset name stays a name; anything that exists next to the file is a path.
    if isinstance(config, str) and ("/" in config or (directory / config).is_file()):
        raw["config"] = str(directory / config)
    rules = raw.get("rules")
    raw["rules"] = [fix_rule(rule) for rule in rules] if isinstance(rules, list) else rules
    if isinstance(raw.get("quick"), Mapping):
        raw["quick"] = _absolutise(raw["quick"], directory)  # the same keys, one level down
    return raw


def _resolve_raw(ref: str | Path) -> tuple[dict[str, Any], str, str]:
    """Raw experiment mapping (``extends`` resolved), its origin and its name."""
    names: list[str] = []

    def read(ref: str | Path, relative_to: Path | None) -> tuple[dict[str, Any], str, Path | None]:
        data, origin, directory, name = _read_spec(ref, relative_to)
        names.append(name)
        return data, origin, directory

    data, origin = compose_yaml(ref, read, _merge_spec, "extends", "an experiment name or path")
    return data, origin, names[0]


def _read_spec(
    ref: str | Path, relative_to: Path | None
) -> tuple[dict[str, Any], str, Path | None, str]:
    """One experiment file's raw mapping (``extends`` not resolved), origin, directory, name."""
    file, origin, directory, name = _locate(ref, relative_to)
    if file is None:  # a bare config preset name, e.g. "default": one cell
        return {"config": str(ref)}, origin, directory, name
    data = parse_yaml(file.read_text(encoding="utf-8"), origin)
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise ConfigError(f"{origin}: the top level must be a mapping, got {type(data).__name__}")
    if not (SPEC_KEYS - {"output_dir"}) & set(data):  # output_dir: a key of both kinds
        # A plain config file (e.g. best.yaml from `tune`): one cell crossed with the seeds.
        return {"config": str(Path(file).resolve())}, origin, directory, name
    unknown = set(data) - SPEC_KEYS
    if unknown:
        raise ConfigError(
            f"{origin}: unknown key(s) {sorted(unknown)}; an experiment file has "
            f"{', '.join(sorted(SPEC_KEYS))} (config keys go under 'set' as dotted keys)"
        )
    return _absolutise(data, directory), origin, directory, name


def _parse_rule(raw: Any, where: str) -> Rule:
    if not isinstance(raw, Mapping) or not set(raw) <= _RULE_KEYS:
        raise ConfigError(f"{where} must be a mapping with keys when, set, include; got {raw!r}")
    when = _as_dotted_mapping(raw.get("when"), f"{where}.when")
    settings = _as_dotted_mapping(raw.get("set"), f"{where}.set")
    if "include" in raw:
        path = Path(str(raw["include"]))
        if not path.is_file():
            raise ConfigError(f"{where}.include: {path} does not exist")
        included = parse_yaml(path.read_text(encoding="utf-8"), str(path))
        settings = {**_as_dotted_mapping(included, f"{path}"), **settings}
    if not settings:
        raise ConfigError(f"{where} changes nothing (give 'set' or 'include')")
    return Rule(when={k: _as_list(v) for k, v in when.items()}, set=settings)


def load_experiment(ref: str | Path, *, quick: bool = False) -> ExperimentSpec:
    """Parse an experiment preset or file (or a plain config, as a one-cell experiment).

    Args:
        ref: a packaged experiment name (``list_experiment_presets()``), a path to an
            experiment YAML, a config preset name or a path to a config YAML.
        quick: apply the file's ``quick`` section (a ConfigError when it has none).
    """
    raw, origin, name = _resolve_raw(ref)
    quick_raw = raw.pop("quick", None)
    if quick:
        if quick_raw is None:
            raise ConfigError(f"{origin} has no 'quick' variant")
        if not isinstance(quick_raw, Mapping) or not set(quick_raw) <= _QUICK_KEYS:
            raise ConfigError(
                f"{origin}: 'quick' must be a mapping with keys {', '.join(sorted(_QUICK_KEYS))}"
            )
        raw = _merge_spec(raw, quick_raw)
    grid_raw = _as_dotted_mapping(raw.get("grid"), f"{origin}: grid")
    for axis in ("seed", "output_dir"):
        if axis in grid_raw:
            raise ConfigError(f"{origin}: '{axis}' cannot be a grid axis (use 'seeds' / --out)")
    grid = {key: _as_list(values) for key, values in grid_raw.items()}
    for key, values in grid.items():
        if not values:
            raise ConfigError(f"{origin}: grid axis {key!r} has no values")
    rules = [_parse_rule(r, f"{origin}: rules[{i}]") for i, r in enumerate(raw.get("rules") or [])]
    config = raw.get("config", "default")
    if not isinstance(config, str):
        raise ConfigError(f"{origin}: 'config' must be a preset name or a path, got {config!r}")
    seeds = raw.get("seeds")
    seeds = [int(load_config(config).seed)] if seeds is None else _parse_seeds(seeds, origin)
    output_dir = raw.get("output_dir")
    use_paper = raw.get("paper_settings", False)
    if not isinstance(use_paper, bool):
        raise ConfigError(f"{origin}: 'paper_settings' must be true or false, got {use_paper!r}")
    return ExperimentSpec(
        name=name,
        description=str(raw.get("description") or f"{name} ({origin})").strip(),
        config=config,
        set=_as_dotted_mapping(raw.get("set"), f"{origin}: set"),
        grid=grid,
        seeds=seeds,
        rules=rules,
        quick=quick,
        origin=origin,
        output_dir=str(output_dir) if output_dir is not None else None,
        paper_settings=use_paper,
    )


# =========================================================================== expansion
def _override(key: str, value: Any) -> str:
    # JSON is valid YAML, so config_from_dict parses the value back exactly (and checks the key).
    return f"{key}={json.dumps(value)}"


def _lookup(data: Mapping[str, Any], dotted: str) -> tuple[bool, Any]:
    node: Any = data
    for part in dotted.split("."):
        if not isinstance(node, Mapping) or part not in node:
            return False, None
        node = node[part]
    return True, node


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, str) and isinstance(b, str):
        return a.strip().lower() == b.strip().lower()
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, bool) or isinstance(b, bool):
        return a is b
    return a == b


def match_cell(values: Mapping[str, Any], when: Mapping[str, Sequence[Any]]) -> bool:
    """Whether a config dict matches every ``dotted.key: [allowed values]`` of ``when``."""
    for key, allowed in when.items():
        found, value = _lookup(values, key)
        if not found:
            raise ConfigError(f"'when' key {key!r} is not a configuration key")
        if not any(_same(value, option) for option in allowed):
            return False
    return True


def parse_where(items: Iterable[str]) -> dict[str, list[Any]]:
    """``["model.name=res_tf", "inputs=[Image, ALL]"]`` -> a ``when`` mapping."""
    when: dict[str, list[Any]] = {}
    for item in items:
        key, sep, text = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"filter {item!r} must look like key=value")
        value = yaml.safe_load(text) if text.strip() else None
        when.setdefault(key.strip(), []).extend(_as_list(value))
    return when


def expand_experiment(
    spec: ExperimentSpec,
    *,
    seeds: Sequence[int] | int | None = None,
    store: str | Path | None = None,
    overrides: Iterable[str] = (),
    where: Iterable[str] = (),
    output_dir: str | Path | None = None,
) -> list[Cell]:
    """The validated cells of an experiment, in grid order (seeds innermost).

    Args:
        spec: from :func:`load_experiment`.
        seeds: a count (seeds 0..n-1) or a list; default: the experiment's seeds.
        store: the GraspStore for every cell (``data.store``); default: the file's.
        overrides: ``dotted.key=value`` strings applied to every cell last.
        where: ``key=value`` filters; only matching cells are kept (values may be lists).
        output_dir: where run directories go; default ``spec.default_output_dir``.

    Paths (store, output directory) are made absolute so that workers started elsewhere
    (a remote Dask scheduler) write to the same place; cells that turn out identical
    (same config hash) are kept once.
    """
    if seeds is None:
        seed_list = list(spec.seeds)
    else:
        seed_list = _parse_seeds(seeds if isinstance(seeds, int) else list(seeds), "--seeds")
    out = Path(output_dir) if output_dir is not None else spec.default_output_dir
    base = config_template(spec.config)
    tail = list(overrides)
    if store is not None:
        tail.append(_override("data.store", str(store)))
    filters = parse_where(where)
    axes = list(spec.grid)
    linked = _linked_axes(spec.grid, base, spec.origin)
    cells: list[Cell] = []
    seen: set[str] = set()
    duplicates = 0
    for combo in itertools.product(*(spec.grid[a] for a in axes)):
        for seed in seed_list:
            values: dict[str, Any] = {}
            for axis, value in zip(axes, combo, strict=True):
                values.update(value if axis in linked else {axis: value})
            where_text = ", ".join(f"{k}={v}" for k, v in {**values, "seed": seed}.items())
            origin = f"{spec.origin}, cell {where_text}"
            head = [
                *(_override(k, v) for k, v in spec.set.items()),
                *(_override(k, v) for k, v in values.items()),
                _override("seed", seed),
            ]
            with warnings.catch_warnings():
                # The first pass only decides which rules match; warnings come once, below.
                warnings.simplefilter("ignore")
                before_rules = config_to_dict(config_from_dict(base, head, origin))
            paper = _paper_overrides(before_rules, origin) if spec.paper_settings else []
            matched = [
                _override(k, v)
                for r in spec.rules
                if match_cell(before_rules, r.when)
                for k, v in r.set.items()
            ]
            cfg = config_from_dict(base, [*head, *paper, *matched, *tail], origin)
            cfg = _absolute_paths(cfg, out)
            if filters and not match_cell(config_to_dict(cfg), filters):
                continue
            key = config_hash(cfg)
            if key in seen:
                duplicates += 1
                continue
            seen.add(key)
            cells.append(Cell(len(cells), key, cfg, {**values, "seed": seed}))
    if duplicates:
        warnings.warn(
            f"{duplicates} cell(s) of {spec.name} duplicate others (same configuration) and "
            "run once",
            UserWarning,
            stacklevel=2,
        )
    return cells


def _overlap(a: str, b: str) -> bool:
    """Whether two dotted keys set the same value (equal, or one inside the other)."""
    return a == b or a.startswith(f"{b}.") or b.startswith(f"{a}.")


def _linked_axes(
    grid: Mapping[str, Sequence[Any]], base: Mapping[str, Any], origin: str
) -> set[str]:
    """The grid's linked axes (names that are not config keys), validated.

    A linked axis lists mappings of dotted keys; every key any axis sets must be set by
    that axis alone, so the order of the axes can never decide a cell's value.
    """
    linked: set[str] = set()
    owners: dict[str, str] = {}
    for axis, values in grid.items():
        if _lookup(base, axis)[0] or not any(isinstance(v, Mapping) for v in values):
            # A config key (model.hparams.* included): validated with each cell, as before.
            keys = [axis]
        else:
            if not all(isinstance(v, Mapping) and v for v in values):
                raise ConfigError(
                    f"{origin}: grid axis {axis!r} is not a configuration key, so it is a "
                    "linked axis and every value must be a non-empty mapping of dotted keys, "
                    "e.g. objects: [{split.condition: seen, split.grouping: grasp}, "
                    f"{{split.condition: unseen}}]; got {list(values)!r}"
                )
            for value in values:
                _as_dotted_mapping(value, f"{origin}: grid axis {axis!r}")
            linked.add(axis)
            keys = list(dict.fromkeys(k for v in values for k in v))
        for key in keys:
            for other, owner in owners.items():
                if owner != axis and _overlap(key, other):
                    raise ConfigError(
                        f"{origin}: grid axes {owner!r} and {axis!r} both set {key!r}; "
                        f"change the values of {owner!r} instead (e.g. with 'extends', "
                        "give the whole axis again)"
                    )
            owners[key] = axis
    return linked


def _paper_overrides(values: Mapping[str, Any], origin: str) -> list[str]:
    """The paper settings of a cell's model and input strategy, as overrides."""
    try:
        settings = paper_settings(values["model"]["name"], values["inputs"])
    except ValueError as exc:  # an unregistered model: a config error of this cell
        raise ConfigError(f"{origin}: paper_settings: {exc}") from None
    return [_override(k, v) for k, v in settings.items()]


def _absolute_paths(cfg: ExperimentConfig, out: Path) -> ExperimentConfig:
    data = config_to_dict(cfg)
    data["output_dir"] = str(out.expanduser().resolve())
    if data["data"].get("store"):
        data["data"]["store"] = str(Path(data["data"]["store"]).expanduser().resolve())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # already warned when the cell was first validated
        return ExperimentConfig.model_validate(data)
