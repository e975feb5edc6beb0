"""Train / validation / test splits (by object, grasp or sample, seeded, optionally
stratified), analysis subsets, and their persistence as sample ids in JSON.

See docs/protocol.md, "3. Splits".
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from tactile_compliance.data.preprocess import require_columns
from tactile_compliance.outputs import atomic_file, check_format_version, check_output_file
from tactile_compliance.physics.contact import DEFAULT_GEL_MODULUS_PA

__all__ = [
    "N_ROLLING_WINDOWS",
    "Split",
    "SplitSummary",
    "check_split_store",
    "grasp_keys",
    "make_split",
    "make_split_from_config",
    "rolling_windows",
    "select_subset",
    "store_metadata",
    "summarise_split",
]

#: Number of rolling windows (three decades each, from 1e3-1e6 to 1e9-1e12 Pa).
N_ROLLING_WINDOWS: int = 7

SPLIT_FORMAT = "tactile-compliance-split"
SPLIT_FORMAT_VERSION = 1
SPLIT_NAMES = ("train", "val", "test")


# ============================================================================ subsets
def rolling_windows() -> list[tuple[float, float]]:
    """The 7 rolling-window ranges ``(lo, hi)`` in Pa: 1e3-1e6, 1e4-1e7, ..., 1e9-1e12.

    A window holds the moduli in ``(lo, hi]``: above ``lo``, up to and including ``hi``.
    """
    return [(10.0 ** (3 + k), 10.0 ** (6 + k)) for k in range(N_ROLLING_WINDOWS)]


def _in_window(modulus_pa: pd.Series, window: tuple[float, float]) -> pd.Series:
    # (lo, hi] as in the published code (mfkuhlmann/youngs-modulus-estimation,
    # k_fold_youngs_data_module.py: 1e3 * 10**k < E <= 1e6 * 10**k). It matters: handbook
    # grades sit exactly on decades (1e10 Pa pine), and including both ends also put such
    # an object into the window that starts at its modulus (four windows, not three).
    lo, hi = window
    return (modulus_pa > lo) & (modulus_pa <= hi)


def select_subset(
    samples: pd.DataFrame,
    subset: int | str | None,
    seed: int = 0,
    sensor_modulus_pa: float = DEFAULT_GEL_MODULUS_PA,
) -> pd.DataFrame:
    """Rows of ``samples`` belonging to an analysis subset (applied before splitting).

    Args:
        samples: filtered samples table.
        subset: None / ``"none"`` (everything); an int 0-6 (rolling window: moduli in
            ``(lo, hi]``, :func:`rolling_windows`; undersampled so that all 7 windows have
            the size of the smallest one, seeded); a shape name
            (e.g. ``"Sphere"``); ``"soft"`` (modulus < ``sensor_modulus_pa``) or ``"hard"``
            (modulus >= ``sensor_modulus_pa``).
        seed: seed of the rolling-window undersampling.
        sensor_modulus_pa: soft/hard boundary (Pa), the gel's modulus by default.
    """
    require_columns(samples, ("sample_id", "modulus_pa"), "subset selection")
    if subset is None or (isinstance(subset, str) and subset.lower() == "none"):
        return samples
    if isinstance(subset, (int, np.integer)) and not isinstance(subset, bool):
        k = int(subset)
        if not 0 <= k < N_ROLLING_WINDOWS:
            raise ValueError(f"rolling window index must be 0-{N_ROLLING_WINDOWS - 1}, got {k}")
        sizes = [int(_in_window(samples["modulus_pa"], w).sum()) for w in rolling_windows()]
        n_equal = min(sizes)
        if n_equal == 0:
            empty = [i for i, n in enumerate(sizes) if n == 0]
            raise ValueError(
                f"rolling window(s) {empty} contain no samples (sizes {sizes}); the windows "
                "cannot be undersampled to a common size"
            )
        rows = samples.loc[_in_window(samples["modulus_pa"], rolling_windows()[k])]
        # Undersample by sample: every window then has exactly n_equal samples.
        rng = np.random.default_rng([seed, k])
        chosen = np.sort(rng.choice(len(rows), size=n_equal, replace=False))
        return rows.iloc[chosen]
    if not isinstance(subset, str):
        raise TypeError(f"subset must be None, an int or a str, got {type(subset).__name__}")
    key = subset.lower()
    if key == "soft":
        return samples.loc[samples["modulus_pa"] < sensor_modulus_pa]
    if key == "hard":
        return samples.loc[samples["modulus_pa"] >= sensor_modulus_pa]
    require_columns(samples, ("shape",), f"subset {subset!r}")
    mask = samples["shape"].astype(str).str.lower() == key
    if not mask.any():
        shapes = sorted(samples["shape"].astype(str).unique())
        raise ValueError(
            f"subset {subset!r} is neither none, a window index, soft, hard nor a shape "
            f"present in the data; shapes: {shapes}"
        )
    return samples.loc[mask]


# ============================================================================ Split
def is_split_file(path: Path) -> bool:
    """Whether ``path`` is a split written by :meth:`Split.save` (safe to replace)."""
    data = json.loads(path.read_text(encoding="utf-8"))
    return isinstance(data, dict) and data.get("format") == SPLIT_FORMAT


@dataclass
class Split:
    """Sample ids of train / validation / test plus how they were drawn."""

    train_ids: np.ndarray
    val_ids: np.ndarray
    test_ids: np.ndarray
    condition: str = "seen"
    grouping: str = "grasp"
    seed: int = 0
    test_fraction: float = 0.2
    val_fraction: float = 0.2
    stratify: bool = False
    subset: int | str | None = None
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name in SPLIT_NAMES:
            ids = np.sort(np.asarray(self.ids(name), dtype=np.int64).reshape(-1))
            setattr(self, f"{name}_ids", ids)
            if len(np.unique(ids)) != len(ids):
                raise ValueError(f"{name} ids contain duplicates")
        for a, b in (("train", "val"), ("train", "test"), ("val", "test")):
            both = np.intersect1d(self.ids(a), self.ids(b))
            if len(both):
                raise ValueError(f"{len(both)} sample id(s) in both {a} and {b}: {both[:5]}")

    def ids(self, name: str) -> np.ndarray:
        """Sample ids of split ``name`` (``train`` | ``val`` | ``test``)."""
        if name not in SPLIT_NAMES:
            raise KeyError(f"unknown split {name!r}; expected one of {SPLIT_NAMES}")
        return getattr(self, f"{name}_ids")

    @property
    def all_ids(self) -> np.ndarray:
        """Every sample id of the split (sorted)."""
        return np.sort(np.concatenate([self.train_ids, self.val_ids, self.test_ids]))

    def frames(self, samples: pd.DataFrame) -> dict[str, pd.DataFrame]:
        """Rows of ``samples`` per split name (raises when an id is absent from ``samples``)."""
        indexed = samples.set_index("sample_id", drop=False)
        out = {}
        for name in SPLIT_NAMES:
            ids = self.ids(name)
            missing = np.setdiff1d(ids, indexed.index.to_numpy())
            if len(missing):
                raise ValueError(
                    f"{len(missing)} {name} sample id(s) are not in the samples table "
                    f"(e.g. {missing[:5].tolist()}); wrong store or filter?"
                )
            out[name] = indexed.loc[ids].reset_index(drop=True)
        return out

    # ------------------------------------------------------------------ persistence
    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly dict: metadata first, then the id lists."""
        return {
            "format": SPLIT_FORMAT,
            "version": SPLIT_FORMAT_VERSION,
            "condition": self.condition,
            "grouping": self.grouping,
            "seed": self.seed,
            "test_fraction": self.test_fraction,
            "val_fraction": self.val_fraction,
            "stratify": self.stratify,
            "subset": self.subset,
            "counts": {name: len(self.ids(name)) for name in SPLIT_NAMES},
            "metadata": self.metadata,
            **{f"{name}_ids": self.ids(name).tolist() for name in SPLIT_NAMES},
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Split:
        """Inverse of :meth:`to_dict`; checks the format marker and the id lists."""
        if data.get("format") != SPLIT_FORMAT:
            raise ValueError(f"not a split file (format={data.get('format')!r})")
        check_format_version(data.get("version"), SPLIT_FORMAT_VERSION, "split file")
        missing = [f"{n}_ids" for n in SPLIT_NAMES if f"{n}_ids" not in data]
        if missing:
            raise ValueError(f"split file lacks {missing}")
        return cls(
            **{f"{name}_ids": data[f"{name}_ids"] for name in SPLIT_NAMES},
            condition=data.get("condition", "seen"),
            grouping=data.get("grouping", "grasp"),
            seed=int(data.get("seed", 0)),
            test_fraction=float(data.get("test_fraction", 0.2)),
            val_fraction=float(data.get("val_fraction", 0.2)),
            stratify=bool(data.get("stratify", False)),
            subset=data.get("subset"),
            metadata=dict(data.get("metadata") or {}),
        )

    def save(self, path: str | Path) -> Path:
        """Write the split as JSON (atomically: temp file + rename). Returns the path."""
        path = check_output_file(path, "split", is_split_file)
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_file(path) as handle:
            handle.write(json.dumps(self.to_dict(), indent=1) + "\n")
        return path

    @classmethod
    def load(cls, path: str | Path) -> Split:
        """Read a split written by :meth:`save`."""
        path = Path(path)
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except FileNotFoundError as exc:
            raise FileNotFoundError(f"{path}: no such split file") from exc
        except UnicodeDecodeError as exc:
            raise ValueError(f"{path}: not a split JSON (not a text file)") from exc
        except json.JSONDecodeError as exc:
            raise ValueError(f"{path}: not valid JSON ({exc})") from exc
        try:
            return cls.from_dict(data)
        except ValueError as exc:
            raise ValueError(f"{path}: {exc}") from exc

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Split):
            return NotImplemented
        return self.to_dict() == other.to_dict()


