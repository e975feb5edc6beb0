"""Commands that train and score models: train, pretrain, evaluate, experiment, tune,
tune-balance, adapt, report."""

# typer reads the parameters' annotations at runtime and needs Optional[X] on Python 3.10.
# ruff: noqa: UP045

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Optional

import typer

from tactile_compliance.cli.framework import (
    EXIT_INTERRUPTED,
    _fail,
    _json,
    _load_config,
    _size_option,
)
from tactile_compliance.cli.options import (
    Backbone,
    BackboneWeightsOption,
    Condition,
    DeviceOption,
    FilterConfigOption,
    Inputs,
    KeepCheckpoints,
    Objective,
    SetOption,
)
from tactile_compliance.devices import DEFAULT_DEVICE

ConfigArg = Annotated[
    str, typer.Option("--config", "-c", help="YAML config file or packaged preset name.")
]


def train(
    config: ConfigArg = "default",
    overrides: SetOption = None,
    run_dir: Annotated[
        Optional[Path],
        typer.Option(
            "--out", help="Run directory to write (default: the config's output_dir/NAME)."
        ),
    ] = None,
    overwrite: Annotated[bool, typer.Option(help="Retrain a finished run.")] = False,
    size: Annotated[
        Optional[str],
        typer.Option(help="Frame size HxW the model sees (data.image_size; a --set of it wins)."),
    ] = None,
    split_file: Annotated[
        Optional[Path],
        typer.Option(
            "--split",
            help="Train on this saved split (`split STORE --out FILE`) instead of drawing one; "
            "the run takes its condition, grouping and seed.",
        ),
    ] = None,
    as_json: Annotated[
        bool, typer.Option("--json", help="Print the run's result (metrics.json) as JSON.")
    ] = False,
    keep_checkpoints: Annotated[
        KeepCheckpoints,
        typer.Option(
            help="What the finished run keeps: all (best.pt + checkpoints/last.ckpt, which "
            "only resumes an interrupted run), best (best.pt) or none."
        ),
    ] = "all",
    verbose: Annotated[
        bool,
        typer.Option(
            "--verbose",
            "-v",
            help="Also show Lightning's start-up messages (GPU available, tips, checkpoint "
            "loading) and its deprecation and housekeeping warnings.",
        ),
    ] = False,
) -> None:
    """Train one configuration and evaluate its best epoch on the test split.

    Writes a run directory (config, split, checkpoints, per-epoch log, predictions,
    metrics.json). Re-running resumes an interrupted run or returns a finished one.
    """
    image_size = _size_option(size)
    sized = {"data.image_size": image_size} if image_size else None
    # The config first, before torch loads: a typo is reported at once.
    cfg = _load_config(config, [], overrides, sized)
    from tactile_compliance.config import use_split_file
    from tactile_compliance.runs.config_checks import check_frame_size_early

    if split_file is not None:
        cfg = use_split_file(cfg, split_file)  # type: ignore[arg-type]
    check_frame_size_early(cfg)  # type: ignore[arg-type]
    from tactile_compliance.training.train import train as train_run

    result = train_run(  # --json: stdout holds the JSON only, so no progress bar
        cfg,  # type: ignore[arg-type]
        run_dir=run_dir,
        overwrite=overwrite,
        verbose=verbose,
        progress=not as_json,
    )
    from tactile_compliance.runs.layout import prune_checkpoints

    prune_checkpoints(result["run_dir"], keep_checkpoints)
    if as_json:
        typer.echo(_json(result))
        return
    test, median = result["test"], result["reference"]["median"]
    typer.echo(
        f"{result['run_name']}: best epoch {result['best_epoch']}, "
        f"test log10 accuracy {test['log10_accuracy']:.3f}, N-MSE {test['nmse']:.4f} "
        f"(median predictor {median['nmse']:.4f})\nRun directory: {result['run_dir']}"
    )


