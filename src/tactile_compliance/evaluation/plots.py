"""Figures of the report (PNG), drawn headless on :class:`matplotlib.figure.Figure`.

Not through ``pyplot``: importing this module never switches a notebook's backend, and
no global figure registry leaks memory across a long report.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.artist import Artist
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from tactile_compliance.data.normalisation import NormalisationConstants, normalise_modulus
from tactile_compliance.outputs import atomic_file
from tactile_compliance.physics.contact import DEFAULT_GEL_MODULUS_PA

__all__ = [
    "ScatterPanel",
    "band_factor",
    "plot_dataset_distribution",
    "plot_learning_curves",
    "plot_nmse_boxes",
    "plot_prediction_panels",
    "share_inside_band",
]

DPI = 130
#: Tableau colours, cycled; one colour per series is fixed for the whole report figure.
_COLOURS = (
    "#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd",
    "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf",
)  # fmt: skip


def _colour(index: int) -> str:
    return _COLOURS[index % len(_COLOURS)]


def _legend_below(fig: Figure, handles: Sequence[Artist], max_cols: int) -> None:
    """One figure legend under the panels (constrained layout makes room for it)."""
    fig.legend(
        handles=handles,
        loc="outside lower center",
        ncol=min(len(handles), max_cols),
        fontsize=8,
        frameon=False,
    )


def _save(fig: Figure, out: Path, title: str = "") -> Path:
    if title:
        fig.suptitle(title, fontsize=11)
    out.parent.mkdir(parents=True, exist_ok=True)
    # Through outputs.atomic_file: the figure whole, never through a link.
    with atomic_file(out, "wb") as handle:
        fig.savefig(handle, format=out.suffix.lstrip(".") or "png", dpi=DPI, bbox_inches="tight")
    return out


# ============================================================================ Fig. 1
def plot_dataset_distribution(
    samples: pd.DataFrame,
    out: Path,
    constants: NormalisationConstants | None = None,
    title: str = "Dataset distribution",
    bins: int = 30,
) -> Path:
    """Histogram of the normalised Young's modulus of a store's ``samples``, stacked by
    object shape (paper Fig. 1); ``constants``: the label range ([1e3, 1e12] Pa by default)."""
    c = constants or NormalisationConstants()
    data = samples[np.isfinite(samples["modulus_pa"]) & (samples["modulus_pa"] > 0)]
    y = normalise_modulus(data["modulus_pa"].to_numpy(dtype=float), c)
    shapes = sorted(data["shape"].astype(str).unique())
    values = [y[(data["shape"].astype(str) == s).to_numpy()] for s in shapes]
    fig = Figure(figsize=(7.0, 4.2))
    ax = fig.add_subplot()
    lo = min(0.0, float(np.min(y))) if y.size else 0.0
    hi = max(1.0, float(np.max(y))) if y.size else 1.0
    edges = np.linspace(lo, hi, bins + 1)
    ax.hist(
        values,
        bins=edges,
        stacked=True,
        label=[f"{s} (n={len(v)})" for s, v in zip(shapes, values, strict=True)],
        color=[_colour(i) for i in range(len(shapes))],
        edgecolor="white",
        linewidth=0.4,
    )
    sensor = normalise_modulus(DEFAULT_GEL_MODULUS_PA, c)
    ax.axvline(
        sensor, color="blue", linestyle="--", linewidth=1.2, label="GelSight gel (0.275 MPa)"
    )
    ax.set_xlabel(
        f"Normalised Young's modulus y = (log₁₀E − {c.label_log10_min:g}) / "
        f"{c.label_log10_span:g}  (E in Pa)"
    )
    ax.set_ylabel("Number of samples")
    ax.set_title(f"{title}  (N = {len(data)} samples)")
    top = ax.secondary_xaxis(
        "top",
        functions=(
            lambda v: v * c.label_log10_span + c.label_log10_min,
            lambda v: (v - c.label_log10_min) / c.label_log10_span,
        ),
    )
    top.set_xlabel("log₁₀ E (Pa)")
    ax.legend(title="Shape", fontsize=8, title_fontsize=9)
    ax.grid(axis="y", alpha=0.3)
    return _save(fig, out)


# ============================================================================ Fig. 5 / 8
def band_factor(nmse: float, span_decades: float = 9.0) -> float:
    """The paper's band half-width factor f = 10^(span * sqrt(N-MSE)) (span 9 on [1e3, 1e12]).

    A prediction lies inside ``[E / f, E * f]`` exactly when its squared normalised error
    is at most the run's N-MSE: the band shows "error no worse than average".
    """
    return float(10.0 ** (span_decades * math.sqrt(max(nmse, 0.0))))


def share_inside_band(
    true_pa: Sequence[float], pred_pa: Sequence[float], nmse: float, span_decades: float = 9.0
) -> float:
    """Fraction of predictions inside the N-MSE band (comparison in log space, tolerant)."""
    t = np.asarray(true_pa, dtype=float)
    p = np.asarray(pred_pa, dtype=float)
    if t.size == 0:
        return math.nan
    d = np.abs(np.log10(p) - np.log10(t))
    return float(np.mean(d <= span_decades * math.sqrt(max(nmse, 0.0)) + 1e-9))


@dataclass
class ScatterPanel:
    """One panel of Fig. 5: a run's test predictions and its N-MSE."""

    title: str
    true_pa: np.ndarray
    pred_pa: np.ndarray
    material: np.ndarray
    nmse: float
    span_decades: float = 9.0
    subtitle: str = ""

    @property
    def inside(self) -> float:
        return share_inside_band(self.true_pa, self.pred_pa, self.nmse, self.span_decades)


