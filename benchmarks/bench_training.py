"""Training-side benchmarks (issue 5): feature caching, head epochs, fine-tuning, memory.

    python benchmarks/bench_training.py [--samples 7800] [--size 250x350]
        [--cache-samples 128] [--cache-size 224x224] [--finetune-batches 3]
        [--only cache|heads|finetune|memory]

1. Feature caching: `cached_features` (store read + resize + normalise + backbone) vs the
   backbone's raw forward on in-memory tensors of the same size, in the same run; the
   pipeline should keep >= 90 % of the raw throughput.
2. Seconds per epoch of each model head on cached features over ``--samples`` samples
   (through the real Lightning module, float32 and bf16-mixed; goal <= 10 s on 2 cores).
   The features are random, so ``--only heads --size 16x16`` measures the same thing
   without writing a 6 GB store.
3. End-to-end fine-tuning seconds per epoch, extrapolated from ``--finetune-batches``
   batches of each model at its CPU size.
4. Peak resident memory of `train()` on a ``--samples``-sample full-size store (a frozen
   Res-Tf with its feature cache, and Top10NN end to end; a few batches; goal <= 3 GB).

The store is random frames written to a temporary directory and deleted afterwards.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
import torch

from tactile_compliance.data.dataset import GraspDataset, batch_loader
from tactile_compliance.data.features import cached_features
from tactile_compliance.data.normalisation import NormalisationConstants
from tactile_compliance.data.store import GraspStore
from tactile_compliance.data.store_writer import GraspStoreWriter
from tactile_compliance.models import create_model
from tactile_compliance.runs.forward import forward_batch
from tactile_compliance.runs.run_inputs import RunInputs
from tactile_compliance.training.module import ComplianceModule

# The peak is read from /proc/self/status (VmHWM, this process's own address space):
# getrusage's ru_maxrss would also count the parent's resident size at fork time, which
# Linux carries over exec (it reported 6.9 GB here for a 3.3 GB process).
MEMORY_CHILD = """
import json, sys
from tactile_compliance.config import load_config
from tactile_compliance.training.train import train
cfg = load_config("default", sys.argv[2:])
result = train(cfg, run_dir=sys.argv[1], progress=False)
status = dict(line.split(":", 1) for line in open("/proc/self/status") if ":" in line)
print(json.dumps({"peak_kib": int(status["VmHWM"].split()[0]), "n_train": result["n_train"]}))
"""


def write_random_store(path: Path, n: int, size: tuple[int, int], seed: int = 0) -> GraspStore:
    """A store of ``n`` samples with random frames and plausible F/W/E (passes the filter)."""
    rng = np.random.default_rng(seed)
    height, width = size
    block = rng.integers(100, 156, (8, 3, height, width, 3), dtype=np.uint8)
    with GraspStoreWriter(path, size, "benchmark") as writer:
        for i in range(n):
            obj = i // 20
            writer.append(
                block[i % 8],
                {
                    "object": f"obj_{obj:04d}",
                    "grasp": (i // 10) % 2,
                    "augmentation": i % 5,
                    "finger": "markerless" if i % 2 == 0 else "markers",
                    "material": "Rubber",
                    "shape": "Sphere",
                    "modulus_pa": 10 ** (4 + (obj % 8)),
                    "force_n_0": 6.0,
                    "force_n_1": 30.0,
                    "force_n_2": 58.0,
                    "width_m_0": 0.05,
                    "width_m_1": 0.049,
                    "width_m_2": 0.048,
                    "elastic_estimate_pa": 1e5,
                    "hertz_estimate_pa": 2e5,
                    "depth_max_mm_0": 0.5,
                    "depth_max_mm_1": 1.0,
                    "depth_max_mm_2": 1.5,
                },
            )
    return GraspStore.open(path)


def bench_cache(store: GraspStore, size: tuple[int, int], n: int) -> None:
    """Caching pipeline throughput vs raw backbone forward, frames/s, per backbone."""
    subset_dir = store.path.parent / "cache-subset"
    shutil.rmtree(subset_dir, ignore_errors=True)
    subset = write_random_store(subset_dir, n, store.image_size)
    constants = NormalisationConstants()
    torch.manual_seed(0)
    for model_name in ("res_tf", "vgg_lstm"):
        backbone = create_model(model_name).backbone.eval()
        batch = 16
        x = torch.randn(batch * 3, 3, *size)
        with torch.no_grad():
            backbone(x[:3])  # warm-up
            start = time.perf_counter()
            for _ in range(max(1, n // batch)):
                backbone(x)
            raw = max(1, n // batch) * batch * 3 / (time.perf_counter() - start)
        start = time.perf_counter()
        cached_features(subset, backbone, size, constants, batch_size=batch, progress=False)
        pipeline = n * 3 / (time.perf_counter() - start)
        print(
            f"cache  {model_name:9s} {type(backbone).__name__:8s} {size[0]}x{size[1]}: "
            f"raw forward {raw:7.1f} frames/s, caching pipeline {pipeline:7.1f} frames/s "
            f"({100 * pipeline / raw:.0f} %)"
        )
    shutil.rmtree(subset_dir, ignore_errors=True)


def _epoch_seconds(
    module: ComplianceModule, dataset: GraspDataset, batch_size: int, precision: str = "32"
) -> float:
    import lightning as L

    trainer = L.Trainer(
        max_epochs=1,
        accelerator="cpu",
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        num_sanity_val_steps=0,
        limit_val_batches=0,
        precision=precision,
    )
    start = time.perf_counter()
    trainer.fit(module, batch_loader(dataset, batch_size, shuffle=True))  # as train() does
    return time.perf_counter() - start


def bench_heads(store: GraspStore, n: int, repeats: int = 2) -> None:
    """Seconds per training epoch of each head on cached (here random) features, in float32
    and bf16-mixed (``training.precision``); the best of ``repeats`` epochs."""
    constants = NormalisationConstants()
    ids = np.arange(n) % len(store)
    for model_name in ("top10nn", "vgg_lstm", "res_tf"):
        model = create_model(model_name)
        batch_size = int(model.default_training.get("batch_size", 32))
        features = (
            np.random.default_rng(0)
            .standard_normal((len(store), 3, model.feature_dim))
            .astype(np.float16)
        )
        dataset = GraspDataset(store, ids, constants, "ALL", features)
        run_inputs = RunInputs(store.image_size, store.image_size, constants, "ALL")
        for precision in ("32", "bf16-mixed"):
            module = ComplianceModule(
                model, run_inputs, lr=1e-4, gamma=0.98, l2_weight=5e-5, freeze_backbone=True
            )
            seconds = [
                _epoch_seconds(module, dataset, batch_size, precision) for _ in range(repeats)
            ]
            print(
                f"head   {model_name:9s} on cached features, precision {precision:10s}: "
                f"{min(seconds):6.1f} s/epoch (best of {' / '.join(f'{v:.1f}' for v in seconds)};"
                f" {n} samples, batch {batch_size})"
            )


def bench_finetune(store: GraspStore, n_batches: int, n_epoch: int) -> None:
    """End-to-end (backbone trained) seconds per epoch, extrapolated from a few batches."""
    constants = NormalisationConstants()
    sizes = {"top10nn": store.image_size, "res_tf": (224, 224), "vgg_lstm": (224, 224)}
    for model_name, size in sizes.items():
        model = create_model(model_name)
        batch_size = int(model.default_training.get("batch_size", 32))
        run_inputs = RunInputs(size, store.image_size, constants, "ALL")
        module = ComplianceModule(model, run_inputs, lr=1e-4, gamma=None, l2_weight=5e-5)
        optimiser = module.configure_optimizers()
        optimiser = optimiser["optimizer"] if isinstance(optimiser, dict) else optimiser
        dataset = GraspDataset(store, np.arange(batch_size * (n_batches + 1)), constants, "ALL")
        loader = torch.utils.data.DataLoader(dataset, batch_size=batch_size)
        timings = []
        for index, batch in enumerate(loader):
            start = time.perf_counter()
            prediction = forward_batch(model, batch, run_inputs)
            loss = torch.mean((prediction - batch["label"]) ** 2)
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            if index > 0:  # the first batch pays for allocation warm-up
                timings.append(time.perf_counter() - start)
        per_sample = float(np.mean(timings)) / batch_size
        print(
            f"tune   {model_name:9s} end to end at {size[0]}x{size[1]}: "
            f"{per_sample * 1000:6.1f} ms/sample -> {per_sample * n_epoch / 60:6.1f} min/epoch "
            f"for {n_epoch} samples"
        )


def bench_memory(store: GraspStore, work: Path) -> None:
    """Peak resident memory of `train()` on the store: the frozen-backbone path (feature
    cache computed in the run, then the head) and Top10NN end to end at full size."""
    height, width = store.image_size
    runs = {
        "Res-Tf frozen backbone at 112x112 (cache + head)": [
            "model.name=res_tf",
            "model.freeze_backbone=true",
            "data.image_size=[112,112]",
            "augmentation.enabled=false",
        ],
        f"Top10NN end to end at {height}x{width}, augmentation": [
            "model.name=top10nn",
            f"data.image_size=[{height},{width}]",
            "augmentation.enabled=true",
        ],
    }
    store_gb = store.frames.nbytes / 1e9
    for index, (label, config) in enumerate(runs.items()):
        overrides = [
            f"data.store={store.path}",
            "training.max_epochs=1",
            "training.limit_batches=30",
            "training.batch_size=32",
            *config,
        ]
        result = subprocess.run(
            [sys.executable, "-c", MEMORY_CHILD, str(work / f"memory-run-{index}"), *overrides],
            check=True,
            capture_output=True,
            text=True,
        )
        measured = json.loads(result.stdout.strip().splitlines()[-1])
        print(
            f"memory train() {label}, {len(store)}-sample {height}x{width} store "
            f"({store_gb:.2f} GB): peak RSS {measured['peak_kib'] / 1e6:.2f} GB"
        )


def _has_bf16_instructions() -> str:
    """Whether the CPU has native bfloat16 dot products (what makes bf16-mixed fast)."""
    try:
        flags = Path("/proc/cpuinfo").read_text()
    except OSError:
        return "unknown"
    found = [flag for flag in ("avx512_bf16", "amx_bf16") if flag in flags]
    return ", ".join(found) if found else "none"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=7800)
    parser.add_argument("--size", default="250x350")
    parser.add_argument("--cache-samples", type=int, default=128)
    parser.add_argument("--cache-size", default="224x224")
    parser.add_argument("--finetune-batches", type=int, default=3)
    parser.add_argument("--workdir", default=tempfile.gettempdir())
    parser.add_argument(
        "--only",
        choices=("cache", "heads", "finetune", "memory"),
        help="run one part (heads only: a small store suffices, see --size)",
    )
    args = parser.parse_args()
    size = tuple(int(v) for v in args.size.split("x"))
    cache_size = tuple(int(v) for v in args.cache_size.split("x"))
    # Lightning's per-fit banners ("GPU available", tips) would bury the numbers.
    for name in ("lightning.pytorch", "lightning.fabric"):
        logging.getLogger(name).setLevel(logging.ERROR)
    warnings.filterwarnings("ignore", module="lightning.*")
    print(
        f"machine: {platform.machine()}, {os.cpu_count()} cores, torch {torch.__version__}, "
        f"{torch.get_num_threads()} threads, CPU capability "
        f"{torch.backends.cpu.get_cpu_capability()}, bf16 instructions: "
        f"{_has_bf16_instructions()}"
    )
    work = Path(tempfile.mkdtemp(prefix="bench_training_", dir=args.workdir))
    try:
        start = time.perf_counter()
        store = write_random_store(work / "store", args.samples, size)
        print(
            f"store  {len(store)} samples at {size[0]}x{size[1]} written in "
            f"{time.perf_counter() - start:.0f} s"
        )
        parts = {
            "cache": lambda: bench_cache(store, cache_size, args.cache_samples),
            "heads": lambda: bench_heads(store, args.samples),
            "finetune": lambda: bench_finetune(store, args.finetune_batches, args.samples),
            "memory": lambda: bench_memory(store, work),
        }
        for name, run in parts.items():
            if args.only in (None, name):
                run()
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
