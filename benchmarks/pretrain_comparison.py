r"""Frozen random vs frozen depth-pretrained backbones on UnSeen objects (issue 15).

Research script: on the demo-size synthetic store (``demo.PLANS["full"]``; ``--objects``,
``--grasps``, ``--size`` change it), for each seed the backbone of each model is pretrained
(``training.pretrain``) on the depth maps of that seed's UnSeen *training* objects only,
then the model's head is trained with

============  =================================================================
``random``     the frozen random backbone every quick preset uses today
``pretrained`` the frozen depth-pretrained backbone (``model.backbone_weights``)
``finetuned``  (``--finetune``) the pretrained backbone trained end to end
============  =================================================================

with the Table I quick settings of the model (``table1 --quick``: frozen backbone,
32x32 frames, markerless finger, small heads; ``--set KEY=VALUE`` changes them) and its
UnSeen split; the pretraining uses the same filters, split, frame size and seed as the
run. Every run also
scores the gradient-boosting scalar reference on its own split (``runs.metrics``,
``scalar_gbr``: F, W, log10 E; strategies with scalar inputs only) and the median.

Prints two markdown tables and writes every number to ``OUT/comparison.json``:

- test N-MSE (mean +- sd over the seeds), the change of the pretrained backbone against
  the random one, and the pretraining cost per seed (s);
- linear probes of the frozen cached features of the random and the pretrained backbone,
  fitted on each run's training objects and scored on its test objects
  (:func:`_feature_probes`): E (ridge N-MSE, free of the noise of a few epochs of head
  training), the material and shape classes (accuracy, and the majority class's), each
  frame's maximum indentation and contact area (R²: the contact geometry pretraining
  learns), and the E ridge from the *true* geometry instead of the features.

The issue's goal: a frozen pretrained Res-Tf beats the frozen random one by >= 15 % in
UnSeen N-MSE (mean of 3 seeds).

Usage (Res-Tf: about 20 min on the shared 2-core CPU; VGG16's pretraining alone takes
6-17 min per seed at 5 epochs)::

    python benchmarks/pretrain_comparison.py --out /tmp/pcmp
    python benchmarks/pretrain_comparison.py --out /tmp/pcmp --finetune
    python benchmarks/pretrain_comparison.py --out /tmp/pcmp --models vgg_lstm --pretrain-epochs 5
    python benchmarks/pretrain_comparison.py --out /tmp/pcmp --models res_tf vgg_lstm \
        --finetune res_tf

Reduced form (minutes): ``--seeds 1 --pretrain-epochs 5``. Re-running reuses the
generated tree, the store, the weights files, finished runs and their probes in ``OUT``
(an existing weights file is reused whatever ``--pretrain-*`` says), so a comparison can be
run in pieces (``--models``, ``--inputs``, ``--seeds``) and assembled by a last call.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

BACKBONE_OF = {"res_tf": "resnet18", "vgg_lstm": "vgg16"}


def _parse() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, required=True, help="work directory")
    parser.add_argument("--models", nargs="+", default=["res_tf"], choices=sorted(BACKBONE_OF))
    parser.add_argument("--inputs", nargs="+", default=["Image", "ALL"])
    parser.add_argument("--seeds", type=int, default=3, help="seeds 0..N-1")
    parser.add_argument("--objects", type=int, default=None, help="default: the demo's")
    parser.add_argument("--grasps", type=int, default=None, help="default: the demo's")
    parser.add_argument("--pretrain-epochs", type=int, default=30)
    parser.add_argument("--pretrain-patience", type=int, default=4)
    parser.add_argument("--pretrain-batch-size", type=int, default=16)
    parser.add_argument("--pretrain-lr", type=float, default=1e-3)
    parser.add_argument(
        "--no-pretrain-augment", action="store_true", help="pretrain without augmentation"
    )
    parser.add_argument(
        "--finetune",
        nargs="*",
        default=None,
        choices=sorted(BACKBONE_OF),
        metavar="MODEL",
        help="also train end to end (all --models, or only the MODELs named)",
    )
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        help="config override applied to every run and pretraining (repeatable)",
    )
    parser.add_argument(
        "--only-finished",
        action="store_true",
        help="assemble the tables from what OUT holds: pretrain and train nothing new",
    )
    parser.add_argument("--size", default=None, help="frame size HxW of the store (default: demo)")
    parser.add_argument("--threads", type=int, default=None, help="torch threads (default 1)")
    return parser.parse_args()


def _store(out: Path, n_objects: int | None, grasps: int | None, size: str | None) -> Path:
    """The demo-size synthetic store (with depth maps), generated and imported once."""
    from tactile_compliance.data.burgess import import_burgess
    from tactile_compliance.data.image_ops import parse_size
    from tactile_compliance.demo import PLANS
    from tactile_compliance.synthetic import generate_burgess_tree

    plan = PLANS["full"]
    raw, store = out / "raw", out / "store"
    generate_burgess_tree(
        raw,
        n_objects=n_objects or plan.n_objects,
        grasps_per_object=grasps or plan.grasps_per_object,
        seed=0,
        image_size=parse_size(size) or plan.image_size,
    )
    if not store.exists():
        print(import_burgess(raw, store).format())
    return store


def _cells(
    store: Path, models: list[str], inputs: list[str], seeds: int, out: Path, overrides: list[str]
) -> list:
    """The table1 --quick UnSeen cells of ``models`` x ``inputs`` x seeds (+ overrides)."""
    from tactile_compliance.training.experiment import plan_experiment

    plan = plan_experiment(
        "table1",
        quick=True,
        seeds=list(range(seeds)),
        store=store,
        overrides=overrides,
        where=["split.condition=unseen"],
        output_dir=out / "runs",
    )
    return [c for c in plan.cells if c.cfg.model.name in models and c.cfg.inputs in inputs]


#: Version of :func:`_feature_probes`' output, kept next to a run's cached probes.
PROBES_VERSION = 1
#: Regularisation grid of every probe (ridge alpha), chosen by cross-validation by object.
PROBE_ALPHAS = np.logspace(0, 7, 15)


def _fit_probe(make: Any, x: np.ndarray, y: np.ndarray, objects: np.ndarray, error: Any) -> Any:
    """``make(alpha)`` (a standardising linear pipeline) fitted on ``x, y`` with the alpha
    of least ``error(true, predicted)`` in 5-fold cross-validation by object: samples of
    one object share a label, so a per-sample CV would reward memorising objects and pick
    too little regularisation."""
    from sklearn.model_selection import GroupKFold

    def cv_error(alpha: float) -> float:
        folds = GroupKFold(n_splits=5).split(x, y, objects)
        return float(
            np.mean([error(y[h], make(alpha).fit(x[f], y[f]).predict(x[h])) for f, h in folds])
        )

    return make(min(PROBE_ALPHAS, key=cv_error)).fit(x, y)


def _feature_probes(cfg: Any, run_dir: Path) -> dict[str, float]:
    """Linear probes of a run's cached frozen image features, fitted on the run's training
    ids and scored on its test ids (UnSeen: test objects never seen by the probe):

    - ``e_nmse``: test N-MSE of a ridge regression from the three frames' vectors
      (standardised, concatenated) to the normalised label: what the features carry for
      E, without the noise of training a head for a few epochs;
    - ``material_accuracy`` / ``shape_accuracy``: test accuracy of a ridge classifier
      (one-vs-rest) from the same vectors to the object's material / shape class, next
      to ``*_majority``, the accuracy of always answering the training objects' most
      frequent class;
    - ``depth_max_r2`` / ``contact_area_r2``: test R² of a ridge regression from *each*
      frame's vector to that frame's contact geometry: its maximum indentation (mm, the
      store's ``depth_max_mm_*``) and its contact area (share of the stored depth map
      pressed in >= ``CONTACT_THRESHOLD_MM``), the targets depth pretraining learns;
    - ``geometry_e_nmse``: the E ridge from the *true* geometry (those two numbers of the
      three frames) instead of the features: what a backbone that encodes the contact
      geometry perfectly, and nothing else, could give a linear head.
    """
    from sklearn.linear_model import Ridge, RidgeClassifier
    from sklearn.metrics import r2_score
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    from tactile_compliance.data.features import cached_features
    from tactile_compliance.data.normalisation import denormalise_modulus, normalise_modulus
    from tactile_compliance.data.splits import Split
    from tactile_compliance.data.store import GraspStore
    from tactile_compliance.runs.metrics import nmse
    from tactile_compliance.runs.run_inputs import RunInputs
    from tactile_compliance.training.pretrain import CONTACT_THRESHOLD_MM
    from tactile_compliance.training.train import build_model

    store = GraspStore.open(cfg.data.store)
    model = build_model(cfg)
    inputs = RunInputs.resolve(cfg, store, model)  # the record train() resolved
    constants = inputs.constants
    features = cached_features(store, model.backbone, inputs.image_size, constants, progress=False)
    split = Split.load(run_dir / "split.json")
    train_ids, test_ids = split.train_ids, split.test_ids
    samples = store.samples
    objects = samples["object"].to_numpy()[train_ids]

    def ridge(alpha: float) -> Any:
        return make_pipeline(StandardScaler(), Ridge(alpha=alpha))

    def classifier(alpha: float) -> Any:
        return make_pipeline(StandardScaler(), RidgeClassifier(alpha=alpha))

    def squared(true: np.ndarray, predicted: np.ndarray) -> float:
        return float(np.mean((predicted - true) ** 2))

    def misclassified(true: np.ndarray, predicted: np.ndarray) -> float:
        return float(np.mean(predicted != true))

    def joined(ids: np.ndarray) -> np.ndarray:  # (n, 3 * feature_dim): a grasp's frames
        return np.asarray(features[ids], dtype=np.float64).reshape(len(ids), -1)

    def frames(ids: np.ndarray) -> np.ndarray:  # (3 n, feature_dim): one row per frame
        return np.asarray(features[ids], dtype=np.float64).reshape(3 * len(ids), -1)

    result: dict[str, float] = {}
    moduli = store.moduli_pa()
    probe = _fit_probe(
        ridge, joined(train_ids), normalise_modulus(moduli[train_ids], constants), objects, squared
    )
    predicted = np.clip(probe.predict(joined(test_ids)), 0.0, 1.0)
    result["e_nmse"] = nmse(moduli[test_ids], denormalise_modulus(predicted, constants), constants)
    for column in ("material", "shape"):
        labels = samples[column].astype(str).to_numpy()
        train_labels, test_labels = labels[train_ids], labels[test_ids]
        probe = _fit_probe(classifier, joined(train_ids), train_labels, objects, misclassified)
        result[f"{column}_accuracy"] = float(
            np.mean(probe.predict(joined(test_ids)) == test_labels)
        )
        values, counts = np.unique(train_labels, return_counts=True)
        result[f"{column}_majority"] = float(np.mean(test_labels == values[np.argmax(counts)]))

    depth_max = samples[[f"depth_max_mm_{k}" for k in range(3)]].to_numpy(dtype=np.float64)
    depth = store.read_depth(np.arange(len(store))).reshape(len(store), 3, -1)
    with np.errstate(invalid="ignore"):  # a frame without a depth map: NaN, left out
        pressed = np.where(np.isnan(depth), np.nan, depth >= CONTACT_THRESHOLD_MM)
        contact_area = np.nanmean(pressed, axis=2) if depth.shape[2] else depth[..., 0]
    frame_objects = np.repeat(objects, 3)
    for name, target in (("depth_max_r2", depth_max), ("contact_area_r2", contact_area)):
        y_train, y_test = target[train_ids].reshape(-1), target[test_ids].reshape(-1)
        fit, score = ~np.isnan(y_train), ~np.isnan(y_test)
        probe = _fit_probe(ridge, frames(train_ids)[fit], y_train[fit], frame_objects[fit], squared)
        result[name] = float(r2_score(y_test[score], probe.predict(frames(test_ids)[score])))

    # What perfect geometry would give: the same ridge from the *true* max depth and
    # contact area of the three frames (6 numbers) to E. The best a backbone that encodes
    # the contact geometry, and nothing else, could do.
    geometry = np.nan_to_num(np.concatenate([depth_max, contact_area], axis=1))
    probe = _fit_probe(
        ridge,
        geometry[train_ids],
        normalise_modulus(moduli[train_ids], constants),
        objects,
        squared,
    )
    predicted = np.clip(probe.predict(geometry[test_ids]), 0.0, 1.0)
    result["geometry_e_nmse"] = nmse(
        moduli[test_ids], denormalise_modulus(predicted, constants), constants
    )
    return result


def _cached_probes(cfg: Any, run_dir: Path, threads: int) -> dict[str, float]:
    """:func:`_feature_probes` of a finished run, kept in ``RUN/probes.json`` (keyed by
    :data:`PROBES_VERSION`) so that a re-run of the comparison reuses them."""
    from threadpoolctl import threadpool_limits

    from tactile_compliance.outputs import atomic_file

    path = run_dir / "probes.json"
    if path.exists():
        stored = json.loads(path.read_text())
        if stored.get("version") == PROBES_VERSION:
            return stored["probes"]
    # One BLAS thread, like torch: on a shared CPU more threads only contend (measured:
    # 4-8x slower probes at load 9).
    with threadpool_limits(threads):
        probes = _feature_probes(cfg, run_dir)
    with atomic_file(path) as handle:
        handle.write(json.dumps({"version": PROBES_VERSION, "probes": probes}) + "\n")
    return probes


def _summary(values: list[float], digits: int = 4) -> str:
    """Mean ± sample standard deviation (the mean alone for one value; "-" for none)."""
    if not values:
        return "-"
    array = np.asarray(values, dtype=float)
    if len(array) == 1:
        return f"{array.mean():.{digits}f}"
    return f"{array.mean():.{digits}f} ± {float(array.std(ddof=1)):.{digits}f}"


def main() -> None:
    args = _parse()
    import torch

    from tactile_compliance.config import apply_overrides
    from tactile_compliance.outputs import claim_output_dir
    from tactile_compliance.runs.layout import RESULT_FILE
    from tactile_compliance.training.pretrain import PretrainSettings, pretrain
    from tactile_compliance.training.train import train

    torch.set_num_threads(args.threads or 1)
    out = claim_output_dir(args.out, "pretrain-comparison")
    started = time.perf_counter()
    store = _store(out, args.objects, args.grasps, args.size)
    cells = _cells(store, args.models, args.inputs, args.seeds, out, args.overrides)
    if not cells:
        raise SystemExit("no cells: check --models and --inputs")

    # One pretraining per (model, seed): its cells share the split, filters and frame size.
    weights: dict[tuple[str, int], Path] = {}
    pretrain_cost: dict[str, list[float]] = {}
    pretrain_records: dict[str, Any] = {}
    for cell in cells:
        key = (cell.cfg.model.name, cell.cfg.seed)
        if key in weights:
            continue
        backbone = BACKBONE_OF[key[0]]
        path = out / "weights" / f"{backbone}-seed{key[1]}.pt"
        if args.only_finished and not path.exists():
            continue
        path.parent.mkdir(exist_ok=True)
        augment = "false" if args.no_pretrain_augment else "true"
        # The pretraining's own augmentation; freeze_backbone is the downstream run's
        # business (and would warn that frozen runs cannot augment).
        cfg = apply_overrides(
            cell.cfg, [f"augmentation.enabled={augment}", "model.freeze_backbone=false"]
        )
        settings = PretrainSettings(
            backbone,
            epochs=args.pretrain_epochs,
            batch_size=args.pretrain_batch_size,
            lr=args.pretrain_lr,
            patience=args.pretrain_patience,
        )
        record = pretrain(cfg, settings, path).provenance
        weights[key] = path
        pretrain_cost.setdefault(key[0], []).append(float(record["seconds"]))
        pretrain_records[f"{key[0]}-seed{key[1]}"] = {
            k: record[k]
            for k in (
                "seconds",
                "epochs",
                "best_epoch",
                "first_depth_loss_mm2",
                "final_depth_loss_mm2",
                "n_train_samples",
                "image_size",
            )
        }
        print(
            f"pretrained {backbone} seed {key[1]}: depth MSE {record['first_depth_loss_mm2']:.4g}"
            f" -> {record['final_depth_loss_mm2']:.4g} mm² in {record['seconds']:.0f} s"
        )

    finetuned = set(args.models if args.finetune == [] else args.finetune or [])
    variants = ["random", "pretrained"] + (["finetuned"] if finetuned else [])
    rows: list[dict[str, Any]] = []
    # (model, variant, seed) -> the probes of that frozen backbone's cached features
    probes: dict[tuple[str, str, int], dict[str, float]] = {}
    for cell in cells:
        path = weights.get((cell.cfg.model.name, cell.cfg.seed))
        if path is None:  # --only-finished: not pretrained
            continue
        for variant in variants:
            if variant == "finetuned" and cell.cfg.model.name not in finetuned:
                continue
            overrides = {
                "random": [],
                "pretrained": [f"model.backbone_weights={path}"],
                "finetuned": [f"model.backbone_weights={path}", "model.freeze_backbone=false"],
            }[variant]
            cfg = apply_overrides(cell.cfg, overrides)
            run_dir = (
                out
                / "runs"
                / f"{cell.cfg.model.name}-{cell.cfg.inputs}-{variant}-seed{cell.cfg.seed}"
            )
            if args.only_finished and not (run_dir / RESULT_FILE).exists():
                continue
            result = train(cfg, run_dir=run_dir, progress=False)
            reference = result.get("reference", {})
            probe_key = (cell.cfg.model.name, variant, cell.cfg.seed)
            if variant != "finetuned" and probe_key not in probes:
                probes[probe_key] = _cached_probes(cfg, run_dir, args.threads or 1)
            rows.append(
                {
                    "model": cell.cfg.model.name,
                    "inputs": cell.cfg.inputs,
                    "variant": variant,
                    "seed": cell.cfg.seed,
                    "test_nmse": result["test"]["nmse"],
                    "median_nmse": reference.get("median", {}).get("nmse"),
                    "scalar_gbr_nmse": reference.get("scalar_gbr", {}).get("nmse"),
                    "feature_probe_nmse": probes.get(probe_key, {}).get("e_nmse"),
                    "wall_time_s": result["wall_time_s"],
                }
            )
            print(
                f"{cell.cfg.model.name} {cell.cfg.inputs} {variant} seed {cell.cfg.seed}: "
                f"N-MSE {result['test']['nmse']:.4f}"
            )

    lines = [
        "| model | inputs | backbone | UnSeen N-MSE | vs random | image-feature ridge N-MSE "
        "| scalar GBR N-MSE | median N-MSE | pretraining (s per seed) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for model in args.models:
        for inputs in args.inputs:
            selected = [r for r in rows if r["model"] == model and r["inputs"] == inputs]
            if not selected:
                continue
            random_of = {r["seed"]: r["test_nmse"] for r in selected if r["variant"] == "random"}
            gbr = [r["scalar_gbr_nmse"] for r in selected if r["variant"] == "random"]
            median = [r["median_nmse"] for r in selected if r["variant"] == "random"]
            for variant in variants:
                values = [r["test_nmse"] for r in selected if r["variant"] == variant]
                seeds = [r["seed"] for r in selected if r["variant"] == variant]
                if not values:
                    continue
                # Against the random backbone on the same seeds (all, unless a piece is
                # missing: then the row names its seeds).
                same = [random_of[seed] for seed in seeds if seed in random_of]
                change = (
                    f"{100 * (np.mean(values) / np.mean(same) - 1):+.1f} %"
                    if variant != "random" and len(same) == len(values)
                    else ""
                )
                cost = _summary(pretrain_cost.get(model, []), 0) if variant != "random" else ""
                gbr_text = _summary([g for g in gbr if g is not None])
                probe = [
                    r["feature_probe_nmse"]
                    for r in selected
                    if r["variant"] == variant and r["feature_probe_nmse"] is not None
                ]
                label = "fine-tuned pretrained" if variant == "finetuned" else f"frozen {variant}"
                if len(values) < args.seeds:
                    label += f" (seeds {', '.join(map(str, seeds))})"
                lines.append(
                    f"| {model} | {inputs} | {label} | {_summary(values)} | {change} | "
                    f"{_summary(probe)} | {gbr_text} | "
                    f"{_summary([m for m in median if m is not None])} | {cost} |"
                )
    lines += [
        "",
        "| model | frozen backbone | E ridge N-MSE | material accuracy (majority) "
        "| shape accuracy (majority) | max depth R² | contact area R² "
        "| E ridge from true geometry |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for model in args.models:
        for variant in ("random", "pretrained"):
            found = [v for (m, b, _), v in sorted(probes.items()) if m == model and b == variant]
            if not found:
                continue

            def column(name: str, found: list = found) -> str:
                return _summary([v[name] for v in found], 3)

            lines.append(
                f"| {model} | {variant} | {column('e_nmse')} | {column('material_accuracy')} "
                f"({column('material_majority')}) | {column('shape_accuracy')} "
                f"({column('shape_majority')}) | {column('depth_max_r2')} "
                f"| {column('contact_area_r2')} | {column('geometry_e_nmse')} |"
            )
    table = "\n".join(lines)
    print()
    print(table)
    total = time.perf_counter() - started
    print(f"\n{len(rows)} runs, {args.seeds} seed(s), {total:.0f} s in all")
    (out / "comparison.json").write_text(
        json.dumps(
            {
                "arguments": {k: str(v) for k, v in vars(args).items()},
                "rows": rows,
                "pretraining": pretrain_records,
                "probes": [
                    {"model": m, "backbone": b, "seed": seed, **v}
                    for (m, b, seed), v in sorted(probes.items())
                ],
                "table": table,
                "seconds": total,
            },
            indent=2,
        )
        + "\n"
    )


if __name__ == "__main__":
    main()