def pretrain(
    store: Annotated[Path, typer.Argument(help="GraspStore with depth maps (import --depth).")],
    backbone: Annotated[
        Backbone,
        typer.Option(help="resnet18/34/50 (Res-Tf), vgg16 (VGG-LSTM) or top10nn-cnn (Top10NN)."),
    ],
    out: Annotated[Path, typer.Option(help="The backbone weights file to write.")],
    split_file: Annotated[
        Optional[Path],
        typer.Option("--split", help="Use this split's training objects (a split JSON)."),
    ] = None,
    condition: Annotated[
        Condition,
        typer.Option(help="Without --split: draw this condition's split (unseen: by object)."),
    ] = "unseen",
    seed: Annotated[
        int, typer.Option(min=0, help="Seed of the split (without --split) and init.")
    ] = 0,
    config: FilterConfigOption = "default",
    overrides: SetOption = None,
    epochs: Annotated[int, typer.Option(min=1, help="Maximum epochs.")] = 30,
    batch_size: Annotated[int, typer.Option(min=1, help="Samples (3 frames each) per batch.")] = 16,
    lr: Annotated[float, typer.Option(min=0, help="AdamW learning rate.")] = 1e-3,
    patience: Annotated[
        int, typer.Option(min=0, help="Early-stopping patience (epochs, 0: off).")
    ] = 4,
    size: Annotated[
        Optional[str],
        typer.Option(help="Frame size HxW (default: the size the backbone's model uses)."),
    ] = None,
    overwrite: Annotated[bool, typer.Option(help="Replace a pretrained weights file.")] = False,
    device: DeviceOption = DEFAULT_DEVICE,
    as_json: Annotated[
        bool,
        typer.Option(
            "--json",
            help="Print the weights file, its provenance (settings, split, losses per epoch) "
            "and the train overrides that use it as JSON.",
        ),
    ] = False,
) -> None:
    """Pretrain a backbone to predict depth maps and contact masks from the difference images.

    Only the training objects of the split are used (never a test or validation object).
    The result loads with --set model.backbone_weights=OUT. Re-running resumes after the
    last finished epoch.
    """
    _refuse_unread_overrides(overrides)
    options = [f"data.store={store}", f"split.condition={condition}", f"seed={seed}"]
    cfg = _load_config(config, options, overrides)  # before torch loads
    from tactile_compliance.training.pretrain import PretrainSettings
    from tactile_compliance.training.pretrain import pretrain as run_pretrain

    settings = PretrainSettings(
        backbone=backbone,
        epochs=epochs,
        batch_size=batch_size,
        lr=lr,
        patience=patience,
        image_size=_size_option(size),
    )
    result = run_pretrain(
        cfg,  # type: ignore[arg-type]
        settings,
        out,
        split_file=split_file,
        overwrite=overwrite,
        device=device,
        progress=not as_json,
    )
    record = result.provenance
    use = [
        f"data.store={store}",
        f"model.name={record['model']}",
        f"model.backbone_weights={result.out}",
        "model.freeze_backbone=true",
    ]
    if as_json:
        payload = {
            "out": str(result.out),
            "existing": result.existing,
            "resumed_from_epoch": result.resumed_from_epoch,
            "provenance": record,
            "train_overrides": use,
        }
        typer.echo(_json(payload))
        return
    if result.existing:
        typer.echo(f"{out} is already pretrained (pass --overwrite to train it again).")
    typer.echo(
        f"{record['backbone']}: {record['epochs']} epochs (best {record['best_epoch']}) on "
        f"{record['n_train_samples']} samples of {record['n_train_objects']} training objects, "
        f"validation depth MSE {record['first_depth_loss_mm2']:.4g} -> "
        f"{record['final_depth_loss_mm2']:.4g} mm², {record['seconds']:.0f} s\n"
        f"Weights: {result.out}\nUse them: tactile-compliance train "
        + " ".join(f"--set {override}" for override in use)
    )


#: The config sections `pretrain` never reads: its model is --backbone, its training
#: --epochs, --batch-size, --lr, --patience and --device.
_PRETRAIN_UNREAD = ("model", "training", "sampling", "inputs", "output_dir")


def _refuse_unread_overrides(overrides: list[str] | None) -> None:
    """Refuse a `pretrain --set` of a key pretraining never reads (it would be accepted
    and have no effect)."""
    for override in overrides or []:
        key = override.split("=", 1)[0].strip()
        if key.split(".", 1)[0] in _PRETRAIN_UNREAD:
            raise typer.BadParameter(
                f"--set {key}: pretrain does not read {key} (it reads data, filters, split, "
                f"augmentation and seed; the backbone is --backbone, the training --epochs, "
                f"--batch-size, --lr, --patience and --device)"
            )


