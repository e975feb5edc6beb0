"""The sample filter: which samples of a GraspStore an experiment may use (eight switchable
rules, counted per rule in a :class:`FilterReport`), and why not the rest.

See docs/protocol.md, "1. Sample filter".
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from tactile_compliance.data.inputs import ANALYTICAL_INPUTS, INPUTS
from tactile_compliance.data.store import (
    DEPTH_COLUMNS,
    ESTIMATE_COLUMNS,
    FORCE_COLUMNS,
    WIDTH_COLUMNS,
)

__all__ = [
    "UNKNOWN_GROUND_TRUTH_OBJECTS",
    "FilterReport",
    "RuleResult",
    "filter_samples",
    "require_columns",
]

#: Objects whose ground-truth modulus is unknown; excluded by both prior codebases.
UNKNOWN_GROUND_TRUTH_OBJECTS: tuple[str, ...] = (
    "playdoh",
    "silly_puty",
    "blue_sponge_dry",
    "blue_sponge_wet",
    "apple",
    "orange",
    "strawberry",
    "ripe_banana",
    "unripe_banana",
    "lacrosse_ball",
    "baseball",
    "racquet_ball",
    "tennis_ball",
)

#: The paper drops the single Paper object (8 materials remain).
DEFAULT_EXCLUDED_MATERIALS: tuple[str, ...] = ("Paper",)

#: (first, last) columns of the per-frame signals whose trend the filter rules check. Not
#: the store's FORCE_COLUMNS etc., which list all three frames.
FORCE_TREND_COLUMNS = (FORCE_COLUMNS[0], FORCE_COLUMNS[-1])
WIDTH_TREND_COLUMNS = (WIDTH_COLUMNS[0], WIDTH_COLUMNS[-1])
#: Frame 0 has no contact, so its depth is 0: the depth trend starts at frame 1.
DEPTH_TREND_COLUMNS = (DEPTH_COLUMNS[1], DEPTH_COLUMNS[-1])
#: The finger whose depth (``depth.pkl``) judges rule 7 for the samples of both fingers,
#: unless the experiment uses only the other finger (the published code's rule).
DEPTH_REFERENCE_FINGER = "markerless"
#: Columns that identify one press (grasp and time shift) across the two fingers.
PRESS_KEY_COLUMNS = ("object", "grasp", "augmentation")


@dataclass(frozen=True)
class FilterRules:
    """The sample filter's rules and their defaults (the paper's); each can be switched off.

    ``config.FilterConfig`` is the validated configuration section of the same fields and
    takes its defaults from here; :func:`filter_samples` accepts either.
    """

    drop_missing_estimates: bool = True
    drop_no_force_increase: bool = True
    drop_no_width_decrease: bool = True
    drop_no_depth_increase: bool = True
    drop_single_sample_objects: bool = True
    exclude_objects: tuple[str, ...] = UNKNOWN_GROUND_TRUTH_OBJECTS
    exclude_materials: tuple[str, ...] = DEFAULT_EXCLUDED_MATERIALS


RULE_DESCRIPTIONS: dict[str, str] = {
    "fingers": "finger not in data.fingers",
    "exclude_objects": "object with unknown ground truth (exclusion list)",
    "exclude_materials": "excluded material",
    "missing_estimates": "missing / non-finite analytical estimate",
    "no_force_increase": "force did not increase (F[2] <= F[0])",
    "no_width_decrease": "width did not decrease (W[2] >= W[0])",
    "no_depth_increase": "gel depth did not increase (max depth[2] <= max depth[1]) on the "
    "markerless finger (both fingers' samples)",
    "single_sample_objects": "object left with a single sample",
}


@dataclass
class RuleResult:
    """Outcome of one filter rule.

    ``removed`` is None when the rule was disabled or not applicable.
    """

    name: str
    description: str
    enabled: bool
    applicable: bool
    removed: int | None
    remaining: int
    note: str = ""

    @property
    def status(self) -> str:
        """``applied`` | ``disabled`` | ``not applicable``."""
        if not self.enabled:
            return "disabled"
        return "applied" if self.applicable else "not applicable"


@dataclass
class FilterReport:
    """What the filter did: per rule, how many samples it removed (printable)."""

    n_input: int
    n_output: int
    rules: list[RuleResult] = field(default_factory=list)

    def removed_by(self, name: str) -> int:
        """Samples removed by rule ``name`` (0 when disabled or not applicable)."""
        return self.rule(name).removed or 0

    def rule(self, name: str) -> RuleResult:
        """The :class:`RuleResult` of rule ``name``."""
        for rule in self.rules:
            if rule.name == name:
                return rule
        raise KeyError(f"unknown rule {name!r}; rules: {[r.name for r in self.rules]}")

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly dict (for run directories and reports)."""
        return {
            "n_input": self.n_input,
            "n_output": self.n_output,
            "rules": [asdict(r) | {"status": r.status} for r in self.rules],
        }

    def __str__(self) -> str:
        lines = [f"Sample filter: {self.n_input} -> {self.n_output} samples"]
        lines.append(f"  {'rule':<22} {'removed':>8} {'remaining':>10}  status / note")
        for r in self.rules:
            removed = str(r.removed) if r.removed is not None else "-"
            note = r.status + (f"; {r.note}" if r.note else "")
            lines.append(f"  {r.name:<22} {removed:>8} {r.remaining:>10}  {note}")
        return "\n".join(lines)


