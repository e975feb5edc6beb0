"""Depth maps in the store and tactile pretraining (issue 15)."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from burgess_tree import write_tree
from tactile_compliance.cli import app
from tactile_compliance.config import load_config
from tactile_compliance.data.burgess import import_burgess
from tactile_compliance.data.features import cache_key
from tactile_compliance.data.preprocess import filter_samples
from tactile_compliance.data.splits import make_split_from_config
from tactile_compliance.data.store import (
    DEPTH_FILE,
    GraspStore,
    StoreError,
    depth_size_for,
)
from tactile_compliance.data.store_writer import GraspStoreWriter
from tactile_compliance.models import create_model
from tactile_compliance.models.backbones import PRETRAIN_KEY, create_backbone
from tactile_compliance.outputs import OutputExistsError
from tactile_compliance.runs.checkpoint import load_checkpoint
from tactile_compliance.training.pretrain import (
    DepthPretrainNet,
    PretrainSettings,
    pretrain,
    pretrain_backbone,
)
from tactile_compliance.training.train import train
from toy_store import depth_toy_store, make_toy_store, tiny_run_config

runner = CliRunner()
ROW = {"object": "o", "modulus_pa": 1e6, "material": "Foam", "shape": "Sphere"}


def _sha256(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


# ------------------------------------------------------------------- depth in the store
def test_store_round_trips_depth_maps_as_float16_mm(tmp_path):
    frames = np.full((3, 8, 12, 3), 0.5, np.float32)
    depth = np.linspace(-0.2, 3.7, 3 * 2 * 3).reshape(3, 2, 3)
    with GraspStoreWriter(tmp_path / "s", (8, 12), "test", depth_size=(2, 3)) as writer:
        writer.append(frames, ROW, depth)
        writer.append(frames, ROW)  # no depth file: NaN
    store = GraspStore.open(tmp_path / "s")
    assert store.has_depth and store.depth_size == (2, 3)
    read = store.read_depth([0, 1])
    assert read.dtype == np.float32 and read.shape == (2, 3, 2, 3)
    # float16: relative step 2**-11, i.e. < 0.002 mm up to 4 mm.
    np.testing.assert_allclose(read[0], depth, atol=0.002)
    assert np.isnan(read[1]).all()
    header = json.loads((tmp_path / "s" / "header.json").read_text())
    assert header["depth_size"] == [2, 3] and header["depth_unit"] == "mm"
    summary = store.summary()["depth"]
    assert summary["size"] == [2, 3] and summary["bytes"] == 2 * 3 * 2 * 3 * 2


def test_store_without_depth_opens_unchanged(tmp_path):
    store = make_toy_store(tmp_path / "s", n_objects=3, grasps=1, size=(8, 8))
    assert not store.has_depth and store.summary()["depth"] is None
    assert "depth_size" not in json.loads((tmp_path / "s" / "header.json").read_text())
    with pytest.raises(StoreError, match="no depth maps"):
        store.read_depth([0])
    with pytest.raises(StoreError, match="no depth maps"):
        pretrain(
            load_config("default", [f"data.store={tmp_path / 's'}"]),
            PretrainSettings("resnet18"),
            tmp_path / "w.pt",
            progress=False,
        )
    assert not (tmp_path / "w.pt").exists()


@pytest.mark.parametrize(
    "bad, message",
    [
        (np.zeros((3, 3, 3)), "shape"),
        (np.full((3, 2, 3), np.inf), "finite"),
        (np.full((3, 2, 3), 250.0), "within"),
    ],
)
def test_store_refuses_bad_depth_maps(tmp_path, bad, message):
    frames = np.full((3, 8, 12, 3), 0.5, np.float32)
    with GraspStoreWriter(tmp_path / "s", (8, 12), "test", depth_size=(2, 3)) as writer:
        with pytest.raises(ValueError, match=message):
            writer.append(frames, ROW, bad)
        writer.append(frames, ROW, np.zeros((3, 2, 3)))
    assert len(GraspStore.open(tmp_path / "s")) == 1


def test_truncated_depth_file_is_named(tmp_path):
    depth_toy_store(tmp_path / "s", n_objects=3, grasps=1, size=(8, 8))
    path = tmp_path / "s" / DEPTH_FILE
    path.write_bytes(path.read_bytes()[:-2])
    with pytest.raises(StoreError, match=r"depth\.f16"):
        GraspStore.open(tmp_path / "s")


@pytest.mark.parametrize("keep", [True, False])
def test_import_keeps_the_depth_maps_downsampled(tmp_path, keep):
    written = write_tree(tmp_path / "src", grasps=1, augmentations=1, size=(12, 16))
    import_burgess(tmp_path / "src", tmp_path / "store", depth=keep, progress=False)
    store = GraspStore.open(tmp_path / "store")
    assert store.has_depth is keep
    if not keep:
        return
    assert store.depth_size == depth_size_for((12, 16)) == (3, 4)
    row = store.samples.iloc[0]
    raw = written[(row["object"], int(row["grasp"]), int(row["augmentation"]))]
    source = raw["depth.pkl" if row["finger"] == "markerless" else "depth_markers.pkl"]
    # Area averaging over 4x4 blocks, then float16.
    expected = source.reshape(3, 3, 4, 4, 4).mean(axis=(2, 4))
    np.testing.assert_allclose(store.read_depth(0)[0], expected, rtol=2e-3, atol=1e-3)


def test_info_shows_whether_depth_is_present(tmp_path):
    depth_toy_store(tmp_path / "a", n_objects=3, grasps=1, size=(8, 8))
    make_toy_store(tmp_path / "b", n_objects=3, grasps=1, size=(8, 8))
    with_depth = runner.invoke(app, ["info", str(tmp_path / "a")])
    without = runner.invoke(app, ["info", str(tmp_path / "b")])
    assert with_depth.exit_code == 0 and "3 x 2 x 2 (float16 mm), 6 samples" in with_depth.output
    assert without.exit_code == 0 and "Depth       none" in without.output


# ------------------------------------------------------------------------ pretraining
@pytest.fixture(autouse=True)
def _one_thread():
    # Two threads on a shared 2-core machine run these tiny batches 5x slower.
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


@pytest.fixture(scope="module")
def depth_store(tmp_path_factory):
    path = tmp_path_factory.mktemp("pretrain") / "store"
    return depth_toy_store(path, n_objects=8, grasps=2, size=(32, 32))


def _cfg(store, *extra):
    return load_config(
        "default", [f"data.store={store.path}", "split.condition=unseen", "seed=0", *extra]
    )


def test_every_parameter_of_backbone_and_decoder_gets_a_gradient():
    torch.manual_seed(0)
    net = DepthPretrainNet(pretrain_backbone("resnet18"), (8, 8), depth_scale_mm=0.3)
    depth = torch.rand(6, 8, 8)
    net.losses(torch.randn(6, 3, 32, 32), depth)["loss"].backward()
    missing = [n for n, p in net.named_parameters() if p.grad is None or not p.grad.any()]
    assert not missing
    assert any(n.startswith("decoder.") for n, _ in net.named_parameters())


def test_flips_move_frames_and_depth_maps_together():
    from tactile_compliance.training.pretrain import _flip

    frames = torch.zeros(64, 3, 8, 8, 3, dtype=torch.uint8)
    frames[:, :, :4, :4] = 255  # top-left quadrant
    depth = torch.zeros(64, 3, 2, 2)
    depth[:, :, 0, 0] = 1.0
    cfg = load_config("default", ["augmentation.probability=1.0"])
    flipped, flipped_depth = _flip(frames, depth, cfg, torch.Generator().manual_seed(0))
    quadrant = flipped[:, 0, ::4, ::4, 0] == 255  # (64, 2, 2): where the bright block went
    assert torch.equal(quadrant, flipped_depth[:, 0] == 1.0)
    assert len({tuple(q.flatten().tolist()) for q in quadrant}) == 4  # all four flips seen
    off = load_config("default", ["augmentation.enabled=false"])
    unchanged, _ = _flip(frames, depth, off, torch.Generator().manual_seed(0))
    assert torch.equal(unchanged, frames)


def test_pretraining_lowers_the_depth_loss(depth_store, tmp_path):
    settings = PretrainSettings("resnet18", epochs=4, batch_size=8, lr=1e-3, patience=0)
    cfg = _cfg(depth_store, "augmentation.enabled=false")
    result = pretrain(cfg, settings, tmp_path / "w.pt", progress=False)
    history = result.provenance["history"]
    assert len(history) == 4
    # Measured: last/first 0.49 (seed 0; 0.38 and 0.44 with seeds 1 and 2); a backbone
    # or decoder that does not learn stays near 1.
    assert history[-1]["train_loss"] < 0.75 * history[0]["train_loss"]
    assert result.provenance["final_depth_loss_mm2"] < result.provenance["first_depth_loss_mm2"]
    # The file loads as backbone weights and holds the best epoch's backbone.
    backbone = create_backbone("resnet18", tmp_path / "w.pt")
    stored = torch.load(tmp_path / "w.pt", weights_only=True)
    assert stored[PRETRAIN_KEY]["store"] == str(depth_store.path.resolve())
    for name, tensor in backbone.state_dict().items():
        torch.testing.assert_close(tensor, stored["state_dict"][name])


def test_split_test_and_validation_objects_are_never_read(depth_store, tmp_path, monkeypatch):
    cfg = _cfg(depth_store)
    samples, _ = filter_samples(depth_store.samples, cfg)
    split = make_split_from_config(samples, cfg)  # what `train` draws for this config
    read: set[int] = set()
    for method in ("read_samples", "read_depth"):
        original = getattr(GraspStore, method)

        def recording(self, indices, _original=original):
            read.update(np.atleast_1d(np.asarray(indices)).tolist())
            return _original(self, indices)

        monkeypatch.setattr(GraspStore, method, recording)
    settings = PretrainSettings("resnet18", epochs=1, batch_size=8)
    result = pretrain(cfg, settings, tmp_path / "w.pt", progress=False)
    forbidden = set(split.test_ids.tolist()) | set(split.val_ids.tolist())
    assert read and not read & forbidden
    assert read <= set(split.train_ids.tolist())
    # Early stopping holds out whole training objects.
    objects = depth_store.samples["object"]
    assert not set(objects[result.train_ids]) & set(objects[result.val_ids])
    assert result.provenance["split"]["seed"] == 0
    assert result.provenance["split"]["condition"] == "unseen"


def test_a_split_file_is_used_and_recorded_by_sha256(depth_store, tmp_path):
    split_path = tmp_path / "split.json"
    cfg = _cfg(depth_store, "seed=3")
    make_split_from_config(filter_samples(depth_store.samples, cfg)[0], cfg).save(split_path)
    settings = PretrainSettings("resnet18", epochs=1, batch_size=16, limit_batches=1)
    result = pretrain(
        _cfg(depth_store), settings, tmp_path / "w.pt", split_file=split_path, progress=False
    )
    record = result.provenance["split"]
    assert record["sha256"] == _sha256(split_path) and record["seed"] == 3


def test_interrupted_pretraining_resumes_and_never_overwrites_foreign_files(
    depth_store, tmp_path, monkeypatch
):
    out = tmp_path / "w.pt"
    (tmp_path / "mine.pt").write_bytes(b"not ours")
    settings = PretrainSettings("resnet18", epochs=2, batch_size=16, limit_batches=1)
    with pytest.raises(OutputExistsError):
        pretrain(_cfg(depth_store), settings, tmp_path / "mine.pt", progress=False)
    assert (tmp_path / "mine.pt").read_bytes() == b"not ours"

    import tactile_compliance.training.pretrain as module

    calls = {"n": 0}
    original = module._evaluate

    def interrupted(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt
        return original(*args, **kwargs)

    monkeypatch.setattr(module, "_evaluate", interrupted)
    with pytest.raises(KeyboardInterrupt):
        pretrain(_cfg(depth_store), settings, out, progress=False)
    assert not out.exists() and (tmp_path / "w.pt.pretrain-state.pt").exists()
    monkeypatch.setattr(module, "_evaluate", original)
    result = pretrain(_cfg(depth_store), settings, out, progress=False)
    assert result.resumed_from_epoch == 1 and result.provenance["epochs"] == 2
    assert not (tmp_path / "w.pt.pretrain-state.pt").exists()
    # A finished file is returned as it is; --overwrite retrains it.
    again = pretrain(_cfg(depth_store), settings, out, progress=False)
    assert again.existing and again.provenance["created"] == result.provenance["created"]


def test_weights_sha256_and_provenance_land_in_the_checkpoint(depth_store, tmp_path):
    weights = tmp_path / "w.pt"
    settings = PretrainSettings("resnet18", epochs=1, batch_size=16, limit_batches=1)
    provenance = pretrain(_cfg(depth_store), settings, weights, progress=False).provenance
    cfg = tiny_run_config(
        depth_store.path,
        tmp_path / "runs",
        "res_tf",
        [
            "split.condition=unseen",
            f"model.backbone_weights={weights}",
            "model.freeze_backbone=true",
            "training.max_epochs=1",
            "inputs=Image",
            "model.hparams={num_layers: 1, embedding_dim: 32, output_dim: 32, "
            "dim_feedforward: 64, decoder_sizes: [16]}",
        ],
    )
    result = train(cfg, run_dir=tmp_path / "run", progress=False)
    assert result["backbone_weights_sha256"] == _sha256(weights)
    loaded = load_checkpoint(tmp_path / "run" / "best.pt")
    record = loaded.meta["backbone_weights_file"]
    assert record["sha256"] == _sha256(weights)
    assert record["provenance"]["split"] == provenance["split"]
    assert record["provenance"]["final_depth_loss_mm2"] == provenance["final_depth_loss_mm2"]
    # The frozen pretrained backbone's features have their own cache key.
    random = create_model("res_tf", inputs="Image").backbone
    pretrained = create_model("res_tf", inputs="Image", backbone_weights=weights).backbone
    constants = cfg.normalisation_constants()
    assert cache_key(random, (32, 32), constants) != cache_key(pretrained, (32, 32), constants)
    assert len(list((depth_store.path / "features").iterdir())) >= 1


def test_top10nn_takes_a_pretrained_encoder(tmp_path):
    torch.manual_seed(1)
    encoder = pretrain_backbone("top10nn-cnn")
    torch.save({"state_dict": encoder.state_dict()}, tmp_path / "top.pt")
    model = create_model("top10nn", backbone_weights=tmp_path / "top.pt")
    for name, tensor in encoder.state_dict().items():
        torch.testing.assert_close(model.backbone.state_dict()[name], tensor)
    with pytest.raises(ValueError, match="ImageNet"):
        create_model("top10nn", backbone_weights="imagenet")


def _pretrain_args(store, out, *extra):
    """``tactile-compliance pretrain STORE --backbone resnet18 --out OUT`` (+ extra)."""
    return ["pretrain", str(store.path), "--backbone", "resnet18", "--out", str(out), *extra]


def test_pretrain_train_predict_through_the_cli(depth_store, tmp_path):
    weights = tmp_path / "w.pt"
    result = runner.invoke(
        app, _pretrain_args(depth_store, weights, "--epochs", "1", "--batch-size", "32")
    )
    assert result.exit_code == 0, result.output
    assert "model.backbone_weights=" in result.output
    # Again with --json: the file is already pretrained; its record alone on stdout.
    again = runner.invoke(
        app, _pretrain_args(depth_store, weights, "--epochs", "1", "--batch-size", "32", "--json")
    )
    assert again.exit_code == 0, again.output
    document = json.loads(again.stdout)
    assert document["existing"] and document["out"] == str(weights)
    assert document["provenance"]["backbone"] == "resnet18"
    assert document["provenance"]["epochs"] == len(document["provenance"]["history"]) == 1
    assert f"model.backbone_weights={weights}" in document["train_overrides"]
    hparams = "{num_layers: 1, embedding_dim: 32, output_dim: 32, dim_feedforward: 64}"
    result = runner.invoke(
        app,
        [
            "train",
            "--out",
            str(tmp_path / "run"),
            *("--set", f"data.store={depth_store.path}"),
            *("--set", "model.name=res_tf"),
            *("--set", f"model.backbone_weights={weights}"),
            *("--set", "model.freeze_backbone=true"),
            *("--set", "augmentation.enabled=false"),
            *("--set", "split.condition=unseen"),
            *("--set", "training.max_epochs=1"),
            *("--set", f"model.hparams={hparams}"),
        ],
    )
    assert result.exit_code == 0, result.output
    result = runner.invoke(app, ["predict", str(tmp_path / "run"), str(depth_store.path)])
    assert result.exit_code == 0, result.output
    # A file that is not a weights file is never replaced.
    (tmp_path / "notes.pt").write_text("mine")
    result = runner.invoke(app, _pretrain_args(depth_store, tmp_path / "notes.pt"))
    assert result.exit_code == 2 and result.output.count("error:") == 1
    assert (tmp_path / "notes.pt").read_text() == "mine"