# ============================================================================ make_split
def grasp_keys(samples: pd.DataFrame) -> pd.Series:
    """One hashable key per sample identifying its grasp: ``"object/grasp"``."""
    require_columns(samples, ("object", "grasp"), "grasp grouping")
    return samples["object"].astype(str) + "/" + samples["grasp"].astype(str)


def _group_keys(samples: pd.DataFrame, condition: str, grouping: str) -> pd.Series:
    if condition == "unseen":
        require_columns(samples, ("object",), "the unseen condition")
        return samples["object"].astype(str)
    if grouping == "grasp":
        return grasp_keys(samples)
    return samples["sample_id"].astype(str)


def _visit_order(
    groups: np.ndarray, strata: np.ndarray | None, rng: np.random.Generator
) -> np.ndarray:
    """Seeded visiting order of ``groups`` (indices); interleaves strata when given."""
    n = len(groups)
    if strata is None:
        return rng.permutation(n)
    # Systematic sampling: within each stratum, shuffle and place the groups at evenly
    # spaced positions (rank + offset) / n_stratum in [0, 1) with a random offset per
    # stratum; sorting all groups by position makes every prefix proportional per stratum.
    position = np.empty(n)
    for stratum in np.unique(strata):
        members = np.flatnonzero(strata == stratum)
        members = members[rng.permutation(len(members))]
        position[members] = (np.arange(len(members)) + rng.random()) / len(members)
    tiebreak = rng.random(n)
    return np.lexsort((tiebreak, position))