def require_columns(samples: pd.DataFrame, columns: Iterable[str], what: str = "") -> None:
    """Raise ``ValueError`` naming every column of ``columns`` missing from ``samples``."""
    missing = [c for c in columns if c not in samples.columns]
    if missing:
        purpose = f" for {what}" if what else ""
        raise ValueError(
            f"samples table lacks column(s) {missing}{purpose}; has {list(samples.columns)}"
        )


def _usable_columns(samples: pd.DataFrame, columns: Sequence[str]) -> list[str]:
    """Columns that exist and hold at least one non-NaN value (the rule is applicable)."""
    return [c for c in columns if c in samples.columns and samples[c].notna().any()]


def _depth_trend(
    samples: pd.DataFrame, df: pd.DataFrame, fingers: Sequence[str] | None
) -> tuple[np.ndarray, np.ndarray, str]:
    """Max depth (mm) of frames 1 and 2 that judge each row of ``df`` in rule 7, and a note.

    As the published code (mfkuhlmann/youngs-modulus-estimation,
    ``src/dataset/k_fold_youngs_data_module.py``, ``prepare_data``): every sample of a press
    is judged on the markerless finger's depth, unless the marker finger is used alone. The
    markerless sibling is looked up in ``samples``, the unfiltered table, so one removed by
    the finger selection still counts; a sample without one (skipped at import) is judged on
    its own depth, and the note counts those.
    """
    first_col, last_col = DEPTH_TREND_COLUMNS
    own_first = df[first_col].to_numpy(dtype=float)
    own_last = df[last_col].to_numpy(dtype=float)
    key = list(PRESS_KEY_COLUMNS)
    if "finger" not in samples.columns or not set(key) <= set(samples.columns):
        return own_first, own_last, "each sample's own depth (no finger/grasp columns)"
    used = set(fingers) if fingers is not None else set(samples["finger"].astype(str))
    if DEPTH_REFERENCE_FINGER not in used:
        return own_first, own_last, f"each sample's own finger's depth ({sorted(used)} only)"
    reference = samples.loc[
        samples["finger"].astype(str) == DEPTH_REFERENCE_FINGER, [*key, first_col, last_col]
    ].drop_duplicates(key)  # one press has one markerless sample; be safe with copies
    # A left merge keeps df's row order, so the result aligns with df.
    merged = df[key].merge(reference, on=key, how="left", indicator=True)
    # A markerless row is its own reference (also in hand-made tables that repeat a key).
    own = (df["finger"].astype(str) == DEPTH_REFERENCE_FINGER).to_numpy()
    looked_up = ~own & (merged["_merge"] == "both").to_numpy()
    first = np.where(looked_up, merged[first_col].to_numpy(dtype=float), own_first)
    last = np.where(looked_up, merged[last_col].to_numpy(dtype=float), own_last)
    note = f"the {DEPTH_REFERENCE_FINGER} finger's depth judges both fingers' samples"
    alone = int((~own & ~looked_up).sum())
    if alone:
        note += f"; {alone} sample(s) without a {DEPTH_REFERENCE_FINGER} one: own depth"
    return first, last, note


def _resolve_cfg(cfg: Any) -> tuple[Any, list[str] | None, tuple[str, ...]]:
    """Accept FilterRules, a FilterConfig, an ExperimentConfig (its .filters, .data.fingers
    and the estimate columns its inputs take) or None (the default rules); the third
    element is the columns the missing-estimates rule judges."""
    if cfg is None:
        return FilterRules(), None, ESTIMATE_COLUMNS
    if hasattr(cfg, "filters"):
        fingers = getattr(getattr(cfg, "data", None), "fingers", None)
        columns = ESTIMATE_COLUMNS
        for name in ANALYTICAL_INPUTS - {"estimates"}:  # the others the strategy takes
            if cfg.strategy.uses(name):
                columns += INPUTS[name].columns
        return cfg.filters, (list(fingers) if fingers is not None else None), columns
    return cfg, None, ESTIMATE_COLUMNS