def plot_prediction_panels(
    panels: Sequence[ScatterPanel | str],
    out: Path,
    ncols: int = 3,
    suptitle: str = "",
    panel_size: tuple[float, float] = (4.2, 4.0),
) -> Path:
    """Predicted vs true modulus, log-log, coloured by material (paper Fig. 5 / Fig. 8).

    A string in ``panels`` leaves that slot empty with the string written in it (e.g. "no
    run"), so the grid keeps its layout (models across, input strategies down).
    """
    drawn = [p for p in panels if isinstance(p, ScatterPanel)]
    if not drawn:
        raise ValueError("no panels to plot")
    ncols = max(1, min(ncols, len(panels)))
    nrows = math.ceil(len(panels) / ncols)
    # Constrained layout keeps titles clear of the row above (equal-aspect log axes make
    # tight_layout overlap them) and reserves room for the figure legend below.
    fig = Figure(figsize=(panel_size[0] * ncols, panel_size[1] * nrows + 0.8), layout="constrained")
    axes = fig.subplots(nrows, ncols, squeeze=False, sharex=True, sharey=True)
    materials = sorted({str(m) for p in drawn for m in p.material})
    colour = {m: _colour(i) for i, m in enumerate(materials)}
    every = np.concatenate([np.concatenate([p.true_pa, p.pred_pa]) for p in drawn])
    every = every[np.isfinite(every) & (every > 0)]
    lo = 10 ** (math.floor(math.log10(every.min())) - 0.3)
    hi = 10 ** (math.ceil(math.log10(every.max())) + 0.3)
    grid = np.logspace(math.log10(lo), math.log10(hi), 200)
    for index, panel in enumerate(panels):
        ax = axes[index // ncols][index % ncols]
        if not isinstance(panel, ScatterPanel):
            ax.text(
                0.5,
                0.5,
                panel,
                transform=ax.transAxes,
                ha="center",
                va="center",
                fontsize=9,
                wrap=True,
                color="0.4",
            )
            ax.set_axis_off()  # not set_xticks([]): the axes are shared, ticks would vanish
            continue
        f = band_factor(panel.nmse, panel.span_decades)
        ax.fill_between(grid, grid / f, grid * f, color="0.6", alpha=0.35, linewidth=0)
        ax.plot(grid, grid, color="red", linewidth=1.2)
        ax.axvline(DEFAULT_GEL_MODULUS_PA, color="blue", linewidth=1.2)
        for material in materials:
            mask = panel.material.astype(str) == material
            if mask.any():
                ax.scatter(
                    panel.true_pa[mask],
                    panel.pred_pa[mask],
                    s=12,
                    alpha=0.75,
                    color=colour[material],
                    edgecolors="none",
                )
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlim(lo, hi)
        ax.set_ylim(lo, hi)
        ax.set_box_aspect(1)  # same decades on both axes; plays well with constrained layout
        ax.grid(alpha=0.25, which="major")
        title = f"{panel.title}\nN-MSE = {panel.nmse:.4f}"
        ax.set_title(title, fontsize=10)
        text = f"inside band: {100 * panel.inside:.1f} %\nn = {panel.true_pa.size}"
        if panel.subtitle:
            text = f"{panel.subtitle}\n{text}"
        ax.text(
            0.03,
            0.97,
            text,
            transform=ax.transAxes,
            va="top",
            fontsize=8,
            bbox={"boxstyle": "round", "facecolor": "white", "alpha": 0.8, "linewidth": 0.5},
        )
        if index // ncols == nrows - 1 or index + ncols >= len(panels):
            ax.set_xlabel("True Young's modulus E (Pa)")
        if index % ncols == 0:
            ax.set_ylabel("Predicted Young's modulus Ê (Pa)")
    for index in range(len(panels), nrows * ncols):
        axes[index // ncols][index % ncols].set_visible(False)
    spans = {round(p.span_decades, 3) for p in drawn}
    span = f"{spans.pop():g}" if len(spans) == 1 else "span"
    handles = [
        Line2D([], [], marker="o", linestyle="", color=colour[m], label=m) for m in materials
    ]
    handles += [
        Line2D([], [], color="red", label="y = x (ground truth)"),
        Line2D([], [], color="blue", label="GelSight gel 0.275 MPa"),
        Patch(color="0.6", alpha=0.35, label=f"N-MSE band: E·f^±1, f = 10^({span}·√N-MSE)"),
    ]
    _legend_below(fig, handles, max_cols=4 if ncols < 3 else 7)
    if suptitle:
        # Square log-log panels leave the layout engine too little slack above two-line
        # panel titles: pad explicitly so the suptitle never touches them.
        fig.get_layout_engine().set(h_pad=0.12)
    return _save(fig, out, suptitle)


# ============================================================================ Fig. 6 / 7
def plot_nmse_boxes(
    data: pd.DataFrame,
    out: Path,
    x: str,
    series: str,
    x_order: Sequence[object],
    x_labels: Sequence[str],
    series_order: Sequence[str],
    panel: str | None = None,
    panel_order: Sequence[str] = (),
    title: str = "",
    xlabel: str = "",
    value: str = "test_nmse",
) -> Path:
    """Box plots of N-MSE over seeds: one box per (x, series), grouped along x, per panel.

    Whiskers: matplotlib's 1.5 IQR, as in the paper; runs are also drawn as dots, because
    a handful of seeds is easier to read as points.
    """
    panels = list(panel_order) if panel else [None]
    width_per_panel = max(4.5, 0.75 * len(x_order) * max(1, len(series_order)) ** 0.5 + 1.5)
    fig = Figure(figsize=(width_per_panel * len(panels), 4.6), layout="constrained")
    axes = fig.subplots(1, len(panels), squeeze=False, sharey=True)[0]
    n_series = max(1, len(series_order))
    width = 0.8 / n_series
    for ax, name in zip(axes, panels, strict=True):
        part = data if name is None else data[data[panel] == name]
        for s_index, s_name in enumerate(series_order):
            boxes, positions = [], []
            for x_index, x_value in enumerate(x_order):
                values = part.loc[(part[series] == s_name) & (part[x] == x_value), value]
                values = pd.to_numeric(values, errors="coerce").dropna().to_numpy()
                if values.size:
                    boxes.append(values)
                    positions.append(x_index - 0.4 + width * (s_index + 0.5))
            if not boxes:
                continue
            artist = ax.boxplot(
                boxes,
                positions=positions,
                widths=width * 0.85,
                patch_artist=True,
                manage_ticks=False,
                showfliers=True,
                medianprops={"color": "black"},
            )
            for patch in artist["boxes"]:
                patch.set_facecolor(_colour(s_index))
                patch.set_alpha(0.55)
            rng = np.random.default_rng(s_index)
            for pos, values in zip(positions, boxes, strict=True):
                jitter = rng.uniform(-width * 0.2, width * 0.2, values.size)
                ax.scatter(pos + jitter, values, s=9, color=_colour(s_index), zorder=3)
        ax.set_xticks(range(len(x_order)))
        crowded = len(x_order) * len(panels) > 8
        ax.set_xticklabels(
            list(x_labels),
            rotation=30 if crowded else 0,
            ha="right" if crowded else "center",
            fontsize=8,
        )
        ax.set_xlim(-0.6, len(x_order) - 0.4)
        ax.grid(axis="y", alpha=0.3)
        ax.set_xlabel(xlabel)
        if name is not None:
            ax.set_title(str(name), fontsize=10)
    axes[0].set_ylabel("Test N-MSE (normalised log modulus, lower is better)")
    handles = [Patch(color=_colour(i), alpha=0.55, label=s) for i, s in enumerate(series_order)]
    _legend_below(fig, handles, max_cols=6)
    return _save(fig, out, title)


# ============================================================================ extra
def plot_learning_curves(
    curves: pd.DataFrame,
    out: Path,
    panel_order: Sequence[str],
    panel_labels: Sequence[str],
    series_order: Sequence[str],
    title: str = "",
) -> Path:
    """Validation N-MSE (solid, mean over seeds, min-max shaded) and training loss (dashed).

    Args:
        curves: one row per (panel, series, seed, epoch) with ``train_loss`` and ``val_nmse``;
            columns ``panel`` (the model) and ``series`` (the input strategy).
    """
    fig = Figure(figsize=(4.6 * len(panel_order), 4.3), layout="constrained")
    axes = fig.subplots(1, len(panel_order), squeeze=False, sharey=True)[0]
    for ax, name, label in zip(axes, panel_order, panel_labels, strict=True):
        part = curves[curves["panel"] == name]
        for s_index, s_name in enumerate(series_order):
            runs = part[part["series"] == s_name]
            if runs.empty:
                continue
            for column, style in (("val_nmse", "-"), ("train_loss", "--")):
                per_epoch = runs.groupby("epoch")[column].agg(["mean", "min", "max", "count"])
                per_epoch = per_epoch.dropna(subset=["mean"])
                if per_epoch.empty:
                    continue
                epochs = per_epoch.index.to_numpy() + 1  # 1-based: "after epoch k"
                ax.plot(epochs, per_epoch["mean"], style, color=_colour(s_index), linewidth=1.3)
                if column == "val_nmse" and runs["seed"].nunique() > 1:
                    ax.fill_between(
                        epochs, per_epoch["min"], per_epoch["max"], color=_colour(s_index),
                        alpha=0.15, linewidth=0,
                    )  # fmt: skip
        ax.set_yscale("log")
        ax.set_title(label, fontsize=10)
        ax.set_xlabel("Epoch")
        ax.grid(alpha=0.3, which="both")
    axes[0].set_ylabel("Validation N-MSE / training loss (log scale)")
    handles = [Line2D([], [], color=_colour(i), label=s) for i, s in enumerate(series_order)]
    handles += [
        Line2D([], [], color="black", linestyle="-", label="validation N-MSE (mean; min–max)"),
        Line2D([], [], color="black", linestyle="--", label="training loss (MSE + l2)"),
    ]
    _legend_below(fig, handles, max_cols=6)
    return _save(fig, out, title)