def _take_prefix(order: np.ndarray, sizes: np.ndarray, target: float, at_least_one: bool) -> int:
    """Length of the prefix of ``order`` whose total size is closest to ``target``."""
    cum = np.concatenate([[0], np.cumsum(sizes[order])])
    k = int(np.argmin(np.abs(cum - target)))  # first closest prefix
    if at_least_one and k == 0 and len(order) > 1:
        k = 1
    return k


def make_split(
    samples: pd.DataFrame,
    condition: str = "seen",
    grouping: str = "grasp",
    seed: int = 0,
    test_fraction: float = 0.2,
    val_fraction: float = 0.2,
    stratify: bool = False,
    subset: int | str | None = None,
    metadata: dict[str, Any] | None = None,
) -> Split:
    """Split ``samples`` into train / validation / test sample ids.

    Deterministic: the same seed and the same table give the same split, whatever the
    order of its rows. No sample is in two parts, and a group (a grasp, or an object for
    ``unseen``) is never divided.

    Args:
        condition, grouping: docs/protocol.md, "3. Splits"; ``unseen`` always groups by
            object (the saved split records ``grouping="object"``).
        stratify: interleave the shape x material strata, so that every part mirrors
            their mix (otherwise the groups are shuffled as one).
        test_fraction: share of samples in test; val_fraction: share of the *remaining*
            samples in validation (paper 0.2 each).
        subset: recorded in the split's metadata (the caller applies :func:`select_subset`).
        metadata: extra JSON-serialisable information to store with the split.
    """
    if condition not in ("seen", "unseen"):
        raise ValueError(f"condition must be 'seen' or 'unseen', got {condition!r}")
    if grouping not in ("grasp", "per_sample", "object"):
        raise ValueError(f"grouping must be 'grasp' or 'per_sample', got {grouping!r}")
    if condition == "unseen" and grouping == "per_sample":
        raise ValueError("grouping='per_sample' only applies to condition='seen'")
    if condition == "seen" and grouping == "object":
        # A saved unseen split records grouping="object"; under seen it would mean unseen.
        raise ValueError("grouping='object' is the unseen condition; use condition='unseen'")
    for name, value in (("test_fraction", test_fraction), ("val_fraction", val_fraction)):
        if not (0.0 <= value < 1.0) or math.isnan(value):
            raise ValueError(f"{name} must be in [0, 1), got {value}")
    require_columns(samples, ("sample_id",), "splitting")
    if samples["sample_id"].duplicated().any():
        raise ValueError("samples table has duplicate sample_id values")

    keys = _group_keys(samples, condition, grouping).to_numpy()
    # Sorted unique keys: the split depends on the seed and the content, not the row order.
    groups, inverse = np.unique(keys, return_inverse=True)
    sizes = np.bincount(inverse, minlength=len(groups)).astype(float)
    n_needed = int(test_fraction > 0) + int(val_fraction > 0) + 1
    if len(groups) < n_needed:
        raise ValueError(
            f"{len(groups)} group(s) ({'objects' if condition == 'unseen' else grouping}) "
            f"cannot fill {n_needed} non-empty splits"
        )

    strata = None
    if stratify:
        require_columns(samples, ("shape", "material"), "stratification")
        labels = (samples["shape"].astype(str) + " x " + samples["material"].astype(str)).to_numpy()
        # A group's stratum is that of its first sample (a group is one object or part of one).
        _, first = np.unique(inverse, return_index=True)
        strata = labels[first]

    rng = np.random.default_rng(seed)
    total = sizes.sum()
    order = _visit_order(groups, strata, rng)
    n_test = _take_prefix(order, sizes, test_fraction * total, test_fraction > 0)
    # Leave a group for training and, when asked for, one for validation.
    n_test = min(n_test, len(groups) - 1 - int(val_fraction > 0))
    test_groups, rest = order[:n_test], order[n_test:]
    # Validation: a fresh (stratified) order over the remaining groups.
    rest_order = rest[_visit_order(groups[rest], None if strata is None else strata[rest], rng)]
    n_val = _take_prefix(rest_order, sizes, val_fraction * sizes[rest].sum(), val_fraction > 0)
    # Keep at least one group for training.
    n_val = min(n_val, len(rest_order) - 1)
    val_groups, train_groups = rest_order[:n_val], rest_order[n_val:]

    sample_ids = samples["sample_id"].to_numpy()

    def ids_of(group_idx: np.ndarray) -> np.ndarray:
        return sample_ids[np.isin(inverse, group_idx)]

    meta = {"n_samples": len(samples), "n_groups": len(groups)} | dict(metadata or {})
    return Split(
        train_ids=ids_of(train_groups),
        val_ids=ids_of(val_groups),
        test_ids=ids_of(test_groups),
        condition=condition,
        grouping="object" if condition == "unseen" else grouping,
        seed=seed,
        test_fraction=test_fraction,
        val_fraction=val_fraction,
        stratify=stratify,
        subset=subset,
        metadata=meta,
    )


