"""Probe what a (synthetic) GraspStore lets a model learn about unseen objects.

Research script (issue 17): cheap learned probes under the UnSeen protocol - 5-fold
``GroupKFold`` by object, so no object is in both the training and the test fold - that
show how much of the label each input carries. Each probe is a
``sklearn.ensemble.HistGradientBoostingRegressor`` on ``log10 E`` (fixed seed):

=====================  ==========================================================
``image features``     hand-made image features alone: per frame, the share of the
                       image whose deviation from 0.5 (max over channels) exceeds 2, 5
                       and 10 grey levels (contact-area shares), and the mean and
                       max deviation [grey levels] (15 features)
``median``             the training fold's median label (no learning)
``F, W, log10 E``      the three forces, the three widths, log10 of both analytical
                       estimates (clamped to [1e2, 1e14] Pa like the model input)
``F, W, E + image``    both sets together (what the learned models see, roughly)
``image + texture``    the image features plus the ladder's texture statistics of the
                       last frame (``synthetic.ladder.image_statistics``: fine/coarse
                       Laplacian energy, orientation coherence) - the surface cues
``oracle material``    no learning: the training fold's median label of the sample's
                       material (what knowing the material alone would give)
``analytical``         no learning: the share of test samples whose analytical estimate
                       is within one decade of the label - the elastic (Hooke) estimate,
                       the Hertz E* converted to the object's E
                       (``physics.contact.object_modulus_from_effective_pa``, default gel
                       and object Poisson ratios; "much stiffer than the gel" = inf is
                       never within a decade), and either of the two
=====================  ==========================================================

With ``--real-store`` the learning probes are also fitted on the whole synthetic store and
scored on a store of real grasps (``benchmarks/real_grasps.py`` writes one to
``OUT/work/store``), as ``real_grasps.py`` scores a model: per grasp the geometric mean
over its samples, the share of grasps within one decade and Spearman over objects. A
probe on ``F, W`` alone joins them there: the rig's closure under force, which the
``wedge-2023`` rig was fitted to (docs/synthetic.md). Nothing is fitted on the real store.

N-MSE and the other metrics are ``tactile_compliance.runs.metrics.compute_metrics`` with
the package's default normalisation (labels on [1e3, 1e12] Pa). Prints a markdown table
(and ``--json`` writes the numbers).

Usage::

    tactile-compliance simulate --out /tmp/raw --objects 286 --size 48x64
    tactile-compliance import burgess /tmp/raw --out /tmp/store
    python benchmarks/calibrate_synthetic.py /tmp/store [--finger markerless] [--json out.json]
    # sim2real's store against the real grasps' (docs/results.md, "What transfers")
    python benchmarks/calibrate_synthetic.py s2r/work/store --finger markerless \
        --real-store real-out/work/store

The issue's targets: image-only probe clearly better than the median; the analytical
estimates within one decade for 20-40 % of test samples.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

THRESHOLDS_GREY = (2.0, 5.0, 10.0)
"""Contact thresholds of the image features [grey levels of the difference image]."""

ESTIMATE_CLAMP_PA = (1e2, 1e14)


def image_features(frames: np.ndarray) -> np.ndarray:
    """Hand-made features of uint8 frames (n, 3, H, W, 3) -> (n, 15).

    Per frame: the area share above each of :data:`THRESHOLDS_GREY`, the mean and the
    max deviation [grey levels]. The store holds difference images as uint8 with 0.5 at
    ~128 (``frames_to_uint8``), so the deviation is ``|x - 0.5|`` in grey levels.
    """
    from tactile_compliance.data.store import frames_from_uint8

    n = frames.shape[0]
    out = np.empty((n, 3, len(THRESHOLDS_GREY) + 2), dtype=np.float64)
    for start in range(0, n, 256):
        block = frames_from_uint8(frames[start : start + 256])  # float32 in (0, 1)
        dev = np.abs(block - 0.5).max(axis=-1) * 255.0  # (b, 3, H, W)
        flat = dev.reshape(*dev.shape[:2], -1)
        for j, t in enumerate(THRESHOLDS_GREY):
            out[start : start + len(block), :, j] = (flat > t).mean(axis=-1)
        out[start : start + len(block), :, -2] = flat.mean(axis=-1)
        out[start : start + len(block), :, -1] = flat.max(axis=-1)
    return out.reshape(n, -1)


def force_width_estimate_features(samples) -> np.ndarray:  # type: ignore[no-untyped-def]
    """F (3) [N], W (3) [m], log10 of both analytical estimates (clamped) -> (n, 8)."""
    from tactile_compliance.data.store import ESTIMATE_COLUMNS, FORCE_COLUMNS, WIDTH_COLUMNS

    f = samples[list(FORCE_COLUMNS)].to_numpy(dtype=np.float64)
    w = samples[list(WIDTH_COLUMNS)].to_numpy(dtype=np.float64)
    e = samples[list(ESTIMATE_COLUMNS)].to_numpy(dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        log_e = np.log10(np.clip(e, *ESTIMATE_CLAMP_PA))
    return np.concatenate([f, w, log_e], axis=1)


def _cross_val_predict(
    x: np.ndarray, y: np.ndarray, groups: np.ndarray, folds: int, seed: int, per_sample: bool
) -> np.ndarray:
    """Out-of-fold gradient-boosting predictions of ``y`` (log10 Pa).

    ``per_sample`` folds are the paper's Seen split (shuffled samples: an object's other
    grasps and augmentations sit in training); otherwise folds are grouped by object
    (UnSeen).
    """
    from sklearn.ensemble import HistGradientBoostingRegressor
    from sklearn.model_selection import GroupKFold, KFold

    splitter = (
        KFold(n_splits=folds, shuffle=True, random_state=seed).split(x)
        if per_sample
        else GroupKFold(n_splits=folds).split(x, y, groups)
    )
    out = np.empty_like(y)
    for train, test in splitter:
        model = HistGradientBoostingRegressor(random_state=seed).fit(x[train], y[train])
        out[test] = model.predict(x[test])
    return out


def soft_hard_probes(  # type: ignore[no-untyped-def]
    samples, image: np.ndarray, folds: int = 5, seed: int = 0, draws: int = 3
) -> dict:
    """The paper's two measures of "objects softer than the sensor are easier".

    * **Margin share** (the paper's Fig. 5): the share of soft (< 0.275 MPa) and of hard
      test samples whose squared normalised error is below the probe's pooled N-MSE,
      and their N-MSE, for the Seen per-sample split the paper used and for UnSeen.
    * **Rolling windows** (Fig. 6): the probe trained and tested inside each 3-decade
      window ``(lo, hi]`` of ``data.splits.rolling_windows``, every window undersampled
      to the smallest one's sample count (``draws`` random draws, mean N-MSE), UnSeen and
      per-sample. The paper finds the N-MSE rising from the windows above ~1e6 Pa on.

    ``image`` holds the samples' :func:`image_features` (computed once by the caller).
    """
    from tactile_compliance.data.normalisation import normalise_modulus
    from tactile_compliance.data.splits import rolling_windows
    from tactile_compliance.runs.metrics import compute_metrics, soft_hard_labels

    y = np.log10(samples["modulus_pa"].to_numpy(dtype=np.float64))
    groups = samples["object"].to_numpy()
    fwe = force_width_estimate_features(samples)
    inputs = {
        "F, W, log10 E": fwe,
        "F, W, E + image features": np.concatenate([fwe, image], axis=1),
    }
    soft = soft_hard_labels(10.0**y) == "soft"
    margin: dict[str, dict[str, dict[str, float]]] = {}
    for split, per_sample in (("seen per-sample", True), ("unseen", False)):
        for name, x in inputs.items():
            pred = _cross_val_predict(x, y, groups, folds, seed, per_sample)
            se = (normalise_modulus(10.0**pred) - normalise_modulus(10.0**y)) ** 2
            pooled = float(se.mean())
            margin.setdefault(split, {})[name] = {
                "nmse": pooled,
                "soft_nmse": float(se[soft].mean()),
                "hard_nmse": float(se[~soft].mean()),
                "soft_in_margin": float((se[soft] < pooled).mean()),
                "hard_in_margin": float((se[~soft] < pooled).mean()),
            }
    windows = rolling_windows()
    members = [np.flatnonzero((y > np.log10(lo)) & (y <= np.log10(hi))) for lo, hi in windows]
    size = min(len(m) for m in members)
    rng = np.random.default_rng(seed)
    rolling: dict[str, dict[str, list[float]]] = {}
    for split, per_sample in (("seen per-sample", True), ("unseen", False)):
        for name, x in inputs.items():
            row = []
            for idx in members:
                scores = []
                for _ in range(draws):
                    sub = np.sort(rng.choice(idx, size, replace=False))
                    pred = _cross_val_predict(x[sub], y[sub], groups[sub], folds, seed, per_sample)
                    scores.append(compute_metrics(10.0 ** y[sub], 10.0**pred)["nmse"])
                row.append(float(np.mean(scores)))
            rolling.setdefault(split, {})[name] = row
    return {
        "margin": margin,
        "rolling_windows": [[float(lo), float(hi)] for lo, hi in windows],
        "rolling_samples_per_window": int(size),
        "rolling_nmse": rolling,
    }


def format_soft_hard(result: dict) -> str:
    """:func:`soft_hard_probes` as two markdown tables."""
    lines = [
        "| split | probe | soft N-MSE | hard N-MSE | soft in margin | hard in margin |",
        "|---|---|---|---|---|---|",
    ]
    for split, probes in result["margin"].items():
        for name, m in probes.items():
            lines.append(
                f"| {split} | {name} | {m['soft_nmse']:.4f} | {m['hard_nmse']:.4f} "
                f"| {m['soft_in_margin']:.3f} | {m['hard_in_margin']:.3f} |"
            )
    heads = [f"1e{np.log10(lo):.0f}-1e{np.log10(hi):.0f}" for lo, hi in result["rolling_windows"]]
    lines += [
        "",
        f"Rolling windows, N-MSE ({result['rolling_samples_per_window']} samples per window):",
        "",
        "| split | probe | " + " | ".join(heads) + " |",
        "|---|---|" + "---|" * len(heads),
    ]
    for split, probes in result["rolling_nmse"].items():
        for name, row in probes.items():
            lines.append(f"| {split} | {name} | " + " | ".join(f"{v:.4f}" for v in row) + " |")
    return "\n".join(lines)


def run_probes(  # type: ignore[no-untyped-def]
    samples, frames: np.ndarray, folds: int = 5, seed: int = 0, image: np.ndarray | None = None
) -> dict:
    """All probes on one set of samples (a DataFrame of the store) and their uint8 frames
    (``image``: their :func:`image_features`, when the caller has them already)."""
    from sklearn.ensemble import HistGradientBoostingRegressor
    from sklearn.model_selection import GroupKFold

    from tactile_compliance.runs.metrics import compute_metrics, soft_hard_labels
    from tactile_compliance.synthetic.ladder import analytical_within_decade

    y = np.log10(samples["modulus_pa"].to_numpy(dtype=np.float64))
    groups = samples["object"].to_numpy()
    from tactile_compliance.synthetic.ladder import image_statistics

    img = image_features(frames) if image is None else image
    texture = np.concatenate(
        [image_statistics(frames[i : i + 256]) for i in range(0, len(frames), 256)]
    )
    fwe = force_width_estimate_features(samples)
    inputs = {
        "image features": img,
        "F, W, log10 E": fwe,
        "F, W, E + image features": np.concatenate([fwe, img], axis=1),
        "image + texture statistics": np.concatenate([img, texture], axis=1),
    }
    materials = samples["material"].to_numpy()
    predictions = {name: np.empty_like(y) for name in ["median", "oracle material", *inputs]}
    for train, test in GroupKFold(n_splits=folds).split(y, y, groups):
        predictions["median"][test] = np.median(y[train])
        medians = {m: np.median(y[train][materials[train] == m]) for m in set(materials[train])}
        predictions["oracle material"][test] = [
            medians.get(m, np.median(y[train])) for m in materials[test]
        ]
        for name, x in inputs.items():
            model = HistGradientBoostingRegressor(random_state=seed)
            model.fit(x[train], y[train])
            predictions[name][test] = model.predict(x[test])
    true_pa = 10.0**y
    rows = {name: compute_metrics(true_pa, 10.0**pred) for name, pred in predictions.items()}
    # Soft (below the gel's 0.275 MPa) against hard objects: the paper's main finding is
    # that soft ones are easier; this says whether the data (not a model) supports it.
    stiffness = soft_hard_labels(true_pa)
    by_stiffness = {
        name: {
            band: compute_metrics(true_pa[stiffness == band], 10.0 ** pred[stiffness == band])
            for band in ("soft", "hard")
            if (stiffness == band).any()
        }
        for name, pred in predictions.items()
    }
    return {
        "samples": len(y),
        "objects": int(np.unique(groups).size),
        "probes": rows,
        "by_stiffness": by_stiffness,
        "analytical_within_one_decade": analytical_within_decade(samples),  # synthetic.ladder
    }


def real_transfer_probes(  # type: ignore[no-untyped-def]
    samples, image: np.ndarray, real_samples, real_image: np.ndarray, seed: int = 0
) -> dict:
    """The learning probes fitted on every synthetic sample, scored on real grasps.

    Returns, per probe, ``real_grasps.score`` over the real grasps (each grasp's prediction
    the geometric mean over its samples) and ``per_object`` (true E and mean prediction).
    """
    from sklearn.ensemble import HistGradientBoostingRegressor

    from real_grasps import per_object, score

    def inputs(rows, img: np.ndarray) -> dict[str, np.ndarray]:  # type: ignore[no-untyped-def]
        fwe = force_width_estimate_features(rows)
        return {
            "image features": img,
            "F, W": fwe[:, :6],
            "F, W, log10 E": fwe,
            "F, W, E + image features": np.concatenate([fwe, img], axis=1),
        }

    y = np.log10(samples["modulus_pa"].to_numpy(dtype=np.float64))
    real = inputs(real_samples, real_image)
    result = {}
    for name, x in inputs(samples, image).items():
        model = HistGradientBoostingRegressor(random_state=seed).fit(x, y)
        rows = real_samples[["object", "grasp", "modulus_pa"]].assign(
            log_pa=model.predict(real[name])
        )
        grasps = [
            {
                "object": obj,
                "true_pa": float(g["modulus_pa"].iloc[0]),
                "probe_pa": float(10 ** g["log_pa"].mean()),
            }
            for (obj, _), g in rows.groupby(["object", "grasp"], sort=False)
        ]
        result[name] = {
            "score": score(grasps, "probe_pa"),
            "objects": per_object(grasps, ["probe_pa"]),
        }
    return result


def format_real_transfer(result: dict) -> str:
    """The real-transfer probes as a markdown table: one row per probe."""
    names = [row["object"] for row in next(iter(result.values()))["objects"]]
    lines = [
        "| probe | grasps within one decade | Spearman over objects | "
        + " | ".join(f"{name} [log10 Pa]" for name in names)
        + " |",
        "|---|---|---|" + "---|" * len(names),
        "| true E | | | "
        + " | ".join(
            f"{np.log10(row['true_pa']):.2f}" for row in result[next(iter(result))]["objects"]
        )
        + " |",
    ]
    for name, probe in result.items():
        sc = probe["score"]
        rho = "-" if sc.get("spearman_objects") is None else f"{sc['spearman_objects']:.2f}"
        within = round(sc["within_one_decade"] * sc["n_grasps"])
        lines.append(
            f"| {name} | {within}/{sc['n_grasps']} | {rho} | "
            + " | ".join(f"{np.log10(row['probe_pa']):.2f}" for row in probe["objects"])
            + " |"
        )
    return "\n".join(lines)


def _rows(store, finger: str):  # type: ignore[no-untyped-def]
    """A store's samples of one finger ("all": every row) and their uint8 frames."""
    samples = store.samples
    if finger != "all":
        samples = samples[samples["finger"] == finger].reset_index(drop=True)
    return samples, store.read_samples(samples["sample_id"].to_numpy())


def format_table(result: dict) -> str:
    """The probes as a markdown table."""
    lines = [
        f"{result['samples']} samples, {result['objects']} objects, "
        "UnSeen 5-fold GroupKFold by object",
        "",
        "| probe | N-MSE | log10 accuracy | R^2 | MAE [dex] |",
        "|---|---|---|---|---|",
    ]
    order = [
        "image features",
        "median",
        "F, W, log10 E",
        "F, W, E + image features",
        "image + texture statistics",
        "oracle material",
    ]
    for name in order:
        m = result["probes"][name]
        lines.append(
            f"| {name} | {m['nmse']:.4f} | {m['log10_accuracy']:.3f} | {m['r2']:.3f} "
            f"| {m['mae_decades']:.2f} |"
        )
    a = result["analytical_within_one_decade"]
    lines.append(
        f"| analytical within one decade (no learning) | - | elastic {a['elastic']:.3f}, "
        f"Hertz->E {a['hertz_as_e']:.3f}, either {a['either']:.3f} | - | - |"
    )
    lines += [
        "",
        "| probe | soft (< 0.275 MPa) N-MSE, log10 acc. | hard N-MSE, log10 acc. |",
        "|---|---|---|",
    ]
    for name in order:
        bands = result["by_stiffness"][name]
        cells = [
            f"{bands[b]['nmse']:.4f}, {bands[b]['log10_accuracy']:.3f}" if b in bands else "-"
            for b in ("soft", "hard")
        ]
        lines.append(f"| {name} | {cells[0]} | {cells[1]} |")
    img, all_ = result["probes"]["image features"], result["probes"]["F, W, E + image features"]
    med = result["probes"]["median"]
    lines += [
        "",
        f"image-only N-MSE / all N-MSE = {img['nmse'] / all_['nmse']:.2f} "
        f"(target <= 1.3); image-only / median = {img['nmse'] / med['nmse']:.2f}",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    """``python benchmarks/calibrate_synthetic.py STORE``: print the probe table."""
    from tactile_compliance.data.store import GraspStore

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("store", type=Path, help="a GraspStore directory")
    parser.add_argument(
        "--finger", default="all", choices=["all", "markerless", "markers"], help="which rows"
    )
    parser.add_argument("--folds", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=Path, default=None, help="also write the numbers here")
    parser.add_argument(
        "--real-store", type=Path, default=None, help="also score the probes on these real grasps"
    )
    args = parser.parse_args(argv)
    start = time.perf_counter()
    samples, frames = _rows(GraspStore.open(args.store), args.finger)
    # Unknown-ground-truth objects stay in (the probe measures the generator, not the paper).
    image = image_features(frames)  # once, for both sets of probes
    result = run_probes(samples, frames, folds=args.folds, seed=args.seed, image=image)
    result["soft_hard"] = soft_hard_probes(samples, image, folds=args.folds, seed=args.seed)
    result["store"] = str(args.store)
    result["finger"] = args.finger
    result["seconds"] = round(time.perf_counter() - start, 1)
    print(format_table(result))
    print()
    print(format_soft_hard(result["soft_hard"]))
    if args.real_store:
        real_samples, real_frames = _rows(GraspStore.open(args.real_store), args.finger)
        result["real"] = real_transfer_probes(
            samples, image, real_samples, image_features(real_frames), seed=args.seed
        )
        print(f"\nfitted on every synthetic sample, scored on {args.real_store}:\n")
        print(format_real_transfer(result["real"]))
    if args.json:
        args.json.write_text(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
