"""Real grasps: a folder of real recordings through the documented user path, scored.

Every recording ``<stem>.avi`` with its ``<stem>_readings.csv`` (``timestamp_s,force_n,
width_m`` per frame) under ``--recordings`` goes through the commands a user runs, called
in-process through the CLI itself (``tactile_compliance.cli.app``; nothing private):

1. ``calibrate wedge:VIDEO --corners ... --warp-size 300x400 --frames 3`` (the pad's
   corners from ``wedge_config/config_*.csv`` of the folder, or ``--corners``);
2. ``record wedge:VIDEO --calibration CAL --readings CSV --object LABEL --modulus E
   [--reference IMAGE] --json`` into one raw dataset;
3. ``import burgess DATASET --fingers markerless``;
4. ``predict MODEL STORE --json`` for every ``--model``;
5. ``adapt MODEL STORE --out work/NAME-adapted-loo`` for every ``--adapt``: these grasps
   are the reference objects, and each grasp is scored by the map fitted on the *other*
   objects' grasps (leave-one-object-out, ``adapt.json``'s ``per_grasp``).

Objects are matched to labels of the object table by the name rule of the folder's
README (``real/README.md``: a row ``| `golf_ball_{1,2,3}` | golf_ball | ...`` maps the
file stem prefix ``golf_ball`` to the label ``golf_ball``), else by the prefix itself
being a label, else by ``--label PREFIX=LABEL``; a recording that matches nothing stops
the run before anything is recorded.

Reported, per object: the true E, the two analytical estimates that ``record`` stored
(elastic, Hertz; geometric mean over the object's grasps), with ``--rig`` the two
rig-corrected ones, each model's zero-shot prediction and each adapted model's
leave-one-object-out prediction
(augmentation 0 of each grasp, the frames ``live`` uses; geometric mean over grasps).
Per estimator / model: the share of grasps within one decade of the truth (a missing
estimate counts as outside), the N-MSE on the dataset's label range [1e3, 1e12] Pa
(``runs.metrics.nmse``, over the grasps with a value), the MAE in decades, and Spearman's
rank correlation over objects (of the objects' mean log10 predictions) and over grasps.
``--out DIR`` (created; must not exist or be empty) gets ``real_grasps.json`` (every
number, per grasp too, the warnings ``record`` gave and the commands run),
``real_grasps.png`` (predicted against true E per object) and ``work/`` (calibrations,
dataset, store).

Run (the 15 grasps of ``../shared/reference-data/real/wedge-grasps``: 0.5-1.5 min on the
shared 2-core project machine, models included)::

    python benchmarks/real_grasps.py --out real-out
    python benchmarks/real_grasps.py --out real-ref --reference \\
        ../shared/reference-data/real/wedge-grasps/wedge_config/init_frame_unwarped.png
    python benchmarks/real_grasps.py --out real-models --model runs/RUN/best.pt --model model-dir
    python benchmarks/real_grasps.py --out real-s2r --rig wedge-2023 \
        --model sim2real-output/best.pt --adapt sim2real-output/best.pt

A research script, not part of the installed package; the test is
``tests/test_real_grasps.py`` (skips when the real data is absent). Results:
``docs/results.md``, "Real grasps".
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import re
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

REPO_ROOT = Path(__file__).resolve().parents[1]
REFERENCE_DATA = REPO_ROOT.parent / "shared" / "reference-data"
DEFAULT_RECORDINGS = REFERENCE_DATA / "real" / "wedge-grasps"
DEFAULT_OBJECTS = REFERENCE_DATA / "dataset_objects_and_compliance.csv"
VIDEO_SUFFIXES = (".avi", ".mp4", ".mov", ".mkv")
ANALYTICAL = ("elastic", "hertz")
#: The same two with the rig's own closure taken out (``record --rig``; docs/physics.md).
RIG_CORRECTED = ("elastic_rig", "hertz_rig")
_README_ROW = re.compile(r"^\|\s*`([A-Za-z0-9_.+-]+?)(?:_\{[\d,\s]+\}|_\d+)?`\s*\|\s*([^|]+?)\s*\|")


class BenchmarkError(RuntimeError):
    """The benchmark cannot run (bad folder, unmatched recording, a command failed)."""


# ---------------------------------------------------------------------- the CLI
def run_cli(*args: Any) -> str:
    """Run ``tactile-compliance ARGS`` in this process; its stdout, or BenchmarkError."""
    import typer.main

    from tactile_compliance.cli import app

    argv = [str(a) for a in args]
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = typer.main.get_command(app).main(
                argv, prog_name="tactile-compliance", standalone_mode=False
            )
        except Exception as error:  # click's usage errors raise without standalone mode
            raise BenchmarkError(f"tactile-compliance {' '.join(argv)}: {error}") from error
    if code not in (None, 0):
        raise BenchmarkError(
            f"tactile-compliance {' '.join(argv)} exited with {code}: {err.getvalue().strip()}"
        )
    return out.getvalue()


# ---------------------------------------------------------------------- recordings
def find_recordings(folder: Path) -> list[tuple[Path, Path]]:
    """(video, readings CSV) pairs under ``folder``, sorted by path."""
    pairs = []
    for video in sorted(p for p in folder.rglob("*") if p.suffix.lower() in VIDEO_SUFFIXES):
        readings = video.with_name(f"{video.stem}_readings.csv")
        if readings.is_file():
            pairs.append((video, readings))
    if not pairs:
        raise BenchmarkError(f"{folder}: no video with a <stem>_readings.csv next to it")
    return pairs


def read_corners(folder: Path) -> str | None:
    """The pad's corners as ``calibrate --corners`` takes them, from ``wedge_config/
    config_*.csv`` (``Name,x,y`` rows topleft, topright, bottomright, bottomleft)."""
    import pandas as pd

    configs = sorted(folder.glob("wedge_config/config_*.csv"))
    if not configs:
        return None
    table = pd.read_csv(configs[0])
    table.columns = [str(c).strip().lower() for c in table.columns]
    points = {str(r["name"]).strip().lower(): (r["x"], r["y"]) for _, r in table.iterrows()}
    order = ("topleft", "topright", "bottomright", "bottomleft")
    missing = [name for name in order if name not in points]
    if missing:
        raise BenchmarkError(f"{configs[0]}: no corner(s) {missing}")
    return " ".join(f"{points[n][0]:g},{points[n][1]:g}" for n in order)


def readme_labels(folder: Path) -> dict[str, str]:
    """``file stem prefix -> label`` from the README of the folder or its parent."""
    rules: dict[str, str] = {}
    for readme in (folder / "README.md", folder.parent / "README.md"):
        if readme.is_file():
            for line in readme.read_text(encoding="utf-8").splitlines():
                if m := _README_ROW.match(line.strip()):
                    rules.setdefault(m.group(1), m.group(2).strip())
    return rules


def split_stem(stem: str) -> tuple[str, int | None]:
    """``golf_ball_2`` -> (``golf_ball``, 2); a stem without a trial number is its own prefix."""
    m = re.match(r"^(.*?)_(\d+)$", stem)
    return (m.group(1), int(m.group(2))) if m else (stem, None)


def match_labels(
    stems: Sequence[str], labels: Sequence[str], rules: dict[str, str], overrides: dict[str, str]
) -> dict[str, str]:
    """``stem -> label``: ``--label`` first, then the README's rule, then the prefix itself
    when it is a label. Raises BenchmarkError naming every stem that matches nothing."""
    known = set(labels)
    matched, problems = {}, []
    for stem in stems:
        prefix, _ = split_stem(stem)
        label = overrides.get(prefix) or rules.get(prefix) or (prefix if prefix in known else None)
        if label is None:
            problems.append(f"{stem}: no label for prefix {prefix!r}")
        elif label not in known:
            problems.append(f"{stem}: label {label!r} is not in the object table")
        else:
            matched[stem] = label
    if problems:
        raise BenchmarkError(
            "recordings without an object (give --label PREFIX=LABEL): " + "; ".join(problems)
        )
    return matched


def _text(value: Any) -> str:
    return "" if value is None or (isinstance(value, float) and math.isnan(value)) else str(value)


# ---------------------------------------------------------------------- metrics
def _spearman(x: Sequence[float], y: Sequence[float]) -> float | None:
    from scipy.stats import spearmanr

    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    ok = np.isfinite(x) & np.isfinite(y)
    if ok.sum() < 3 or np.ptp(x[ok]) == 0 or np.ptp(y[ok]) == 0:
        return None
    return float(spearmanr(x[ok], y[ok]).statistic)


def score(grasps: list[dict[str, Any]], key: str) -> dict[str, Any]:
    """Metrics of one estimator / model over the grasps (``grasp[key]``: Pa or None)."""
    from tactile_compliance.runs.metrics import log10_accuracy, mae_decades, nmse

    true = np.array([g["true_pa"] for g in grasps], dtype=float)
    pred = np.array([np.nan if g[key] is None else g[key] for g in grasps], dtype=float)
    have = np.isfinite(pred) & (pred > 0)
    result: dict[str, Any] = {"n_grasps": len(grasps), "n_missing": int((~have).sum())}
    if not have.any():
        return {**result, "within_one_decade": 0.0}
    inside = log10_accuracy(true[have], pred[have]) * have.sum()
    result["within_one_decade"] = float(inside / len(grasps))  # a missing one is outside
    result["nmse"] = nmse(true[have], pred[have])
    result["mae_decades"] = mae_decades(true[have], pred[have])
    objects = sorted({g["object"] for g in grasps})
    per_object_true, per_object_pred = [], []
    for name in objects:
        logs = [
            np.log10(p)
            for g, p, h in zip(grasps, pred, have, strict=True)
            if h and g["object"] == name
        ]
        truth = next(g["true_pa"] for g in grasps if g["object"] == name)
        per_object_true.append(np.log10(truth))
        per_object_pred.append(float(np.mean(logs)) if logs else np.nan)
    result["spearman_objects"] = _spearman(per_object_true, per_object_pred)
    result["spearman_grasps"] = _spearman(np.log10(true[have]), np.log10(pred[have]))
    return result


def per_object(grasps: list[dict[str, Any]], keys: Sequence[str]) -> list[dict[str, Any]]:
    """Per object: true E and the geometric mean over its grasps of every key."""
    rows = []
    for name in sorted({g["object"] for g in grasps}, key=lambda n: (_true(grasps, n), n)):
        mine = [g for g in grasps if g["object"] == name]
        row: dict[str, Any] = {"object": name, "true_pa": mine[0]["true_pa"], "grasps": len(mine)}
        for key in keys:
            values = [g[key] for g in mine if g[key] is not None and g[key] > 0]
            row[key] = float(10 ** np.mean(np.log10(values))) if values else None
            row[f"{key}_n"] = len(values)
        rows.append(row)
    return rows


def _true(grasps: list[dict[str, Any]], name: str) -> float:
    return next(g["true_pa"] for g in grasps if g["object"] == name)


# ---------------------------------------------------------------------- output
def format_tables(result: dict[str, Any]) -> str:
    """The per-object table and the summary, as Markdown."""
    keys = result["estimators"]
    names = {k: result["names"][k] for k in keys}
    head = "| object | true E [Pa] | " + " | ".join(names[k] for k in keys) + " |"
    lines = [head, "|" + "---|" * (2 + len(keys))]
    for row in result["objects"]:
        cells = [
            "-"
            if row[k] is None
            else f"{row[k]:.3g}"
            + ("" if row[f"{k}_n"] == row["grasps"] else f" ({row[f'{k}_n']}/{row['grasps']})")
            for k in keys
        ]
        lines.append(f"| {row['object']} | {row['true_pa']:.3g} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "| estimator / model | within one decade | N-MSE | MAE [decades] "
        "| Spearman (objects) | Spearman (grasps) | missing |",
        "|---|---|---|---|---|---|---|",
    ]

    def f(value: Any, spec: str) -> str:
        return "-" if value is None else format(value, spec)

    for key in keys:
        s = result["summary"][key]
        n = s["n_grasps"]
        lines.append(
            f"| {names[key]} | {round(s['within_one_decade'] * n)}/{n} "
            f"({s['within_one_decade']:.0%}) | {f(s.get('nmse'), '.4f')} | "
            f"{f(s.get('mae_decades'), '.2f')} | {f(s.get('spearman_objects'), '.2f')} | "
            f"{f(s.get('spearman_grasps'), '.2f')} | {s['n_missing']} |"
        )
    return "\n".join(lines)


def beyond_paper_mark(name: str) -> str:
    """``name`` (a strategy, or a run name ``MODEL-INPUTS-...``) with the tables' mark
    `` (beyond the paper)`` when its input strategy is not one of the paper's four
    (``evaluation.tables.inputs_label``, the one home of that mark)."""
    from tactile_compliance.evaluation.tables import inputs_label

    parts = name.split("-")
    inputs = parts[1] if len(parts) > 1 else name
    return name + inputs_label(inputs)[len(inputs) :]


def figure_panels(result: dict[str, Any]) -> list[tuple[str, list[tuple[str, str]]]]:
    """The figure's panels: (title, [(key, label in the panel)]) per family, in order.

    The analytical estimates (and the rig-corrected ones) are one panel; each model
    family (a run name's model part, ``top10nn-ALL-unseen-random-seed0`` -> ``top10nn``,
    titled by its display name) is another, its members labelled by what tells them
    apart (the run name without the family and the suffix they share: ``ALL``).
    """
    try:
        from tactile_compliance.models import model_display_names

        display = model_display_names()
    except Exception:  # the figure must not fail on a model this install does not know
        display = {}
    analytical = [k for k in result["estimators"] if k in (*ANALYTICAL, *RIG_CORRECTED)]
    panels: list[tuple[str, list[tuple[str, str]]]] = []
    if analytical:
        panels.append(("Analytical", [(k, result["names"][k]) for k in analytical]))
    families: dict[str, list[str]] = {}
    for key in result["estimators"]:
        if key not in analytical:
            families.setdefault(key.split("-")[0], []).append(key)
    for family, keys in families.items():
        parts = [k.split("-")[1:] for k in keys]
        shared = 0  # trailing name parts every member shares (condition, sampling, seed)
        while all(len(q) > shared + 1 for q in parts) and len({q[-1 - shared] for q in parts}) == 1:
            shared += 1
        labels = ["-".join(q[: len(q) - shared]) or family for q in parts]
        if len(set(labels)) < len(labels):
            labels = [result["names"][k] for k in keys]
        else:
            labels = [beyond_paper_mark(label) for label in labels]
        panels.append((display.get(family, family), list(zip(keys, labels, strict=True))))
    return panels


def draw_figure(result: dict[str, Any], path: Path) -> Path:
    """Predicted against true E per object (geometric means over its grasps), one panel
    per family (:func:`figure_panels`): identity, the one-decade band and each member's
    markers, its legend inside the panel; the objects named along the top row."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    markers = "osD^v<>Pp*hX"
    rows = result["objects"]
    lo = min(math.log10(r["true_pa"]) for r in rows)
    hi = max(math.log10(r["true_pa"]) for r in rows)
    for row_values in ([r[k] for r in rows if r[k]] for k in result["estimators"]):
        if row_values:
            lo = min(lo, math.log10(min(row_values)))
            hi = max(hi, math.log10(max(row_values)))
    lo, hi = math.floor(lo) - 0.5, math.ceil(hi) + 0.5
    line = np.array([10**lo, 10**hi])
    panels = figure_panels(result)
    ncols = min(len(panels), 2 if len(panels) <= 4 else 3)
    nrows = math.ceil(len(panels) / ncols)
    fig, axes = plt.subplots(
        nrows, ncols, figsize=(3.6 * ncols, 3.5 * nrows + 0.9), sharex=True, sharey=True,
        squeeze=False,
    )  # fmt: skip
    for index, (title, members) in enumerate(panels):
        ax = axes[index // ncols][index % ncols]
        first = index == 0  # the identity and the band are named once, in the first panel
        ax.plot(line, line, color="black", lw=1, label="identity" if first else None)
        ax.fill_between(
            line, line / 10, line * 10, color="0.9", label="within one decade" if first else None
        )
        offsets = np.linspace(-0.05, 0.05, max(len(members), 1))
        for i, (key, label) in enumerate(members):
            xs = [r["true_pa"] * 10 ** offsets[i] for r in rows if r[key]]
            ys = [r[key] for r in rows if r[key]]
            ax.scatter(xs, ys, marker=markers[i % len(markers)], s=30, label=label, zorder=3)
        ax.set(xscale="log", yscale="log", xlim=(10**lo, 10**hi), ylim=(10**lo, 10**hi))
        ax.set_box_aspect(1)
        ax.set_title(title, fontsize=9)
        ax.legend(fontsize=6, loc="upper left", framealpha=0.85)
        if index // ncols == 0:
            top = ax.secondary_xaxis("top")
            top.set_xticks([r["true_pa"] for r in rows], [r["object"] for r in rows], fontsize=6)
            top.tick_params(axis="x", labelrotation=60)
            top.minorticks_off()
        if index % ncols == 0:
            ax.set_ylabel("predicted E [Pa]\n(geometric mean over grasps)", fontsize=8)
        if index // ncols == nrows - 1 or index + ncols >= len(panels):
            ax.set_xlabel("true E [Pa]", fontsize=8)
    for index in range(len(panels), nrows * ncols):
        axes[index // ncols][index % ncols].set_visible(False)
    fig.suptitle(f"Real grasps: {len(rows)} objects, {len(result['grasps'])} grasps", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100, pil_kwargs={"optimize": True})
    plt.close(fig)
    return path


# ---------------------------------------------------------------------- the run
def _model_names(models: Sequence[Path]) -> list[str]:
    """Short unique names: the run directory's (or the export's) name without the run
    name's trailing hash (``top10nn-ALL-unseen-random-seed0-cf1c812ecd`` ->
    ``top10nn-ALL-unseen-random-seed0``); a checkpoint not called ``best.pt`` by its own
    name (``models/seed1.pt`` -> ``seed1``)."""
    names: list[str] = []
    for model in models:
        if model.suffix == ".pt":
            name = model.parent.name if model.name == "best.pt" else model.stem
        else:
            name = model.name
        name = re.sub(r"-[0-9a-f]{10}$", "", name) or name
        base, k = name, 2
        while name in names:
            name, k = f"{base}-{k}", k + 1
        names.append(name)
    return names


def run(
    out: Path,
    recordings: Path = DEFAULT_RECORDINGS,
    objects: Path = DEFAULT_OBJECTS,
    models: Sequence[Path] = (),
    reference: Path | None = None,
    corners: str | None = None,
    warp_size: str = "300x400",
    frames: int = 3,
    labels: dict[str, str] | None = None,
    rig: str | None = None,
    adapt: Sequence[Path] = (),
    log: Any = print,
) -> dict[str, Any]:
    """Run the benchmark (see the module docstring); returns what ``real_grasps.json`` holds."""
    from tactile_compliance.data.object_table import read_object_table

    started = time.perf_counter()
    recordings, out = Path(recordings), Path(out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise BenchmarkError(f"{out} exists and is not empty; give a fresh --out directory")
    pairs = find_recordings(recordings)
    corners = corners or read_corners(recordings)
    if corners is None:
        raise BenchmarkError(f"{recordings}: no wedge_config/config_*.csv; give --corners")
    table = read_object_table(objects)
    stems = [video.stem for video, _ in pairs]
    if len(set(stems)) != len(stems):
        raise BenchmarkError("two recordings share a file name; the stem names the grasp")
    matched = match_labels(stems, list(table.index), readme_labels(recordings), labels or {})
    names = _model_names([Path(m) for m in models])
    work = out / "work"
    (work / "calibrations").mkdir(parents=True)
    dataset, store = work / "dataset", work / "store"
    commands: list[str] = []

    def cli(*args: Any) -> str:
        commands.append("tactile-compliance " + " ".join(_quote(str(a)) for a in args))
        return run_cli(*args)

    grasps: list[dict[str, Any]] = []
    t0 = time.perf_counter()
    for (video, readings), stem in zip(pairs, stems, strict=True):
        label = matched[stem]
        row = table.loc[label]
        calibration = work / "calibrations" / f"{stem}.json"
        spec = f"wedge:{video}"
        cli(
            "calibrate",
            spec,
            "--out",
            calibration,
            "--corners",
            corners,
            "--warp-size",
            warp_size,
            "--frames",
            frames,
        )
        extra = ["--reference", reference] if reference is not None else []
        extra += ["--rig", rig] if rig is not None else []
        recorded = json.loads(
            cli(
                "record",
                spec,
                "--calibration",
                calibration,
                "--readings",
                readings,
                "--out",
                dataset,
                "--object",
                label,
                "--modulus",
                repr(float(row["modulus_pa"])),
                "--material",
                _text(row.get("material")),
                "--shape",
                _text(row.get("shape")),
                *extra,
                "--json",
            )
        )
        elastic, hertz = recorded["estimates_pa"]
        corrected = recorded.get("rig_corrected_pa") or [None, None]
        grasps.append(
            {
                **dict(zip(RIG_CORRECTED, corrected, strict=True)),
                "recording": stem,
                "object": label,
                "grasp": recorded["grasp"],
                "true_pa": float(row["modulus_pa"]),
                "elastic": elastic,
                "hertz": hertz,
                "frame_indices": recorded["frame_indices"][0],
                "augmentations": recorded["augmentations"],
                "n_frames": recorded["n_frames"],
                "warnings": recorded.get("warnings", []),
                "checks": recorded.get("checks", {}),
            }
        )
        log(
            f"recorded {stem:<24} -> {label:<20} frames {recorded['frame_indices'][0]} "
            f"elastic {_g(elastic)} Hertz {_g(hertz)}"
            + "".join(f"\n    warning: {w}" for w in recorded.get("warnings", []))
        )
    record_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    cli(
        "import",
        "burgess",
        dataset,
        "--out",
        store,
        "--fingers",
        "markerless",
        "--objects",
        dataset / "dataset_objects_and_compliance.csv",
    )
    import_s = time.perf_counter() - t0
    by_key = {(g["object"], g["grasp"]): g for g in grasps}
    predict_s = {}
    for model, name in zip(models, names, strict=True):
        t0 = time.perf_counter()
        report = json.loads(cli("predict", model, store, "--json"))
        predict_s[name] = time.perf_counter() - t0
        for g in grasps:
            g[name], g[f"{name}_augmentations_log10"] = None, []
        for p in report["predictions"]:
            g = by_key[(p["object"], int(p["grasp"]))]
            g[f"{name}_augmentations_log10"].append(p["pred_log10_pa"])
            if int(p["augmentation"]) == 0:
                g[name] = p["pred_pa"]
        log(
            f"predicted with {name}: {len(report['predictions'])} samples, "
            f"{len(report.get('skipped', []))} skipped"
        )
    adapted = [f"{n}-adapted-loo" for n in _model_names([Path(m) for m in adapt])]
    adapt_s = {}
    for model, key in zip(adapt, adapted, strict=True):
        t0 = time.perf_counter()
        target = work / key
        cli("adapt", model, store, "--out", target)
        adapt_s[key] = time.perf_counter() - t0
        report = json.loads((target / "adapt.json").read_text(encoding="utf-8"))
        for g in grasps:
            g[key] = None
        for p in report["per_grasp"]:
            by_key[(p["object"], int(p["grasp"]))][key] = p["adapted_loo_pa"]
        log(f"adapted {model}: {target / 'best.pt'} (leave-one-object-out per grasp)")
    keys = [*ANALYTICAL, *(RIG_CORRECTED if rig is not None else ()), *names, *adapted]
    display = {"elastic": "elastic (analytical)", "hertz": "Hertz (analytical)"}
    display |= {"elastic_rig": "elastic, rig-corrected", "hertz_rig": "Hertz, rig-corrected"}
    display.update({n: beyond_paper_mark(n) for n in names})
    display.update(
        {k: f"{k[: -len('-adapted-loo')]}, adapted (leave-one-object-out)" for k in adapted}
    )
    result = {
        "recordings": str(recordings),
        "objects_table": str(objects),
        "reference": None if reference is None else str(reference),
        "rig": rig,
        "corners": corners,
        "models": {n: str(m) for n, m in zip(names, models, strict=True)},
        "adapted": {k: str(m) for k, m in zip(adapted, adapt, strict=True)},
        "estimators": keys,
        "names": display,
        "label_range_pa": [1e3, 1e12],
        "grasps": grasps,
        "objects": per_object(grasps, keys),
        "summary": {k: score(grasps, k) for k in keys},
        "timing_s": {
            "calibrate_and_record": record_s,
            "import": import_s,
            "predict": predict_s,
            "adapt": adapt_s,
            "total": time.perf_counter() - started,
        },
        "commands": commands,
    }
    (out / "real_grasps.json").write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    draw_figure(result, out / "real_grasps.png")
    return result


def _g(value: float | None) -> str:
    return "-" if value is None else f"{value:.3g}"


def _quote(text: str) -> str:
    return text if re.fullmatch(r"[\w./:=+,-]+", text) else json.dumps(text)


def _label_option(text: str) -> tuple[str, str]:
    prefix, sep, label = text.partition("=")
    if not (sep and prefix and label):
        raise argparse.ArgumentTypeError(f"--label takes PREFIX=LABEL, got {text!r}")
    return prefix, label


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--recordings",
        type=Path,
        default=DEFAULT_RECORDINGS,
        help="folder of <stem>.avi + <stem>_readings.csv (searched recursively)",
    )
    parser.add_argument("--objects", type=Path, default=DEFAULT_OBJECTS, help="object table CSV")
    parser.add_argument(
        "--model",
        type=Path,
        action="append",
        default=[],
        help="a checkpoint (best.pt / run dir) or an exported directory; repeatable",
    )
    parser.add_argument("--out", type=Path, required=True, help="fresh output directory")
    parser.add_argument(
        "--reference",
        type=Path,
        default=None,
        help="no-contact frame for `record --reference` (default: the calibration's)",
    )
    parser.add_argument(
        "--corners",
        default=None,
        help="pad corners 'x,y x,y x,y x,y' (default: wedge_config/config_*.csv)",
    )
    parser.add_argument("--warp-size", default="300x400", help="calibrate --warp-size")
    parser.add_argument("--frames", type=int, default=3, help="calibrate --frames")
    parser.add_argument(
        "--label",
        type=_label_option,
        action="append",
        default=[],
        help="PREFIX=LABEL: the object of recordings <PREFIX>_<n>; repeatable",
    )
    parser.add_argument(
        "--rig",
        default=None,
        help="a rig file or name for `record --rig`: adds the rig-corrected estimates",
    )
    parser.add_argument(
        "--adapt",
        type=Path,
        action="append",
        default=[],
        help="a checkpoint to `adapt` on these grasps; scored leave-one-object-out "
        "(each object by a map fitted on the others); repeatable",
    )
    args = parser.parse_args(argv)
    try:
        result = run(
            args.out,
            recordings=args.recordings,
            objects=args.objects,
            models=args.model,
            reference=args.reference,
            corners=args.corners,
            warp_size=args.warp_size,
            frames=args.frames,
            labels=dict(args.label),
            rig=args.rig,
            adapt=args.adapt,
        )
    except (BenchmarkError, OSError, ValueError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print()
    print(format_tables(result))
    timing = result["timing_s"]
    print(
        f"\n{len(result['grasps'])} grasps of {len(result['objects'])} objects in "
        f"{timing['total']:.0f} s (calibrate + record {timing['calibrate_and_record']:.0f} s, "
        f"import {timing['import']:.1f} s); {args.out / 'real_grasps.json'}, "
        f"{args.out / 'real_grasps.png'}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
