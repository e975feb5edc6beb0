"""best.pt: head-only for frozen backbones, whole for fine-tuned ones, old files still load."""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

from tactile_compliance.data.normalisation import NormalisationConstants
from tactile_compliance.models import backbones, create_model
from tactile_compliance.physics.estimators import (
    DEFAULT_ESTIMATOR,
    AnalyticalEstimator,
    SensorUnits,
)
from tactile_compliance.runs.checkpoint import (
    CHECKPOINT_VERSION,
    FROZEN_BACKBONE_SEED,
    frozen_backbone_record,
    load_checkpoint,
    save_checkpoint,
)
from tactile_compliance.runs.run_inputs import RunInputs
from tactile_compliance.training.train import build_model, train
from toy_store import make_toy_store, tiny_run_config

SMALL = {
    "vgg_lstm": "{hidden_size: 64}",
    "res_tf": "{num_layers: 1, embedding_dim: 64, output_dim: 64}",
    "top10nn": "{}",
}


@pytest.fixture(scope="module")
def toy_store(tmp_path_factory):
    return make_toy_store(tmp_path_factory.mktemp("toy") / "store")


def _config(store_path, out, model, extra=()):
    size = "data.image_size=[72,72]" if model == "top10nn" else "data.image_size=[32,32]"
    return tiny_run_config(
        store_path, out, model, [f"model.hparams={SMALL[model]}", size, "training.lr=1e-3", *extra]
    )


def _inputs(size, batch=2):
    """``(args, kwargs)`` of a model call: frames, then the scalars by name."""
    generator = torch.Generator().manual_seed(1)
    frames = torch.rand(batch, 3, 3, *size, generator=generator)
    scalars = {name: torch.rand(batch, n, generator=generator) for name, n in _SIZES.items()}
    return (frames,), scalars


_SIZES = {"force": 3, "width": 3, "estimates": 2}


def _call(model, size):
    args, kwargs = _inputs(size)
    return model(*args, **kwargs)


def _save(path, model, frozen_backbone=None):
    return save_checkpoint(
        path,
        model,
        run_inputs=RunInputs((32, 32), (32, 32), NormalisationConstants(), model.inputs),
        config={},
        seed=0,
        frozen_backbone=frozen_backbone,
    )


def _perturb_head(model):
    """Make the head differ from any initialisation, as training would."""
    generator = torch.Generator().manual_seed(2)
    with torch.no_grad():
        for name, parameter in model.named_parameters():
            if not name.startswith("backbone."):
                parameter.add_(0.01 * torch.randn(parameter.shape, generator=generator))


@pytest.mark.parametrize("name", sorted(SMALL))
def test_head_only_checkpoint_reproduces_the_in_memory_model(tmp_path, name):
    cfg = _config(tmp_path / "no-store", tmp_path, name, ["model.freeze_backbone=true"])
    model = build_model(cfg).eval()
    _perturb_head(model)
    record = frozen_backbone_record(model, seed=FROZEN_BACKBONE_SEED)
    path = _save(tmp_path / "head.pt", model, frozen_backbone=record)

    payload = torch.load(path, weights_only=True)
    assert payload["format_version"] == CHECKPOINT_VERSION == 3
    assert not any(k.startswith("backbone.") for k in payload["state_dict"])
    assert payload["backbone"]["weights"] == "none"
    assert payload["backbone"]["seed"] == FROZEN_BACKBONE_SEED
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # same machine: the exact sha256 must match
        # On the CPU, beside the in-memory model ("auto" would take a GPU where there is one).
        loaded = load_checkpoint(path, device="cpu").model
    reference = model.state_dict()
    assert set(loaded.state_dict()) == set(reference)
    assert all(torch.equal(v, reference[k]) for k, v in loaded.state_dict().items())
    size = tuple(cfg.data.image_size)
    with torch.no_grad():
        assert torch.equal(_call(loaded, size), _call(model, size))


@pytest.fixture(scope="module")
def frozen_run(toy_store, tmp_path_factory):
    """A frozen VGG-LSTM trained for two epochs through train()."""
    out = tmp_path_factory.mktemp("frozen-run")
    cfg = _config(
        toy_store.path, out, "vgg_lstm", ["model.freeze_backbone=true", "training.max_epochs=2"]
    )
    result = train(cfg, progress=False)
    return cfg, out / result["run_name"]


def test_frozen_run_checkpoints_leave_the_backbone_out(frozen_run):
    cfg, run_dir = frozen_run
    full = build_model(cfg).state_dict()
    full_bytes = sum(t.numel() * t.element_size() for t in full.values())
    backbone_bytes = sum(
        t.numel() * t.element_size() for k, t in full.items() if k.startswith("backbone.")
    )
    assert backbone_bytes > 0.9 * full_bytes  # VGG16 is almost all of the model
    best, last = run_dir / "best.pt", run_dir / "checkpoints" / "last.ckpt"
    assert best.stat().st_size < 0.05 * full_bytes, (best.stat().st_size, full_bytes)
    # last.ckpt also holds Adam's two moments of every head tensor.
    assert last.stat().st_size < 0.15 * full_bytes, (last.stat().st_size, full_bytes)
    state = torch.load(last, map_location="cpu", weights_only=False)["state_dict"]
    assert not any(".backbone." in k for k in state)
    assert any(k.startswith("model.lstm.") for k in state)
    # best.pt's backbone is the one the feature cache was computed with.
    sha256 = load_checkpoint(best).meta["backbone"]["sha256"]
    caches = [p.name for p in (Path(cfg.data.store) / "features").iterdir()]
    assert any(f"-{sha256[:16]}-" in name for name in caches), (sha256, caches)


