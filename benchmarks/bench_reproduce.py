"""Time and memory of reproducing Table I / Table III on a CPU, measured on synthetic data
of the real size and extrapolated (docs/reproduce.md, "Time and memory").

    python benchmarks/bench_reproduce.py [--part import|train|all] [--dirs 200]
        [--samples 7840] [--size 250x350] [--batches 4] [--val-batches 2]
        [--models top10nn,vgg_lstm,res_tf] [--threads 1] [--workdir /tmp] [--json OUT]

1. ``import``: a tree of ``--dirs`` augmentation directories in the dataset's exact
   layout (float32 pickles, both fingers, 5 grasps x 5 augmentations per object) at
   ``--size``: seconds of the download check (``check_burgess_download``) per file, of
   ``import burgess`` per store sample (in a child process, with its peak RSS), and bytes
   per store sample.
2. ``train``: a ``--samples``-sample random-frame store at ``--size`` (the real dataset's
   7,840 samples at 250 x 350: 6.2 GB, under ``--workdir``), then for each model one
   child process that trains the full ``table1`` preset's cell (ALL inputs, Seen
   grasp-grouped, seed 0: the paper's settings, fine-tuned backbone, augmentation)
   through the real Lightning module for ``--batches`` training batches (the first is
   warm-up and not counted) and ``--val-batches`` validation batches, and reports the
   seconds per batch, the split sizes and the child's peak RSS.

It then prints the extrapolation (seconds per epoch and per run) with its inputs. Nothing
is trained to the end; the tree and store are deleted afterwards.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))
sys.path.insert(0, str(HERE))

IMPORT_CHILD = """
import json, sys, time
from tactile_compliance.data.burgess import import_burgess
start = time.perf_counter()
report = import_burgess(sys.argv[1], sys.argv[2], progress=False)
seconds = time.perf_counter() - start
status = dict(line.split(":", 1) for line in open("/proc/self/status") if ":" in line)
print(json.dumps({"samples": report.samples_imported, "seconds": seconds,
                  "peak_kib": int(status["VmHWM"].split()[0])}))
"""

# One table1 cell through the real module: Lightning's fit with limited batches and a
# callback timing each batch. train() itself would end with a forward pass over the whole
# store (predictions.csv), hours for VGG16 on a CPU, so the module is driven directly.
TRAIN_CHILD = """
import json, sys, time, warnings, logging
import lightning as L
from tactile_compliance.data.augment import GraspAugmentation
from tactile_compliance.data.dataset import GraspDataset, batch_loader
from tactile_compliance.training.experiment import plan_experiment
from tactile_compliance.training.module import ComplianceModule
from tactile_compliance.training.train import build_model, prepare_data
for name in ("lightning.pytorch", "lightning.fabric"):
    logging.getLogger(name).setLevel(logging.ERROR)
warnings.filterwarnings("ignore")
store, model_name = sys.argv[1], sys.argv[2]
batches, val_batches, threads = int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5])
import torch
torch.set_num_threads(threads)  # as `experiment --threads` (default 1 per run)
plan = plan_experiment("table1", store=store, seeds=1,
                       where=[f"model.name={model_name}", "inputs=ALL",
                              "split.condition=seen", "split.grouping=grasp"])
cfg = plan.cells[0].cfg
L.seed_everything(0, workers=True, verbose=False)
model = build_model(cfg)
data = prepare_data(cfg, model)
augmentation = (GraspAugmentation.from_config(cfg.augmentation, seed=0)
                if cfg.augmentation.enabled and not cfg.model.freeze_backbone else None)
module = ComplianceModule(model, data.run_inputs, lr=cfg.training.lr, gamma=cfg.training.gamma,
                          l2_weight=cfg.training.l2_weight, augmentation=augmentation,
                          freeze_backbone=cfg.model.freeze_backbone, finetune=cfg.model.finetune)
def loader(ids, shuffle):
    dataset = GraspDataset(data.store, ids, data.run_inputs.constants, data.run_inputs.inputs)
    return batch_loader(dataset, cfg.training.batch_size, shuffle=shuffle)
class Clock(L.Callback):
    # wall and CPU seconds (this process, all its threads) of each batch
    def __init__(self):
        self.train, self.val, self.train_cpu, self.val_cpu = [], [], [], []
    def _start(self):
        self.t, self.c = time.perf_counter(), time.process_time()
    def on_train_batch_start(self, *a):
        self._start()
    def on_train_batch_end(self, *a):
        self.train.append(time.perf_counter() - self.t)
        self.train_cpu.append(time.process_time() - self.c)
    def on_validation_batch_start(self, *a):
        self._start()
    def on_validation_batch_end(self, *a):
        self.val.append(time.perf_counter() - self.t)
        self.val_cpu.append(time.process_time() - self.c)
