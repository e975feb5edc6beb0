"""sim2real: a model for a real GelSight rig, trained on synthetic grasps only.

Generates grasps of a real rig (``simulate --rig``), imports them, trains the packaged
``sim2real`` configuration and copies the best epoch to ``DIR/best.pt``. See
docs/results.md, "A model trained on simulation only".
"""

from __future__ import annotations

import json
import shutil
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

from tactile_compliance.devices import DEFAULT_DEVICE

Sim2RealMode = Literal["full", "ci"]

CONFIG = "sim2real"
"""The packaged training configuration (``configs/sim2real.yaml``)."""

MIN_SYNTHETIC_R2 = 0.05
"""Below this R^2 on unseen synthetic objects the summary warns that the model learned
next to nothing (the earlier recipe's runs: -0.05 to 0.11; this recipe's: 0.19 to 0.40)."""


@dataclass(frozen=True)
class Sim2RealPlan:
    """Sizes of one mode: the synthetic data and the training budget."""

    n_objects: int
    grasps_per_object: int
    image_size: tuple[int, int]  # (height, width) px of the generated frames
    overrides: tuple[str, ...] = ()


PLANS: dict[str, Sim2RealPlan] = {
    # ~10 minutes on 2 CPU cores (docs/results.md): many objects at a low resolution,
    # because the model sees 32 x 32 px and unseen objects are what it must handle.
    "full": Sim2RealPlan(n_objects=400, grasps_per_object=3, image_size=(64, 88)),
    # The same path in seconds, for the test suite.
    "ci": Sim2RealPlan(
        n_objects=12, grasps_per_object=2, image_size=(48, 64), overrides=("training.max_epochs=1",)
    ),
}


@dataclass
class Sim2RealSummary:
    """What ``sim2real`` wrote, how long each stage took and the synthetic test scores."""

    out_dir: Path
    checkpoint: Path
    rig: str
    mode: str
    stage_seconds: dict[str, float] = field(default_factory=dict)
    synthetic_test: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        data = asdict(self)
        data["out_dir"], data["checkpoint"] = str(self.out_dir), str(self.checkpoint)
        return data

    def format(self) -> str:
        stages = ", ".join(f"{name} {sec:.0f} s" for name, sec in self.stage_seconds.items())
        test = self.synthetic_test
        scores = (
            f"On unseen synthetic objects: N-MSE {test['nmse']:.4f}, R^2 {test['r2']:.2f}, "
            f"log10 accuracy {test['log10_accuracy']:.2f}."
            if test
            else ""
        )
        # A model that learned nothing on unseen synthetic objects predicts a near-constant
        # modulus on real ones (docs/results.md, "How the recipe was chosen").
        warning = (
            f"Warning: the model explains almost none of the modulus of unseen synthetic "
            f"objects (R^2 {test['r2']:.2f} < {MIN_SYNTHETIC_R2}); it cannot rank real "
            f"objects either. Try another --seed.\n"
            if test and self.mode == "full" and test["r2"] < MIN_SYNTHETIC_R2
            else ""
        )
        return (
            f"sim2real ({self.rig} rig) finished in {sum(self.stage_seconds.values()):.0f} s "
            f"({stages}). {scores}\n{warning}"
            f"Model: {self.checkpoint} (trained on synthetic grasps only).\n"
            f"Next: tactile-compliance predict {self.checkpoint} STORE, or "
            f"tactile-compliance live {self.checkpoint} SOURCE ..."
        )


def run_sim2real(
    out_dir: str | Path,
    *,
    rig: str | Path = "wedge-2023",
    mode: Sim2RealMode = "full",
    seed: int = 0,
    workers: int | None = None,
    device: str = DEFAULT_DEVICE,
    progress: bool = True,
    echo: Callable[[str], None] = print,
) -> Sim2RealSummary:
    """Generate, import and train under ``out_dir``; the model is ``out_dir/best.pt``.

    No real grasp is read: the rig (a packaged one, or the file ``calibrate-rig`` fitted
    on the user's own recordings) is the only thing fitted on real data. The same
    ``seed`` and rig give the same generated grasps on any machine.

    Args:
        out_dir: created, or one that ``sim2real`` wrote before (it then continues:
            generated objects, the store and a finished or interrupted run are kept).
        rig: a name of ``synthetic.rig.RIGS`` or a rig file that ``calibrate-rig`` wrote
            (``simulate --rig``).
        mode: ``full`` or ``ci`` (a tiny run for tests).
        workers: generator processes (default: all CPUs).
        echo: where the import report goes (``--json`` sends it to stderr).

    Raises:
        OutputExistsError: ``out_dir`` holds something ``sim2real`` did not write.
        GenerationError: an unknown rig or an invalid rig file.
    """
    from tactile_compliance.config import load_config
    from tactile_compliance.data.burgess import import_burgess
    from tactile_compliance.outputs import atomic_file, claim_output_dir
    from tactile_compliance.runs.layout import prune_checkpoints
    from tactile_compliance.synthetic import GenerationError, generate_burgess_tree
    from tactile_compliance.synthetic.rig import resolve_rig
    from tactile_compliance.training.train import train

    plan = PLANS[mode]
    try:
        resolve_rig(rig)  # a bad rig file fails before anything is written
    except ValueError as err:
        raise GenerationError(str(err)) from err
    out = claim_output_dir(out_dir, "sim2real")
    summary = Sim2RealSummary(out_dir=out, checkpoint=out / "best.pt", rig=str(rig), mode=mode)

    start = time.perf_counter()
    raw = out / "raw"
    options: dict[str, Any] = {"rig": rig} | ({"workers": workers} if workers else {})
    generate_burgess_tree(
        raw,
        n_objects=plan.n_objects,
        grasps_per_object=plan.grasps_per_object,
        seed=seed,
        image_size=plan.image_size,
        progress=progress,
        **options,
    )
    summary.stage_seconds["generate"] = time.perf_counter() - start

    start = time.perf_counter()
    store = out / "store"
    if not store.exists():
        echo(import_burgess(raw, store, progress=progress).format())
    summary.stage_seconds["import"] = time.perf_counter() - start

    start = time.perf_counter()
    cfg = load_config(
        CONFIG,
        [
            f"data.store={store}",
            f"seed={seed}",
            f"training.device={device}",
            *plan.overrides,
        ],
    )
    metrics = train(cfg, run_dir=out / "run", progress=progress)  # type: ignore[arg-type]
    # The resume checkpoint (53 MB for the full mode) serves only an interrupted run.
    prune_checkpoints(out / "run", "best")
    summary.stage_seconds["train"] = time.perf_counter() - start
    summary.synthetic_test = dict(metrics.get("test", {}))

    with (
        atomic_file(summary.checkpoint, "wb") as handle,
        open(out / "run" / "best.pt", "rb") as best,
    ):
        shutil.copyfileobj(best, handle)
    with atomic_file(out / "sim2real.json", "w") as handle:
        handle.write(json.dumps(summary.to_dict(), indent=2) + "\n")
    return summary