def store_metadata(store: Any) -> dict[str, Any]:
    """What a split records of the store it was drawn from (a ``GraspStore``): its path,
    creation time and sample count; :func:`check_split_store` compares them."""
    return {
        "store": str(store.path),
        "store_created": store.header.created,
        "store_samples": int(store.header.num_samples),
    }


def check_split_store(split: Split, path: str | Path, store: Any, samples: pd.DataFrame) -> None:
    """Refuse a saved split (``path``) that was not drawn from ``store``, or whose ids are
    not among its filtered ``samples``.

    A split that records its store (:func:`store_metadata`) must name a store created at the
    same time with the same sample count; the ids must all be in ``samples["sample_id"]``.

    Raises:
        ValueError: one line naming the split, both stores and the fix (``split STORE --out``).
    """
    fix = f"draw one with `tactile-compliance split {store.path} --out FILE`"
    recorded = {k: split.metadata.get(k) for k in ("store", "store_created", "store_samples")}
    here = store_metadata(store)
    if recorded["store_created"] is not None and (
        recorded["store_created"] != here["store_created"]
        or recorded["store_samples"] != here["store_samples"]
    ):
        raise ValueError(
            f"{path}: a split of another store ({recorded['store']}, created "
            f"{recorded['store_created']}, {recorded['store_samples']} samples), not of "
            f"{store.path} (created {here['store_created']}, {here['store_samples']} samples); "
            f"{fix}"
        )
    missing = np.setdiff1d(split.all_ids, samples["sample_id"].to_numpy())
    if len(missing):
        raise ValueError(
            f"{path}: {len(missing)} of its sample ids are not among {store.path}'s samples "
            f"left by the filter (e.g. {missing[:3].tolist()}): drawn from another store or "
            f"with other filter rules; {fix}"
        )