clock = Clock()
trainer = L.Trainer(max_epochs=1, accelerator="cpu", logger=False, enable_checkpointing=False,
                    enable_progress_bar=False, enable_model_summary=False,
                    num_sanity_val_steps=0, limit_train_batches=batches,
                    limit_val_batches=val_batches, callbacks=[clock], deterministic=True)
trainer.fit(module, loader(data.train_ids, True), loader(data.val_ids, False))
status = dict(line.split(":", 1) for line in open("/proc/self/status") if ":" in line)
print(json.dumps({"model": model_name, "batch_size": cfg.training.batch_size,
                  "image_size": list(data.run_inputs.image_size),
                  "augmentation": augmentation is not None,
                  "freeze_backbone": cfg.model.freeze_backbone,
                  "n_train": len(data.train_ids), "n_val": len(data.val_ids),
                  "n_test": len(data.split.test_ids), "train_s": clock.train, "val_s": clock.val,
                  "train_cpu_s": clock.train_cpu, "val_cpu_s": clock.val_cpu,
                  "peak_kib": int(status["VmHWM"].split()[0])}))
"""


def _bytes(root: Path) -> int:
    return sum(p.stat().st_size for p in root.rglob("*") if p.is_file())


def _load() -> str:
    one, five, fifteen = os.getloadavg()
    return f"load average {one:.1f} / {five:.1f} / {fifteen:.1f}"


def bench_import(work: Path, dirs: int, size: tuple[int, int]) -> dict[str, float]:
    import numpy as np

    from burgess_tree import write_tree
    from tactile_compliance.data.download_check import check_burgess_download

    n_objects = max(1, dirs // 25)
    objects = {f"obj_{i:03d}": (10.0 ** (4 + i % 7), "Rubber", "Sphere") for i in range(n_objects)}
    tree = work / "tree"
    write_tree(tree, objects, grasps=5, augmentations=5, size=size, dtype=np.float32, keep=False)
    start = time.perf_counter()
    check = check_burgess_download(tree)
    check_s = time.perf_counter() - start
    assert check.complete, check.error_line()
    print(f"[{_load()}]")
    result = subprocess.run(
        [sys.executable, "-c", IMPORT_CHILD, str(tree), str(work / "store")],
        check=True,
        capture_output=True,
        text=True,
    )
    measured = json.loads(result.stdout.strip().splitlines()[-1])
    store_bytes = _bytes(work / "store")
    files = check.counts["files"]
    out = {
        "dirs": check.counts["samples"],
        "files": files,
        "tree_bytes_per_dir": check.total_bytes / check.counts["samples"],
        "check_s": check_s,
        "check_ms_per_file": 1000 * check_s / files,
        "samples": measured["samples"],
        "import_s": measured["seconds"],
        "import_ms_per_sample": 1000 * measured["seconds"] / measured["samples"],
        "store_bytes_per_sample": store_bytes / measured["samples"],
        "import_peak_gb": measured["peak_kib"] / 1e6,
    }
    print(
        f"import  tree {out['dirs']} dirs / {files} files at {size[0]}x{size[1]} "
        f"({check.total_bytes / 1e9:.2f} GB): check {check_s:.1f} s "
        f"({out['check_ms_per_file']:.2f} ms/file); import {measured['samples']} samples in "
        f"{measured['seconds']:.1f} s ({out['import_ms_per_sample']:.1f} ms/sample), store "
        f"{out['store_bytes_per_sample'] / 1e6:.3f} MB/sample, peak RSS "
        f"{out['import_peak_gb']:.2f} GB   [{_load()}]"
    )
    shutil.rmtree(tree, ignore_errors=True)
    return out


def bench_train(
    work: Path,
    n: int,
    size: tuple[int, int],
    models: list[str],
    batches: int,
    val_batches: int,
    threads: int,
) -> list[dict[str, object]]:
    from bench_training import write_random_store

    start = time.perf_counter()
    store = write_random_store(work / "store-train", n, size)
    print(
        f"store   {len(store)} random-frame samples at {size[0]}x{size[1]}, "
        f"{store.frames.nbytes / 1e9:.2f} GB, written in {time.perf_counter() - start:.0f} s"
    )
    rows = []
    for model in models:
        before = _load()
        started = time.perf_counter()
        result = subprocess.run(
            [
                sys.executable,
                "-c",
                TRAIN_CHILD,
                str(store.path),
                model,
                str(batches),
                str(val_batches),
                str(threads),
            ],
            capture_output=True,
            text=True,
        )
        if result.returncode != 0:
            print(result.stderr[-3000:])
            raise SystemExit(f"{model}: the child failed")
        row = json.loads(result.stdout.strip().splitlines()[-1])
        row["wall_s"] = time.perf_counter() - started
        row["load"] = f"{before} -> {_load()}"
        for kind in ("train_s", "train_cpu_s"):  # the first batch is warm-up
            steps = row[kind][1:] or row[kind]
            row[kind.replace("_s", "_batch_s")] = sum(steps) / len(steps)
        for kind in ("val_s", "val_cpu_s"):
            row[kind.replace("_s", "_batch_s")] = sum(row[kind]) / max(1, len(row[kind]))
        rows.append(row)
        print(
            f"train   {model:9s} {row['image_size'][0]}x{row['image_size'][1]} batch "
            f"{row['batch_size']} (augmentation {row['augmentation']}, frozen backbone "
            f"{row['freeze_backbone']}, {threads} torch thread(s)): train batch "
            f"{row['train_batch_s']:.2f} s wall, {row['train_cpu_batch_s']:.2f} s CPU "
            f"(wall per batch {' / '.join(f'{t:.1f}' for t in row['train_s'])}), val batch "
            f"{row['val_batch_s']:.2f} s wall, {row['val_cpu_batch_s']:.2f} s CPU, "
            f"n_train {row['n_train']} n_val {row['n_val']} "
            f"n_test {row['n_test']}, peak RSS {row['peak_kib'] / 1e6:.2f} GB, child wall "
            f"{row['wall_s']:.0f} s   [{row['load']}]"
        )
    return rows


def extrapolate(rows: list[dict[str, object]], n: int, seeds: int = 10, cells: int = 12) -> None:
    """From each run's CPU seconds per batch (with one torch thread, the time on a core
    of its own; the wall time on a shared machine is longer):
    epoch = ceil(n_train / B) t_train + ceil(n_val / B) t_val; the final pass over the
    whole store (predictions.csv) = ceil(N / B) t_val; run(E) = E epoch + final pass;
    Table I per model = ``cells`` (4 inputs x 3 object conditions) x ``seeds`` runs."""
    print("extrapolation from CPU seconds per batch (one core per run; E = epochs trained):")
    for row in rows:
        b = int(row["batch_size"])  # type: ignore[call-overload]
        t_train, t_val = float(row["train_cpu_batch_s"]), float(row["val_cpu_batch_s"])  # type: ignore[arg-type]
        epoch = (
            math.ceil(int(row["n_train"]) / b) * t_train  # type: ignore[call-overload]
            + math.ceil(int(row["n_val"]) / b) * t_val  # type: ignore[call-overload]
        )
        final = math.ceil(n / b) * t_val
        runs = {e: e * epoch + final for e in (31, 200)}
        print(
            f"  {row['model']:9s} epoch {epoch / 3600:.2f} h; run {runs[31] / 3600:.1f} h "
            f"(E = 31, the fewest early stopping allows) to {runs[200] / 3600:.1f} h "
            f"(E = 200, the cap); Table I's {cells * seeds} runs of this model: "
            f"{cells * seeds * runs[31] / 86400:.0f}-{cells * seeds * runs[200] / 86400:.0f} "
            "core-days"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--part", choices=("import", "train", "all"), default="all")
    parser.add_argument("--dirs", type=int, default=200)
    parser.add_argument("--samples", type=int, default=7840)
    parser.add_argument("--size", default="250x350")
    parser.add_argument("--batches", type=int, default=4)
    parser.add_argument("--val-batches", type=int, default=2)
    parser.add_argument("--models", default="top10nn,vgg_lstm,res_tf")
    parser.add_argument(
        "--threads", type=int, default=1, help="torch threads per run (experiment's default)"
    )
    parser.add_argument("--workdir", default=tempfile.gettempdir())
    parser.add_argument("--json", type=Path, help="also write the measurements here")
    args = parser.parse_args()
    size = tuple(int(v) for v in args.size.split("x"))
    import torch

    print(
        f"machine: {platform.machine()} {platform.processor() or ''}, {os.cpu_count()} cores, "
        f"python {platform.python_version()}, torch {torch.__version__} "
        f"({torch.get_num_threads()} threads), {_load()}"
    )
    work = Path(tempfile.mkdtemp(prefix="bench_reproduce_", dir=args.workdir))
    measured: dict[str, object] = {}
    try:
        if args.part in ("import", "all"):
            measured["import"] = bench_import(work, args.dirs, size)  # type: ignore[arg-type]
        if args.part in ("train", "all"):
            rows = bench_train(
                work,
                args.samples,
                size,
                args.models.split(","),
                args.batches,
                args.val_batches,
                args.threads,
            )
            measured["train"] = rows
            extrapolate(rows, args.samples)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    if args.json:
        args.json.write_text(json.dumps(measured, indent=2) + "\n")


if __name__ == "__main__":
    main()
