"""Uncertainty from an ensemble of checkpoints: the members' mean log10 E and a central
interval ``mean +- z * scale * std`` in decades. See docs/inference.md, "Uncertainty from
an ensemble".
"""

from __future__ import annotations

import glob
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from statistics import NormalDist
from typing import Any

import numpy as np

from tactile_compliance.data.inputs import INPUTS
from tactile_compliance.devices import DEFAULT_DEVICE
from tactile_compliance.inference.base import BaseEstimator, to_plain
from tactile_compliance.inference.estimator import ComplianceEstimator

__all__ = [
    "EnsembleEstimator",
    "EnsemblePrediction",
    "coverage",
    "ensemble_calibration",
    "fit_interval_scale",
    "interval_z",
]


def interval_z(level: float) -> float:
    """Normal quantile of a central interval holding ``level`` (0.8 -> 1.2816)."""
    if not 0 < level < 1:
        raise ValueError(f"interval level must be in (0, 1), got {level}")
    return NormalDist().inv_cdf(0.5 + level / 2)


def _spread(members_log10: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    m = np.asarray(members_log10, dtype=np.float64)
    mean = m.mean(axis=0)
    std = m.std(axis=0, ddof=1) if m.shape[0] > 1 else np.zeros_like(mean)
    return mean, std


def coverage(
    members_log10: np.ndarray, true_log10: np.ndarray, level: float = 0.8, scale: float = 1.0
) -> float:
    """Share of true values inside the ensemble's ``level`` interval (members x samples)."""
    mean, std = _spread(members_log10)
    half = interval_z(level) * scale * std
    return float(np.mean(np.abs(np.asarray(true_log10) - mean) <= half))


def fit_interval_scale(
    members_log10: np.ndarray, true_log10: np.ndarray, level: float = 0.8
) -> float:
    """Smallest ``scale`` whose interval holds a share ``level`` of the true values.

    Args:
        members_log10: (members, samples) predicted log10 E of each member.
        true_log10: (samples,) true log10 E.
        level: target coverage.
    """
    mean, std = _spread(members_log10)
    if np.asarray(members_log10).shape[0] < 2:
        raise ValueError("an interval needs at least two ensemble members")
    # Ratio of the error to the unit half-width; a member-free spread of 0 gives inf.
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.abs(np.asarray(true_log10) - mean) / (interval_z(level) * std)
    ratio = np.where(np.isnan(ratio), 0.0, ratio)
    return float(np.quantile(ratio, level, method="higher"))


@dataclass(frozen=True)
class EnsemblePrediction:
    """Ensemble estimate of one grasp (floats) or a batch (arrays over B).

    Attributes:
        modulus_pa: geometric mean of the members' moduli (10 ** mean log10), Pa.
        log10_modulus_pa: mean of the members' log10 E.
        std_decades: members' standard deviation of log10 E (decades, ddof=1).
        interval_pa: (low, high) in Pa of the central ``level`` interval.
        interval_log10: (low, high) in log10 Pa.
        half_width_decades: half-width of the interval in decades (= z * scale * std).
        level: nominal coverage of the interval.
        members_log10: (members,) or (members, B) predicted log10 E of every member.
    """

    modulus_pa: Any
    log10_modulus_pa: Any
    std_decades: Any
    interval_pa: tuple[Any, Any]
    interval_log10: tuple[Any, Any]
    half_width_decades: Any
    level: float
    members_log10: np.ndarray

    def contains(self, true_pa: Any) -> Any:
        """Whether the interval holds ``true_pa`` (bool, or a bool array for a batch)."""
        t = np.log10(np.asarray(true_pa, dtype=np.float64))
        inside = (t >= self.interval_log10[0]) & (t <= self.interval_log10[1])
        return bool(inside) if np.ndim(inside) == 0 else inside

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly dict."""
        return {
            "modulus_pa": to_plain(self.modulus_pa),
            "log10_modulus_pa": to_plain(self.log10_modulus_pa),
            "std_decades": to_plain(self.std_decades),
            "interval_pa": [to_plain(v) for v in self.interval_pa],
            "interval_log10": [to_plain(v) for v in self.interval_log10],
            "half_width_decades": to_plain(self.half_width_decades),
            "level": self.level,
            "members_log10": self.members_log10.tolist(),
        }


def _expand(paths: str | Path | Iterable[str | Path]) -> list[Path]:
    if isinstance(paths, (str, Path)):
        text = str(paths)
        found = sorted(glob.glob(text)) if any(c in text for c in "*?[") else [text]
        if not found:
            raise ValueError(f"no checkpoints match {text!r}")
        return [Path(p) for p in found]
    return [Path(p) for p in paths]


class EnsembleEstimator:
    """Several estimators combined in log10 space; they may differ in model, strategy and
    label range.

    Args:
        members: at least one estimator (two or more for a non-degenerate interval).
        level: nominal coverage of the interval (0.8 = 80 %).
        scale: interval inflation factor (1 = raw member spread).
    """

    def __init__(
        self, members: Sequence[BaseEstimator], *, level: float = 0.8, scale: float = 1.0
    ) -> None:
        if not members:
            raise ValueError("an ensemble needs at least one member")
        interval_z(level)
        if not scale > 0:
            raise ValueError(f"scale must be positive, got {scale}")
        self.members = list(members)
        self.level = float(level)
        self.scale = float(scale)

    @classmethod
    def from_checkpoints(
        cls,
        paths: str | Path | Iterable[str | Path],
        *,
        device: str = DEFAULT_DEVICE,
        level: float = 0.8,
        scale: float = 1.0,
        backbone_weights: str | Path | None = None,
    ) -> EnsembleEstimator:
        """Members from checkpoint files or run directories (a glob pattern works too,
        e.g. ``"runs/res_tf-ALL-*-seed*/"``); ``backbone_weights`` as in
        :meth:`ComplianceEstimator.from_checkpoint`."""
        members = [
            ComplianceEstimator.from_checkpoint(p, device=device, backbone_weights=backbone_weights)
            for p in _expand(paths)
        ]
        return cls(members, level=level, scale=scale)

    @property
    def required_inputs(self) -> tuple[str, ...]:
        """Union of the members' inputs, in table order (``data.inputs.INPUTS``)."""
        needed = {name for m in self.members for name in m.required_inputs}
        return tuple(n for n in INPUTS if n in needed)

    def __len__(self) -> int:
        return len(self.members)

    def members_log10(self, *inputs: Any, **options: Any) -> np.ndarray:
        """log10 E of every member: (members,) for one grasp, (members, B) for a batch
        (``BaseEstimator.predict``'s arguments)."""
        return np.stack(
            [
                np.asarray(m.predict(*inputs, **options).log10_modulus_pa, dtype=np.float64)
                for m in self.members
            ]
        )

    def combine(self, members_log10: np.ndarray, level: float | None = None) -> EnsemblePrediction:
        """Ensemble statistics from member predictions (members,) or (members, B)."""
        level = self.level if level is None else float(level)
        m = np.asarray(members_log10, dtype=np.float64)
        mean, std = _spread(m)
        half = interval_z(level) * self.scale * std
        lo, hi = mean - half, mean + half
        if m.ndim == 1:
            mean, std, half, lo, hi = (float(v) for v in (mean, std, half, lo, hi))
        return EnsemblePrediction(
            modulus_pa=10.0**mean,
            log10_modulus_pa=mean,
            std_decades=std,
            interval_pa=(10.0**lo, 10.0**hi),
            interval_log10=(lo, hi),
            half_width_decades=half,
            level=level,
            members_log10=m,
        )

    def predict(
        self,
        frames: Any = None,
        force: Any = None,
        width: Any = None,
        estimates: Any = None,
        *,
        level: float | None = None,
        channel_order: str = "RGB",
        batch_size: int = 64,
        **other_inputs: Any,
    ) -> EnsemblePrediction:
        """Mean and interval of the members for one grasp or a batch (same inputs as
        :meth:`ComplianceEstimator.predict`; each member validates what it uses, so
        members of different strategies share one call)."""
        members = self.members_log10(
            frames,
            force,
            width,
            estimates,
            channel_order=channel_order,
            batch_size=batch_size,
            **other_inputs,
        )
        return self.combine(members, level)


def ensemble_calibration(
    run_dirs: str | Path | Iterable[str | Path],
    *,
    store: str | Path | None = None,
    level: float = 0.8,
    device: str = DEFAULT_DEVICE,
    batch_size: int = 64,
) -> dict[str, Any]:
    """Coverage of the ensemble interval on the runs' test split, with the scale fitted on
    their validation split (the runs must share one split).

    Returns:
        ``n_members``, ``n_val``, ``n_test``, ``level``, ``coverage_raw`` (scale 1),
        ``scale`` (fitted on validation), ``coverage_calibrated`` (test, fitted scale),
        ``coverage_val_calibrated``, mean interval half-widths in decades, and the test
        MAE in decades / log10 accuracy of the ensemble mean and of the mean member.
    """
    from tactile_compliance.data.splits import Split
    from tactile_compliance.inference.sources import read_store

    dirs = [p if p.is_dir() else p.parent for p in _expand(run_dirs)]
    if len(dirs) < 2:
        raise ValueError("calibration needs at least two runs")
    splits = [Split.load(d / "split.json") for d in dirs]
    for d, s in zip(dirs[1:], splits[1:], strict=True):
        if not (
            np.array_equal(s.test_ids, splits[0].test_ids)
            and np.array_equal(s.val_ids, splits[0].val_ids)
        ):
            raise ValueError(
                f"{d} was trained on another split than {dirs[0]}: an ensemble interval can "
                f"only be calibrated on a split no member trained on (fix split.seed)"
            )
    ensemble = EnsembleEstimator.from_checkpoints(dirs, device=device, level=level)
    if store is None:
        store = ensemble.members[0].meta.get("config", {}).get("data", {}).get("store")
        if not store:
            raise ValueError("the runs' config names no store; pass store=")

    def members_and_truth(ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        needed = ensemble.required_inputs
        members, truth = [], []
        for start in range(0, len(ids), 256):  # bounded memory on full-size stores
            batch = read_store(store, ids[start : start + 256])
            given = batch.inputs(needed)
            members.append(ensemble.members_log10(**given, batch_size=batch_size))
            truth.append(np.log10(batch.rows["modulus_pa"].to_numpy(np.float64)))
        return np.concatenate(members, axis=1), np.concatenate(truth)

    val_members, val_true = members_and_truth(splits[0].val_ids)
    test_members, test_true = members_and_truth(splits[0].test_ids)
    scale = fit_interval_scale(val_members, val_true, level)
    z = interval_z(level)
    test_mean, test_std = _spread(test_members)
    member_errors = np.abs(test_members - test_true[None, :])
    return {
        "n_members": len(dirs),
        "n_val": int(val_true.size),
        "n_test": int(test_true.size),
        "level": level,
        "coverage_raw": coverage(test_members, test_true, level, 1.0),
        "coverage_val_raw": coverage(val_members, val_true, level, 1.0),
        "scale": scale,
        "coverage_calibrated": coverage(test_members, test_true, level, scale),
        "coverage_val_calibrated": coverage(val_members, val_true, level, scale),
        "half_width_raw_decades": float(np.mean(z * test_std)),
        "half_width_calibrated_decades": float(np.mean(z * scale * test_std)),
        "ensemble_mae_decades": float(np.mean(np.abs(test_mean - test_true))),
        "ensemble_log10_accuracy": float(np.mean(np.abs(test_mean - test_true) <= 1.0)),
        "member_mae_decades": float(member_errors.mean()),
        "member_log10_accuracy": float(np.mean(member_errors <= 1.0)),
        "runs": [str(d) for d in dirs],
    }
