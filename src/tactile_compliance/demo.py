"""The one-command demo: synthetic data -> stores -> quick experiment grids -> report.

It exercises every layer on built-in synthetic data within minutes on a 2-core CPU;
``--mode ci`` runs the same path in seconds, for the test suite.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

if TYPE_CHECKING:
    from tactile_compliance.data.import_report import ImportReport

DemoMode = Literal["full", "ci"]


@dataclass(frozen=True)
class DemoPlan:
    """Sizes of one demo mode."""

    n_objects: int
    grasps_per_object: int
    image_size: tuple[int, int]  # (height, width) px of the generated frames
    shore_objects: int
    presets: tuple[str, ...]  # quick experiment presets run on the GelSight store
    seeds: int | None  # None: the quick presets' own seed count
    where: tuple[str, ...] = ()  # grid filters (ci: a few cells only)
    overrides: tuple[str, ...] = ()


# Sized for <= 10 minutes on a 2-core CPU with models that converge (before the 9 cells
# beyond the paper were added; not re-measured): Table I (quick) with
# one seed, 36 runs (3 models x 4 inputs x 3 object conditions), each trained until early
# stopping, plus the Shore-hardness grid (120 silicone samples x 3 presses: Table III needs
# a few hundred training presses to learn hardness). Many objects at a low resolution
# rather than few at a high one: the UnSeen condition needs objects of each material grade
# on both sides of the split, and the quick models see 65 x 65 (Top10NN) or 32 x 32 px
# frames anyway.
_FULL = DemoPlan(
    n_objects=90,
    grasps_per_object=2,
    image_size=(64, 88),
    shore_objects=120,
    # Table I, then the strategies beyond the paper on the same store (3 frame-free
    # cells of seconds, 3 depth-map Top10NN cells like Table I's).
    presets=("table1", "beyond-paper"),
    seeds=1,
)
# The report says what the demo trades away: VGG-LSTM and Res-Tf keep frozen random
# backbones because fine-tuning them does not fit 10 minutes on 2 CPU cores (a fine-tuned
# Res-Tf at 64 x 64 px takes ~6 minutes for one Shore run alone, docs/results.md).
DEMO_REPORT_TITLE = (
    "Young's modulus from GelSight grasps — the demo on synthetic data (VGG-LSTM and Res-Tf "
    "on frozen random backbones: fine-tuning does not fit the demo's 10 minutes on 2 CPU "
    "cores)"
)
PLANS: dict[str, DemoPlan] = {
    "full": _FULL,
    # The same path in seconds: a tiny dataset, one grid cell, one epoch.
    "ci": replace(
        _FULL,
        n_objects=12,
        grasps_per_object=2,
        image_size=(72, 96),
        shore_objects=6,
        presets=("table1",),
        where=("model.name=top10nn", "inputs=ALL", "split.condition=seen", "split.grouping=grasp"),
        overrides=("training.max_epochs=1",),
    ),
}


@dataclass
class DemoSummary:
    """Where the demo put things and how long each stage took (seconds)."""

    out_dir: Path
    report: Path | None
    stage_seconds: dict[str, float] = field(default_factory=dict)
    #: What each stage printed, as dictionaries: the import reports (stores imported by
    #: this call) and the summaries of the experiment grids.
    imports: list[dict[str, Any]] = field(default_factory=list)
    experiments: list[dict[str, Any]] = field(default_factory=list)

    def format(self) -> str:
        stages = ", ".join(
            f"{name} {seconds:.0f} s" for name, seconds in self.stage_seconds.items()
        )
        total = sum(self.stage_seconds.values())
        return (
            f"Demo finished in {total:.0f} s ({stages}).\n"
            f"Everything is in {self.out_dir}; open the report: {self.report}"
        )

    def to_dict(self) -> dict[str, Any]:
        """What the demo printed, for ``--json``."""
        return {
            "out_dir": str(self.out_dir),
            "report": None if self.report is None else str(self.report),
            "stage_seconds": {k: round(v, 2) for k, v in self.stage_seconds.items()},
            "total_s": round(sum(self.stage_seconds.values()), 2),
            "imports": self.imports,
            "experiments": self.experiments,
        }


def run_demo(
    out_dir: str | Path = "demo-output",
    *,
    mode: DemoMode = "full",
    workers: int | None = None,
    progress: bool = True,
    echo: Callable[[str], None] = print,
) -> DemoSummary:
    """Generate, import, train the quick grids and build the report under ``out_dir``.

    ``workers`` are the grid's Dask worker processes (single-threaded each); ``None``
    uses every available CPU up to 4 in ``full`` mode (independent runs scale almost
    linearly: 1.75x from 1 to 2 workers on 2 cores, docs/experiments.md) and one
    worker in ``ci`` mode. Re-running continues where a previous run stopped:
    generated objects, stores and finished grid cells are kept. Each import report and
    grid summary is passed to ``echo`` as text when its stage ends (and kept in the
    summary).
    """
    from tactile_compliance.data.burgess import import_burgess
    from tactile_compliance.data.yuan import import_yuan
    from tactile_compliance.evaluation.report import build_report
    from tactile_compliance.outputs import claim_output_dir
    from tactile_compliance.synthetic import generate_burgess_tree, generate_shore_videos
    from tactile_compliance.training.cluster import available_cpus
    from tactile_compliance.training.experiment import run_experiment

    plan = PLANS[mode]
    if workers is None:
        workers = 1 if mode == "ci" else min(available_cpus(), 4)
    out = claim_output_dir(out_dir, "demo")
    summary = DemoSummary(out_dir=out, report=None)

    def stage(name: str, start: float) -> None:
        summary.stage_seconds[name] = summary.stage_seconds.get(name, 0.0) + (
            time.perf_counter() - start
        )

    def imported(report: ImportReport) -> None:
        echo(report.format())
        summary.imports.append(report.to_dict())

    start = time.perf_counter()
    generate_burgess_tree(
        out / "raw" / "gelsight",
        n_objects=plan.n_objects,
        grasps_per_object=plan.grasps_per_object,
        seed=0,
        image_size=plan.image_size,
        progress=progress,
    )
    generate_shore_videos(
        out / "raw" / "shore",
        n_objects=plan.shore_objects,
        seed=0,
        image_size=plan.image_size,
        progress=progress,
    )
    stage("generate", start)

    start = time.perf_counter()
    gelsight_store, shore_store = out / "stores" / "gelsight", out / "stores" / "shore"
    if not gelsight_store.exists():
        imported(import_burgess(out / "raw" / "gelsight", gelsight_store, progress=progress))
    if not shore_store.exists():
        imported(import_yuan(out / "raw" / "shore", shore_store, progress=progress))
    stage("import", start)

    start = time.perf_counter()
    results = out / "results"
    jobs = [(preset, gelsight_store) for preset in plan.presets]
    if mode == "full":
        jobs.append(("new-dataset", shore_store))
    for preset, store in jobs:
        experiment = run_experiment(
            preset,
            quick=True,
            seeds=plan.seeds,
            store=store,
            where=plan.where,
            overrides=plan.overrides,
            workers=workers,
            output_dir=out / "runs",
            results=results,
            progress=progress,
        )
        echo(experiment.format())
        summary.experiments.append(experiment.to_dict())
    stage("train", start)

    start = time.perf_counter()
    report = build_report(
        results,
        out / "report",
        formats=("md", "html"),
        stores=(gelsight_store,),
        title=DEMO_REPORT_TITLE,
    )
    summary.report = report.documents.get("html") or next(iter(report.documents.values()))
    stage("report", start)
    return summary