def test_checkpoints_record_the_stores_analytical_estimator(frozen_run, tmp_path):
    """Live estimates must come from the estimator that made the training data's."""
    from tactile_compliance.data.store import GraspStore
    from tactile_compliance.inference import ComplianceEstimator

    cfg, run_dir = frozen_run
    store = GraspStore.open(cfg.data.store)
    # A store that names no estimator (toy stores) holds the default's values.
    assert store.header.source == "toy"
    assert "analytical_estimator" not in store.header.creation_parameters
    assert store.analytical_estimator == DEFAULT_ESTIMATOR
    assert load_checkpoint(run_dir / "best.pt").run_inputs.estimator == DEFAULT_ESTIMATOR
    assert ComplianceEstimator.from_checkpoint(run_dir).run_inputs.estimator.name == "dataset"
    model = create_model("top10nn", inputs="ALL")
    contact = AnalyticalEstimator("contact")
    path = save_checkpoint(
        tmp_path / "best.pt",
        model,
        run_inputs=RunInputs(
            (72, 72), (72, 72), NormalisationConstants(), model.inputs, estimator=contact
        ),
        config={},
        seed=0,
    )
    estimator = ComplianceEstimator.from_checkpoint(path)
    assert estimator.run_inputs.estimator == contact
    assert estimator.describe()["run_inputs"]["analytical_estimator"] == "contact"
    assert estimator.stream().analytical_estimator == contact


def _tamper(path, out, **changes):
    payload = torch.load(path, weights_only=True)
    payload["backbone"].update(changes)
    torch.save(payload, out)
    return out


def test_a_tampered_backbone_record_is_a_clear_error(tmp_path):
    cfg = _config(tmp_path / "no-store", tmp_path, "res_tf", ["model.freeze_backbone=true"])
    model = build_model(cfg).eval()
    record = frozen_backbone_record(model, seed=FROZEN_BACKBONE_SEED)
    path = _save(tmp_path / "head.pt", model, frozen_backbone=record)

    # Another seed: other weights, found out before the head is used.
    other_seed = _tamper(path, tmp_path / "seed.pt", seed=FROZEN_BACKBONE_SEED + 1)
    with pytest.raises(ValueError, match="not the one the head was trained with"):
        load_checkpoint(other_seed)
    # A fingerprint that fits no rebuild: the sha256 and the summary both disagree.
    summary = {k: [2 * v[0] + 1, *v[1:]] for k, v in record["summary"].items()}
    forged = _tamper(path, tmp_path / "forged.pt", sha256="0" * 64, summary=summary)
    with pytest.raises(ValueError, match=r"sha256 is [0-9a-f]+\.\.\., the checkpoint records 0+"):
        load_checkpoint(forged)
    # Only the sha256 differs while every value agrees to float32 rounding: what another
    # CPU instruction set gives for torch's random initialisation. Loads, with a warning.
    rounding = _tamper(path, tmp_path / "rounding.pt", sha256="0" * 64)
    with pytest.warns(UserWarning, match="float32 rounding"):
        loaded = load_checkpoint(rounding, device="cpu").model
    assert all(torch.equal(v, model.state_dict()[k]) for k, v in loaded.state_dict().items())


def test_imagenet_backbone_is_never_downloaded_on_load(tmp_path, monkeypatch):
    model = create_model("res_tf", inputs="ALL", num_layers=1, embedding_dim=64, output_dim=64)
    model.eval()
    # Stand-in for ImageNet weights (none are reachable here): only the source differs.
    model.backbone_weights = "imagenet"
    path = _save(tmp_path / "head.pt", model, frozen_backbone_record(model, seed=None))
    assert torch.load(path, weights_only=True)["backbone"]["seed"] is None

    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path / "empty-hub"))

    def no_network(*args, **kwargs):
        raise AssertionError("loading a checkpoint must not touch the network")

    monkeypatch.setattr(backbones, "_probe", no_network)
    monkeypatch.setattr(torch.hub, "load_state_dict_from_url", no_network)
    hint = re.escape("--weights /path/to/resnet18-f37072fd.pth")
    with pytest.raises(FileNotFoundError, match=hint):
        load_checkpoint(path)

    # A local copy of the weights, passed explicitly, is loaded and verified.
    local = tmp_path / "my-resnet18.pth"
    torch.save(model.backbone.state_dict(), local)
    loaded = load_checkpoint(path, backbone_weights=local, device="cpu").model
    assert loaded.backbone_weights == "imagenet"  # provenance stays the recorded source
    with torch.no_grad():
        assert torch.equal(_call(loaded, (32, 32)), _call(model, (32, 32)))
    wrong = tmp_path / "other-resnet18.pth"
    torch.save(create_model("res_tf").backbone.state_dict(), wrong)
    with pytest.raises(ValueError, match="not the one the head was trained with"):
        load_checkpoint(path, backbone_weights=wrong)