def evaluate(
    run_dir: Annotated[Path, typer.Argument(help="A finished run directory.")],
    store: Annotated[Optional[Path], typer.Option(help="Evaluate on this store instead.")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON.")] = False,
    weights: BackboneWeightsOption = None,
    device: DeviceOption = DEFAULT_DEVICE,
) -> None:
    """Recompute metrics (overall, per material, shape, soft/hard) from a run's checkpoint."""
    from tactile_compliance.evaluation.evaluate import evaluate_run

    evaluation = evaluate_run(run_dir, store, backbone_weights=weights, device=device)
    groups = evaluation.groups
    # R^2 is undefined (NaN) for a group whose true moduli are all equal: said, not shown
    # as a number (JSON: null).
    undefined = "r2" in groups.columns and bool(groups["r2"].isna().any())
    if as_json:
        records = groups.astype(object).where(groups.notna(), None).to_dict(orient="records")
        metrics = {
            k: None if isinstance(v, float) and v != v else v for k, v in evaluation.metrics.items()
        }
        typer.echo(_json({"metrics": metrics, "groups": records}))
        return
    typer.echo(groups.to_string(index=False, float_format=lambda v: f"{v:.4f}", na_rep="n/a"))
    if undefined:
        typer.echo(
            "r2 n/a: the group's true moduli are all equal, so there is no variance to explain"
        )


WorkersOption = Annotated[
    int, typer.Option("--workers", "-w", min=1, help="Local Dask worker processes.")
]


SchedulerOption = Annotated[
    Optional[str],
    typer.Option(
        "--scheduler",
        help="Address (tcp://host:8786) or scheduler file of a "
        "running Dask scheduler, e.g. one started by dask-jobqueue on SLURM/PBS.",
    ),
]


StoreOption = Annotated[
    Optional[Path],
    typer.Option("--store", help="GraspStore for every run (default: the preset's)."),
]


OutputDirOption = Annotated[
    Optional[Path],
    typer.Option("--out", help="Where run directories go.", show_default="the preset's"),
]


QuickOption = Annotated[
    bool, typer.Option("--quick", help="The preset's small variant for a 2-core CPU.")
]


ThreadsOption = Annotated[
    Optional[int],
    typer.Option(min=1, help="Torch threads per run (default 1: one run per worker and core)."),
]


ConditionOption = Annotated[
    Optional[Condition],
    typer.Option(help="Split condition (unseen: by object).", show_default="the config's"),
]


ObjectiveOption = Annotated[
    Objective,
    typer.Option(
        help="A trial's cost: the validation N-MSE of its last epoch (as in the paper; the "
        "trial trains its whole budget) or of its best epoch (with early stopping)."
    ),
]


InputsOption = Annotated[Inputs, typer.Option(help="Input strategy whose search space is used.")]


TuneJsonOption = Annotated[
    bool,
    typer.Option("--json", help="Print the best values, their cost and the files written as JSON."),
]


def experiment(
    preset: Annotated[str, typer.Argument(help="Experiment preset (see `presets`) or YAML file.")],
    quick: QuickOption = False,
    seeds: Annotated[
        Optional[int], typer.Option(min=1, help="Number of seeds (0..N-1); default: the preset's.")
    ] = None,
    store: StoreOption = None,
    overrides: SetOption = None,
    where: Annotated[
        Optional[list[str]],
        typer.Option(
            metavar="KEY=VALUE",
            help="Run only matching cells: --where model.name=res_tf (repeatable).",
        ),
    ] = None,
    workers: WorkersOption = 1,
    scheduler: SchedulerOption = None,
    output_dir: OutputDirOption = None,
    results: Annotated[
        Optional[Path], typer.Option(help="Results store directory (default: runs/results).")
    ] = None,
    threads: ThreadsOption = None,
    keep_checkpoints: Annotated[
        KeepCheckpoints,
        typer.Option(help="What a finished run keeps: best (best.pt), all (+ last.ckpt), none."),
    ] = "best",
    retry_failed: Annotated[
        bool, typer.Option(help="Re-run cells recorded as failed (--no-retry-failed skips them).")
    ] = True,
    dry_run: Annotated[
        bool, typer.Option("--dry-run", help="List the cells and their status; run nothing.")
    ] = False,
    as_json: Annotated[
        bool,
        typer.Option(
            "--json",
            help="Print the summary (counts, failures, mean +- std per configuration) or, "
            "with --dry-run, the cells as JSON.",
        ),
    ] = False,
) -> None:
    """Run an experiment grid (models x inputs x conditions x sampling x seeds) on Dask.

    Every cell goes through `train`; each result is a row of the results store.
    Re-running skips finished cells and retries failed or interrupted ones. Exits with
    status 1 when a cell failed and 130 when interrupted (re-run to continue).
    """
    from tactile_compliance.training.experiment import plan_experiment, run_experiment

    common = dict(
        quick=quick,
        seeds=seeds,
        store=store,
        overrides=overrides or [],
        where=where or [],
        output_dir=output_dir,
        results=results,
    )
    if dry_run:
        plan = plan_experiment(preset, **common)  # type: ignore[arg-type]
        typer.echo(_json(plan.to_dict()) if as_json else plan.format())
        return
    try:
        summary = run_experiment(
            preset,
            workers=workers,
            scheduler=scheduler,
            threads=threads,
            keep_checkpoints=keep_checkpoints,
            retry_failed=retry_failed,
            **common,  # type: ignore[arg-type]
        )
    except KeyboardInterrupt:  # the summary is already on stderr
        raise typer.Exit(EXIT_INTERRUPTED) from None
    typer.echo(_json(summary.to_dict()) if as_json else summary.format())
    if summary.failed:
        _fail(f"{summary.failed} cell(s) failed (recorded with their errors); re-run to retry")


def tune(
    model: Annotated[str, typer.Argument(help="A registered model (top10nn, vgg_lstm, ...).")],
    inputs: InputsOption = "ALL",
    config: Annotated[
        str, typer.Option("--config", "-c", help="Base config or experiment preset.")
    ] = "default",
    quick: QuickOption = False,
    store: StoreOption = None,
    overrides: SetOption = None,
    trials: Annotated[int, typer.Option(min=1, help="SMAC trials.")] = 132,
    min_epochs: Annotated[int, typer.Option(min=1, help="Smallest Hyperband budget (epochs).")] = 5,
    max_epochs: Annotated[int, typer.Option(min=1, help="Largest Hyperband budget (epochs).")] = 50,
    eta: Annotated[int, typer.Option(min=2, help="Hyperband's reduction factor.")] = 3,
    objective: ObjectiveOption = "last",
    condition: ConditionOption = None,
    seed: Annotated[int, typer.Option(min=0, help="SMAC seed.")] = 0,
    workers: WorkersOption = 1,
    scheduler: SchedulerOption = None,
    threads: ThreadsOption = None,
    output_dir: OutputDirOption = None,
    overwrite: Annotated[bool, typer.Option(help="Start the search afresh.")] = False,
    as_json: TuneJsonOption = False,
) -> None:
    """Tune a model's hyperparameters with SMAC3 (Hyperband over epochs, val N-MSE).

    The defaults are the paper's search: 132 trials, 5-50 epochs, each trial scored on its
    last epoch. Resumes from SMAC's run history; writes best.yaml, usable by `train` and
    `experiment`.
    """
    _run_search("tune", dict(locals()))


def tune_balance(
    config: Annotated[
        str, typer.Option("--config", "-c", help="Experiment preset or config to tune.")
    ] = "table2",
    quick: QuickOption = False,
    store: StoreOption = None,
    overrides: SetOption = None,
    epochs: Annotated[
        Optional[int],
        typer.Option(
            min=1, help="Epochs per model and trial.", show_default="10; 50 with --paper-budget"
        ),
    ] = None,
    trials: Annotated[
        Optional[int],
        typer.Option(min=1, help="SMAC trials.", show_default="30; 132 with --paper-budget"),
    ] = None,
    paper_budget: Annotated[
        bool,
        typer.Option(
            "--paper-budget",
            help="The paper's budget: 132 trials of 50 epochs per model (explicit "
            "--epochs / --trials still win).",
        ),
    ] = False,
    objective: ObjectiveOption = "last",
    models: Annotated[
        str, typer.Option(help="Comma-separated models whose mean val N-MSE is the cost.")
    ] = "top10nn,vgg_lstm,res_tf",
    inputs: Annotated[Inputs, typer.Option(help="Input strategy of every model.")] = "ALL",
    condition: Annotated[
        Condition, typer.Option(help="Split condition (unseen: by object).")
    ] = "seen",
    seed: Annotated[int, typer.Option(min=0, help="SMAC seed.")] = 0,
    workers: WorkersOption = 1,
    scheduler: SchedulerOption = None,
    threads: ThreadsOption = None,
    output_dir: OutputDirOption = None,
    overwrite: Annotated[bool, typer.Option(help="Start the search afresh.")] = False,
    as_json: TuneJsonOption = False,
) -> None:
    """Tune the balance threshold t_balance in [0, 1] with SMAC3.

    Cost of a value: the mean validation N-MSE of the three models after a fixed number
    of epochs (of the last epoch, as in the paper, or --objective best). The default
    budget, 30 trials of 10 epochs, is sized for a CPU; --paper-budget is the paper's
    132 x 50. Writes a config with the best t_balance.
    """
    options = dict(locals())
    options["models"] = [m.strip() for m in models.split(",") if m.strip()]
    _run_search("tune_balance", options)


def _run_search(name: str, options: dict[str, Any]) -> None:
    """Run the SMAC search ``training.hpo.<name>`` and print its result.

    ``options`` are the command's parameters, which are named like the search function's
    keyword arguments. Expected errors become one line.
    """
    from tactile_compliance.training import hpo

    options["overrides"] = options["overrides"] or []
    as_json = options.pop("as_json")
    result = getattr(hpo, name)(**options)
    typer.echo(_json(result.to_dict()) if as_json else result.format())


def adapt(
    model: Annotated[
        Path, typer.Argument(help="A simulation-trained checkpoint (best.pt or a run directory).")
    ],
    reference_store: Annotated[
        Path,
        typer.Argument(
            help="A store of grasps of reference objects of known modulus on your rig "
            "(`record`, then `import burgess`)."
        ),
    ],
    out: Annotated[Path, typer.Option(help="Directory for best.pt and adapt.json.")],
    ridge: Annotated[
        float,
        typer.Option(
            min=0.0,
            help="How strongly the calibration's slope is pulled towards 1 (a pure shift); "
            "docs/inference.md.",
        ),
    ] = 1.0,
    device: DeviceOption = DEFAULT_DEVICE,
    as_json: Annotated[bool, typer.Option("--json", help="Print the summary as JSON.")] = False,
) -> None:
    """Adapt a model to your rig from grasps of reference objects of known modulus: an
    output calibration in log10 space, fitted on them, with leave-one-object-out scores.
    Writes OUT/best.pt, which `predict` and `live` take (they apply the calibration)."""
    from tactile_compliance.inference.adapt import adapt_model

    summary = adapt_model(model, reference_store, out, ridge=ridge, device=device)
    typer.echo(_json(summary.to_dict()) if as_json else summary.format())


def report(
    results: Annotated[
        Path,
        typer.Argument(
            help="Results store directory (holds rows/*.json), or one run directory (holds "
            "metrics.json): its metrics and predicted-against-true figure."
        ),
    ],
    out: Annotated[
        Optional[Path],
        typer.Option("--out", "-o", help="Output directory (default: RESULTS/report)."),
    ] = None,
    formats: Annotated[
        str, typer.Option("--format", "-f", help="Comma-separated formats: md, html, tex.")
    ] = "md,html",
    stores: Annotated[
        Optional[list[Path]],
        typer.Option("--store", help="Extra GraspStore to draw in Fig. 1 (repeatable)."),
    ] = None,
    as_json: Annotated[
        bool, typer.Option("--json", help="Print what was written and skipped as JSON.")
    ] = False,
) -> None:
    """Build the paper's tables and figures from a results store (Markdown, HTML, LaTeX).

    Given one run directory, report that run: its metrics table and its predicted against
    true figure. Parts whose runs are missing are skipped with a note naming the preset
    that produces them; only complete runs count; failed runs are listed.
    """
    from tactile_compliance.evaluation.report import build_report

    summary = build_report(results, out, formats=formats, stores=stores or ())
    payload = {
        "results_dir": str(summary.results_dir),
        "out_dir": str(summary.out_dir),
        "documents": {k: str(v) for k, v in summary.documents.items()},
        "figures": {k: str(v) for k, v in summary.figures.items()},
        "tables": sorted(summary.tables),
        "notes": summary.notes,
        "rows": summary.n_rows,
        "complete": summary.n_complete,
        "failed": summary.n_failed,
    }
    typer.echo(_json(payload) if as_json else str(summary))