def filter_samples(
    samples: pd.DataFrame, cfg: Any = None, fingers: Sequence[str] | None = None
) -> tuple[pd.DataFrame, FilterReport]:
    """Apply the sample filter and report what each rule removed.

    The rules run in the order of docs/protocol.md, "1. Sample filter". A missing value
    (NaN) fails the force, width and depth rules (an unverifiable increase counts as
    none); a rule whose columns are absent or all NaN is not applicable, skipped and
    reported so. Exclusion lists match case-insensitively; the report says how many
    listed names were present.

    Args:
        samples: the GraspStore's ``samples`` table (or any subset of it).
        cfg: :class:`FilterRules`, a ``FilterConfig``, an ``ExperimentConfig`` (its ``filters`` and
            ``data.fingers`` are used, and a strategy that takes the rig-corrected estimates
            also drops grasps missing them) or None for the defaults.
        fingers: fingers to keep (overrides ``cfg.data.fingers``); None keeps all.

    Returns:
        The kept rows (original index and ``sample_id`` preserved) and a :class:`FilterReport`.
    """
    fcfg, cfg_fingers, estimate_columns = _resolve_cfg(cfg)
    if fingers is None:
        fingers = cfg_fingers
    require_columns(samples, ("sample_id", "object", "material"), "the sample filter")

    df = samples
    report = FilterReport(n_input=len(samples), n_output=len(samples))

    def record(name: str, enabled: bool, applicable: bool, keep: Any, note: str = "") -> None:
        nonlocal df
        if enabled and applicable:
            keep_arr = np.asarray(keep, dtype=bool)
            removed = int((~keep_arr).sum())
            df = df.loc[keep_arr]
        else:
            removed = None
        report.rules.append(
            RuleResult(name, RULE_DESCRIPTIONS[name], enabled, applicable, removed, len(df), note)
        )

    # 1. fingers ----------------------------------------------------------------------
    if fingers is not None and "finger" in df.columns:
        wanted = set(fingers)
        record("fingers", True, True, df["finger"].isin(wanted), f"kept {sorted(wanted)}")
    else:
        note = "all fingers kept" if fingers is None else "no finger column"
        record("fingers", fingers is not None, False, None, note)

    # 2./3. exclusion lists (case-insensitive) ----------------------------------------------
    for name, column, listed in (
        ("exclude_objects", "object", fcfg.exclude_objects),
        ("exclude_materials", "material", fcfg.exclude_materials),
    ):
        listed_lower = {str(v).lower() for v in listed}
        values = df[column].astype(str).str.lower()
        present = listed_lower & set(samples[column].astype(str).str.lower())
        note = f"{len(listed_lower)} listed, {len(present)} present in the data"
        record(name, bool(listed_lower), True, ~values.isin(listed_lower), note)

    # 4. missing estimates ------------------------------------------------------------------
    usable = _usable_columns(samples, estimate_columns)
    if usable:
        keep = np.isfinite(df[usable].to_numpy(dtype=float)).all(axis=1)
        record("missing_estimates", fcfg.drop_missing_estimates, True, keep, ", ".join(usable))
    else:
        record("missing_estimates", fcfg.drop_missing_estimates, False, None, "no estimates")

    # 5.-7. monotonicity rules (NaN fails the comparison: an unverifiable change is dropped)
    for name, enabled, columns, direction in (
        ("no_force_increase", fcfg.drop_no_force_increase, FORCE_TREND_COLUMNS, "increase"),
        ("no_width_decrease", fcfg.drop_no_width_decrease, WIDTH_TREND_COLUMNS, "decrease"),
        ("no_depth_increase", fcfg.drop_no_depth_increase, DEPTH_TREND_COLUMNS, "increase"),
    ):
        if len(_usable_columns(samples, columns)) == len(columns):
            note = ""
            if name == "no_depth_increase":
                first, last, note = _depth_trend(samples, df, fingers)
            else:
                first = df[columns[0]].to_numpy(dtype=float)
                last = df[columns[1]].to_numpy(dtype=float)
            keep = last > first if direction == "increase" else last < first
            record(name, enabled, True, keep, note)
        else:
            record(name, enabled, False, None, f"columns {list(columns)} missing or all NaN")

    # 8. objects left with a single sample (after every other rule) --------------------------
    counts = df.groupby("object", sort=False)["sample_id"].transform("size")
    record("single_sample_objects", fcfg.drop_single_sample_objects, True, counts > 1)

    report.n_output = len(df)
    return df.copy(), report