def test_local_weights_file_is_recorded_and_must_exist(tmp_path):
    weights = tmp_path / "weights" / "my-resnet18.pth"
    weights.parent.mkdir()
    torch.save(create_model("res_tf").backbone.state_dict(), weights)
    model = create_model("res_tf", inputs="ALL", backbone_weights=weights).eval()
    path = _save(tmp_path / "head.pt", model, frozen_backbone_record(model, seed=None))
    assert torch.load(path, weights_only=True)["backbone"]["weights"] == str(weights.resolve())
    loaded = load_checkpoint(path, device="cpu").model
    with torch.no_grad():
        assert torch.equal(_call(loaded, (32, 32)), _call(model, (32, 32)))
    weights.unlink()
    with pytest.raises(FileNotFoundError, match="--weights PATH"):
        load_checkpoint(path)


def test_finetuned_run_keeps_the_backbone_in_its_checkpoint(toy_store, tmp_path):
    cfg = _config(
        toy_store.path,
        tmp_path,
        "res_tf",
        [
            "model.freeze_backbone=false",
            "model.finetune=last_block",
            "training.max_epochs=1",
            "training.limit_batches=2",
        ],
    )
    result = train(cfg, progress=False)
    payload = torch.load(f"{result['run_dir']}/best.pt", weights_only=True)
    assert payload["backbone"] is None
    assert any(k.startswith("backbone.layer4.") for k in payload["state_dict"])
    loaded = load_checkpoint(f"{result['run_dir']}/best.pt", device="cpu").model
    assert torch.equal(
        loaded.state_dict()["backbone.layer4.0.conv1.weight"],
        payload["state_dict"]["backbone.layer4.0.conv1.weight"],
    )


def test_pre_release_format_2_checkpoints_are_refused_naming_the_version(tmp_path):
    """Format 2 carried the input contract as loose keys (``image_size``,
    ``store_image_size``, ``normalisation``, ...); format 3 carries one ``run_inputs``."""
    model = create_model("res_tf", inputs="ALL", num_layers=1, embedding_dim=64, output_dim=64)
    path = _save(tmp_path / "v3.pt", model)
    payload = torch.load(path, weights_only=True)
    record = payload.pop("run_inputs")
    payload.update(
        format_version=2,
        inputs=record["inputs"],
        normalisation=record["normalisation"],
        image_size=None,
        store_image_size=record["store_image_size"],
    )
    torch.save(payload, tmp_path / "v2.pt")
    with pytest.raises(ValueError, match=r"format_version 2 is a pre-release format.*format 3"):
        load_checkpoint(tmp_path / "v2.pt")
    # A checkpoint of the current version without its record is refused in one line too.
    payload["format_version"] = CHECKPOINT_VERSION
    torch.save(payload, tmp_path / "norecord.pt")
    with pytest.raises(ValueError, match=r"norecord.pt: invalid run inputs"):
        load_checkpoint(tmp_path / "norecord.pt")


def test_the_run_inputs_record_round_trips_through_the_checkpoint(tmp_path):
    """Every field of the record comes back as written, the store gone or not."""
    from tactile_compliance.inference.estimator import ComplianceEstimator

    model = create_model("top10nn", inputs="ALL")
    record = RunInputs(
        image_size=(72, 80),
        store_image_size=(90, 120),
        constants=NormalisationConstants(image_mean=(0.4, 0.5, 0.6), force_scale_n=50.0),
        inputs=model.inputs,
        sensor=SensorUnits("calibrated", 12.5),
        estimator=AnalyticalEstimator("contact"),
    )
    assert record.estimator.px_per_mm == 12.5  # the estimator runs at the sensor's density
    path = save_checkpoint(
        tmp_path / "best.pt",
        model,
        run_inputs=record,
        config={"data": {"store": str(tmp_path / "deleted-store")}},
        seed=0,
    )
    payload = torch.load(path, weights_only=True)
    assert not {"image_size", "store_image_size", "normalisation", "inputs"} & set(payload)
    assert load_checkpoint(path).run_inputs == record
    estimator = ComplianceEstimator.from_checkpoint(path)
    assert estimator.run_inputs == record
    # Frames of another size are resized to the training size, not fed as they are.
    out = estimator.predict(
        np.full((3, 70, 80, 3), 128, np.uint8),
        force=[8.0, 30.0, 58.0],
        width=[0.05, 0.048, 0.046],
        estimates=[1e5, 2e5],
    )
    assert np.isfinite(out.modulus_pa)
