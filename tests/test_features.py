"""The frozen-backbone feature cache: one computation per key, even across processes."""

from __future__ import annotations

import multiprocessing
import os
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from torch import nn

from tactile_compliance.data.features import FEATURES_DIR, cached_features
from tactile_compliance.data.normalisation import NormalisationConstants
from tactile_compliance.data.store import GraspStore
from toy_store import make_toy_store

fcntl = pytest.importorskip("fcntl", reason="the cache lock needs fcntl (POSIX)")

BATCH_SIZE = 4  # samples per backbone call: a 16-sample store takes 4 calls


class CountingBackbone(nn.Module):
    """A tiny deterministic backbone that logs every forward call to a file.

    The log is the timing-independent evidence of how often the store was encoded:
    every call appends ``PID IMAGES`` (one small ``O_APPEND`` write, atomic across
    processes). ``delay_s`` per call keeps a computation in progress long enough for a
    second, unlocked process to start its own; ``fail_on_call`` simulates a crash.
    """

    feature_dim = 4

    def __init__(self, log_path: Path, delay_s: float = 0.0, fail_on_call: int = 0) -> None:
        super().__init__()
        self.conv = nn.Conv2d(3, self.feature_dim, kernel_size=3)
        # Same weights in every process, without touching the global RNG.
        generator = torch.Generator().manual_seed(0)
        with torch.no_grad():
            self.conv.weight.copy_(torch.randn(self.conv.weight.shape, generator=generator))
            self.conv.bias.copy_(torch.randn(self.conv.bias.shape, generator=generator))
        self.log_path = str(log_path)
        self.delay_s = delay_s
        self.fail_on_call = fail_on_call
        self.calls = 0

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        self.calls += 1
        if self.calls == self.fail_on_call:
            raise RuntimeError("simulated crash")
        with open(self.log_path, "a") as log:
            log.write(f"{os.getpid()} {x.shape[0]}\n")
        time.sleep(self.delay_s)
        return self.conv(x).mean(dim=(2, 3))


def _logged(log_path: Path) -> tuple[set[int], int]:
    """(PIDs that ran the backbone, total images encoded) from a CountingBackbone log."""
    pids, images = set(), 0
    for line in log_path.read_text().splitlines():
        pid, count = line.split()
        pids.add(int(pid))
        images += int(count)
    return pids, images


def _compute_in_process(
    store_path: str, log_path: str, out_path: str, barrier: multiprocessing.synchronize.Barrier
) -> None:
    """Child process: wait for the sibling, then ask for the cache (the race under test)."""
    torch.set_num_threads(1)
    store = GraspStore.open(store_path)
    backbone = CountingBackbone(Path(log_path), delay_s=0.3)
    barrier.wait(timeout=60)
    features = cached_features(
        store,
        backbone,
        store.image_size,
        NormalisationConstants(),
        batch_size=BATCH_SIZE,
        progress=False,
    )
    np.save(out_path, np.asarray(features))


def _tiny_store(path: Path) -> GraspStore:
    return make_toy_store(path, n_objects=4, grasps=2, size=(8, 8))  # 16 samples


def test_two_processes_compute_one_cache_once(tmp_path):
    store = _tiny_store(tmp_path / "store")
    log = tmp_path / "forward.log"
    # spawn, not fork: forking a process that has used torch's thread pools can hang.
    context = multiprocessing.get_context("spawn")
    barrier = context.Barrier(2)
    outputs = [tmp_path / f"features{i}.npy" for i in range(2)]
    workers = [
        context.Process(
            target=_compute_in_process, args=(str(store.path), str(log), str(out), barrier)
        )
        for out in outputs
    ]
    for worker in workers:
        worker.start()
    for worker in workers:
        worker.join(timeout=180)
    assert [w.exitcode for w in workers] == [0, 0]

    # The store went through the backbone once in total, in one of the two processes.
    pids, images = _logged(log)
    assert images == 3 * len(store), (pids, images)
    assert len(pids) == 1 and pids <= {w.pid for w in workers}
    first, second = (np.load(out) for out in outputs)
    np.testing.assert_array_equal(first, second)

    # Equal to a single-process computation on an identical store.
    reference_store = _tiny_store(tmp_path / "reference")
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # as in the children, so the float results match bit for bit
    try:
        reference = cached_features(
            reference_store,
            CountingBackbone(tmp_path / "reference.log"),
            reference_store.image_size,
            NormalisationConstants(),
            batch_size=BATCH_SIZE,
            progress=False,
        )
    finally:
        torch.set_num_threads(threads)
    np.testing.assert_array_equal(first, np.asarray(reference))
    (cache,) = (store.path / FEATURES_DIR).iterdir()
    assert not (cache / "features.f16.partial").exists()
    assert not (cache / "progress.json").exists()


def test_a_crashed_computation_releases_the_lock_and_resumes(tmp_path):
    store = _tiny_store(tmp_path / "store")
    log = tmp_path / "forward.log"
    constants = NormalisationConstants()
    with pytest.raises(RuntimeError, match="simulated crash"):
        cached_features(
            store,
            CountingBackbone(log, fail_on_call=3),
            store.image_size,
            constants,
            batch_size=BATCH_SIZE,
            progress=False,
        )
    assert _logged(log)[1] == 2 * 3 * BATCH_SIZE  # two batches done before the crash
    # The same process locks again (a held lock would block here) and resumes: the
    # finished batches are not encoded a second time.
    features = cached_features(
        store,
        CountingBackbone(log),
        store.image_size,
        constants,
        batch_size=BATCH_SIZE,
        progress=False,
    )
    assert _logged(log)[1] == 3 * len(store)
    assert features.shape == (len(store), 3, CountingBackbone.feature_dim)
    assert np.isfinite(np.asarray(features, dtype=np.float32)).all()
    # A finished cache is read without computing (and without taking the lock).
    cached_features(
        store,
        CountingBackbone(log),
        store.image_size,
        constants,
        batch_size=BATCH_SIZE,
        progress=False,
    )
    assert _logged(log)[1] == 3 * len(store)


def test_depth_maps_have_their_own_cache_prepared_as_training_prepares_them(tmp_path):
    from tactile_compliance.data.dataset import prepare_depth
    from tactile_compliance.data.features import cache_key

    store = make_toy_store(tmp_path / "store", n_objects=4, grasps=2, size=(16, 16), depth=True)
    log = tmp_path / "forward.log"
    constants = NormalisationConstants(depth_scale_mm=0.5)
    backbone = CountingBackbone(log)
    size = store.image_size
    frames = cached_features(store, backbone, size, constants, progress=False)
    depth = cached_features(
        store, backbone, size, constants, image="depth", batch_size=BATCH_SIZE, progress=False
    )
    keys = {path.name for path in (store.path / FEATURES_DIR).iterdir()}
    assert keys == {
        cache_key(backbone, size, constants),
        cache_key(backbone, size, constants, "depth"),
    }
    assert cache_key(backbone, size, constants, "depth") != cache_key(
        backbone, size, NormalisationConstants(), "depth"
    )  # another depth scale is another cache
    x = prepare_depth(torch.from_numpy(store.read_depth(np.arange(len(store)))), constants, size)
    with torch.no_grad():
        expected = backbone(x.reshape(-1, *x.shape[2:])).reshape(len(store), 3, -1)
    np.testing.assert_allclose(
        np.asarray(depth, dtype=np.float32), expected.numpy(), rtol=2e-3, atol=2e-3
    )
    assert not np.allclose(np.asarray(depth), np.asarray(frames))
    with pytest.raises(ValueError, match="no image input"):
        cache_key(backbone, size, constants, "force")