def make_split_from_config(
    samples: pd.DataFrame, cfg: Any, metadata: dict[str, Any] | None = None
) -> Split:
    """Subset selection + :func:`make_split` as configured by an ``ExperimentConfig``.

    The split seed is ``cfg.split.seed`` when set, else the run's ``cfg.seed``;
    ``metadata`` (e.g. :func:`store_metadata`) is recorded with the split.
    """
    sc = cfg.split
    seed = sc.seed if sc.seed is not None else cfg.seed
    subset_rows = select_subset(samples, sc.subset, seed=seed)
    return make_split(
        subset_rows,
        condition=sc.condition,
        grouping=sc.grouping,
        seed=seed,
        test_fraction=sc.test_fraction,
        val_fraction=sc.val_fraction,
        stratify=sc.stratify,
        subset=sc.subset,
        metadata=metadata,
    )


# ============================================================================ summary
@dataclass
class SplitSummary:
    """What a split contains: counts, composition and leakage checks (printable)."""

    overview: pd.DataFrame
    by_material: pd.DataFrame
    by_shape: pd.DataFrame
    leakage: dict[str, int]
    split: Split

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly dict."""
        return {
            "overview": self.overview.reset_index().to_dict(orient="records"),
            "by_material": self.by_material.reset_index().to_dict(orient="records"),
            "by_shape": self.by_shape.reset_index().to_dict(orient="records"),
            "leakage": self.leakage,
        }

    def __str__(self) -> str:
        s = self.split
        head = (
            f"Split: condition={s.condition} grouping={s.grouping} seed={s.seed} "
            f"test={s.test_fraction:g} val={s.val_fraction:g} stratify={s.stratify} "
            f"subset={s.subset}"
        )
        fmt = {
            "modulus_min_pa": "{:.3g}".format,
            "modulus_max_pa": "{:.3g}".format,
            "fraction": "{:.3f}".format,
        }
        leak = ", ".join(f"{k}={v}" for k, v in self.leakage.items())
        if s.condition == "unseen":
            expect = "objects and grasps 0 (unseen)"
        elif s.grouping == "grasp":
            expect = "grasps 0 (seen, grasp-grouped; objects recur by design)"
        else:
            expect = "none (per_sample: grasps straddle splits, optimistic)"
        return "\n\n".join(
            [
                head,
                self.overview.to_string(formatters=fmt),
                "Samples per material:\n" + self.by_material.to_string(),
                "Samples per shape:\n" + self.by_shape.to_string(),
                f"Shared between splits: {leak}\nExpected: {expect}",
            ]
        )


def summarise_split(samples: pd.DataFrame, split: Split) -> SplitSummary:
    """Counts of samples, grasps and objects per split, composition and leakage checks."""
    frames = split.frames(samples)
    rows = {}
    total = sum(len(f) for f in frames.values())
    for name, df in frames.items():
        rows[name] = {
            "samples": len(df),
            "fraction": len(df) / total if total else float("nan"),
            "grasps": grasp_keys(df).nunique() if len(df) else 0,
            "objects": df["object"].nunique(),
            "modulus_min_pa": df["modulus_pa"].min() if len(df) else float("nan"),
            "modulus_max_pa": df["modulus_pa"].max() if len(df) else float("nan"),
        }
    overview = pd.DataFrame.from_dict(rows, orient="index")

    def composition(column: str) -> pd.DataFrame:
        if column not in samples.columns:
            return pd.DataFrame()
        table = (
            pd.DataFrame({name: df[column].value_counts() for name, df in frames.items()})
            .fillna(0)
            .astype(int)
        )
        return table.reindex(columns=list(SPLIT_NAMES), fill_value=0).sort_index()

    objects = {n: set(df["object"]) for n, df in frames.items()}
    grasps = {n: set(grasp_keys(df)) if len(df) else set() for n, df in frames.items()}
    leakage = {
        "objects_train_test": len(objects["train"] & objects["test"]),
        "objects_train_val": len(objects["train"] & objects["val"]),
        "grasps_train_test": len(grasps["train"] & grasps["test"]),
        "grasps_train_val": len(grasps["train"] & grasps["val"]),
    }
    return SplitSummary(
        overview=overview,
        by_material=composition("material"),
        by_shape=composition("shape"),
        leakage=leakage,
        split=split,
    )
