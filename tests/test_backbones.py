"""Tests of the project's VGG16/ResNet backbones and their weight loading.

No pretrained weights are reachable here, so loading is tested with state dicts saved from
randomly initialised backbones, named and laid out like torchvision's files.
"""

from __future__ import annotations

import hashlib
import socket
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import torch

from tactile_compliance.models import BACKBONE_WEIGHTS_URLS, create_backbone, list_backbones
from tactile_compliance.models import backbones as backbones_module

FEATURE_DIMS = {"vgg16": 4096, "resnet18": 512, "resnet34": 512, "resnet50": 2048}
# torchvision's parameter counts without the 1000-class layer (classifier.6 / fc),
# e.g. resnet18: 11,689,512 - (512 * 1000 + 1000).
TORCHVISION_PARAMS_WITHOUT_HEAD = {
    "vgg16": 138_357_544 - (4096 * 1000 + 1000),
    "resnet18": 11_689_512 - (512 * 1000 + 1000),
    "resnet34": 21_797_672 - (512 * 1000 + 1000),
    "resnet50": 25_557_032 - (2048 * 1000 + 1000),
}
# A few torchvision key names per backbone, including the tricky ones (downsample, fc7).
TORCHVISION_KEYS = {
    "vgg16": ["features.0.weight", "features.28.bias", "classifier.0.weight", "classifier.3.bias"],
    "resnet18": [
        "conv1.weight",
        "bn1.running_var",
        "layer1.0.conv2.weight",
        "layer2.0.downsample.0.weight",
        "layer2.0.downsample.1.running_mean",
        "layer4.1.bn2.num_batches_tracked",
    ],
    "resnet34": ["layer3.5.conv2.weight", "layer4.0.downsample.1.weight"],
    "resnet50": ["layer1.0.conv3.weight", "layer1.0.downsample.0.weight", "layer4.2.bn3.bias"],
}


@pytest.fixture(autouse=True, scope="module")
def _one_thread() -> Iterator[None]:
    """Single-threaded: tiny tensors, and competing thread pools on shared cores spin."""
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _save_resnet18(path: Path, seed: int = 0, with_fc: bool = True) -> dict[str, torch.Tensor]:
    """Save a random ResNet18 state dict laid out like torchvision's (incl. ``fc``)."""
    torch.manual_seed(seed)
    state = create_backbone("resnet18").state_dict()
    if with_fc:
        state = {**state, "fc.weight": torch.randn(1000, 512), "fc.bias": torch.zeros(1000)}
    torch.save(state, path)
    return state


def test_list_backbones() -> None:
    assert list_backbones() == ["resnet18", "resnet34", "resnet50", "vgg16"]
    assert set(BACKBONE_WEIGHTS_URLS) == set(list_backbones())
    for name, url in BACKBONE_WEIGHTS_URLS.items():
        assert url.startswith("https://download.pytorch.org/models/" + name + "-")


@pytest.mark.parametrize("name", sorted(FEATURE_DIMS))
def test_backbone_shapes_and_torchvision_layout(name: str) -> None:
    torch.manual_seed(0)
    backbone = create_backbone(name).eval()
    assert backbone.feature_dim == FEATURE_DIMS[name]
    with torch.no_grad():
        features = backbone(torch.randn(2, 3, 32, 48))
    assert features.shape == (2, FEATURE_DIMS[name])
    assert torch.isfinite(features).all()
    # The two samples must not collapse to the same vector.
    assert not torch.allclose(features[0], features[1])
    keys = set(backbone.state_dict())
    assert set(TORCHVISION_KEYS[name]) <= keys
    assert not any(k.startswith(("fc.", "classifier.6.")) for k in keys)
    assert sum(p.numel() for p in backbone.parameters()) == TORCHVISION_PARAMS_WITHOUT_HEAD[name]


def test_unknown_backbone() -> None:
    with pytest.raises(ValueError, match=r"alexnet.*resnet18, resnet34, resnet50, vgg16"):
        create_backbone("alexnet")


def test_construction_never_touches_the_network(monkeypatch: pytest.MonkeyPatch) -> None:
    def no_network(*args, **kwargs):
        raise AssertionError("network access during construction")

    monkeypatch.setattr(socket, "create_connection", no_network)
    monkeypatch.setattr(socket.socket, "connect", no_network)
    monkeypatch.setattr(torch.hub, "load_state_dict_from_url", no_network)
    for name in ("resnet18", "resnet34", "resnet50"):
        create_backbone(name)
        create_backbone(name, weights="none")


def test_local_state_dict_round_trip(tmp_path: Path) -> None:
    path = tmp_path / "my_resnet18.pth"
    saved = _save_resnet18(path, seed=1)
    torch.manual_seed(2)  # the new backbone's own init differs from the saved one
    backbone = create_backbone("resnet18", weights=path)
    loaded = backbone.state_dict()
    for key, value in loaded.items():
        assert torch.equal(value, saved[key]), key
    # str paths work too, and the loaded weights define the output.
    again = create_backbone("resnet18", weights=str(path)).eval()
    x = torch.randn(2, 3, 32, 32)
    with torch.no_grad():
        torch.testing.assert_close(backbone.eval()(x), again(x), rtol=0, atol=0)


def test_hash_named_file_is_verified(tmp_path: Path) -> None:
    plain = tmp_path / "plain.pth"
    _save_resnet18(plain)
    good = tmp_path / f"resnet18-{_sha256(plain)[:8]}.pth"
    plain.rename(good)
    create_backbone("resnet18", weights=good)

    # Same bytes under the official name: the sha256 prefix does not match -> clear error.
    wrong = tmp_path / "resnet18-f37072fd.pth"
    good.rename(wrong)
    with pytest.raises(RuntimeError, match=r"sha256 mismatch.*f37072fd"):
        create_backbone("resnet18", weights=wrong)


def test_corrupted_file(tmp_path: Path) -> None:
    path = tmp_path / "resnet18_truncated.pth"
    _save_resnet18(path)
    path.write_bytes(path.read_bytes()[:1000])
    with pytest.raises(RuntimeError, match=r"cannot read backbone weights from .*truncated"):
        create_backbone("resnet18", weights=path)


def test_mismatched_state_dicts(tmp_path: Path) -> None:
    path = tmp_path / "r18.pth"
    state = _save_resnet18(path, with_fc=False)
    # ResNet18 weights into a ResNet34: the extra blocks are reported as missing.
    with pytest.raises(RuntimeError, match=r"missing keys: .*layer1\.2\.") as info:
        create_backbone("resnet34", weights=path)
    assert str(path) in str(info.value)

    partial = tmp_path / "partial.pth"
    torch.save({k: v for k, v in state.items() if k != "layer3.0.conv1.weight"}, partial)
    with pytest.raises(RuntimeError, match=r"missing keys: layer3\.0\.conv1\.weight"):
        create_backbone("resnet18", weights=partial)

    extra = tmp_path / "extra.pth"
    torch.save({**state, "head.weight": torch.zeros(1)}, extra)
    with pytest.raises(RuntimeError, match=r"unexpected keys: head\.weight"):
        create_backbone("resnet18", weights=extra)

    reshaped = tmp_path / "reshaped.pth"
    torch.save({**state, "conv1.weight": torch.zeros(64, 3, 3, 3)}, reshaped)
    with pytest.raises(RuntimeError, match=r"shape mismatches: conv1\.weight"):
        create_backbone("resnet18", weights=reshaped)

    not_a_state_dict = tmp_path / "list.pth"
    torch.save([torch.zeros(1)], not_a_state_dict)
    with pytest.raises(RuntimeError, match="state dict"):
        create_backbone("resnet18", weights=not_a_state_dict)

    with pytest.raises(FileNotFoundError, match="does not exist"):
        create_backbone("resnet18", weights=tmp_path / "missing.pth")


def test_wrapped_checkpoint_is_unwrapped(tmp_path: Path) -> None:
    plain = tmp_path / "plain.pth"
    state = _save_resnet18(plain)
    wrapped = tmp_path / "wrapped.ckpt"
    torch.save({"state_dict": state}, wrapped)
    backbone = create_backbone("resnet18", weights=wrapped)
    assert torch.equal(backbone.conv1.weight, state["conv1.weight"])


def _network_reachable() -> bool:
    try:
        with socket.create_connection(("download.pytorch.org", 443), timeout=2):
            return True
    except OSError:
        return False


def test_imagenet_offline_fails_fast(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    if _network_reachable():
        pytest.skip("the network is reachable here; the offline path cannot be exercised")
    # An empty hub directory, so no cached file can satisfy the request.
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path / "hub"))
    start = time.monotonic()
    with pytest.raises(RuntimeError) as info:
        create_backbone("resnet18", weights="imagenet")
    elapsed = time.monotonic() - start
    message = str(info.value)
    assert "--weights /path/to/resnet18-f37072fd.pth" in message
    assert BACKBONE_WEIGHTS_URLS["resnet18"] in message
    assert elapsed < 10, f"took {elapsed:.1f} s to fail"


def test_imagenet_uses_the_torch_hub_cache_offline(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    hub = tmp_path / "hub"
    (hub / "checkpoints").mkdir(parents=True)
    saved = _save_resnet18(hub / "checkpoints" / "resnet18-f37072fd.pth", seed=3)
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(hub))

    def no_probe(*args, **kwargs):
        raise AssertionError("a cached file must not trigger a network probe")

    monkeypatch.setattr(backbones_module, "_probe", no_probe)
    backbone = create_backbone("resnet18", weights="imagenet")
    assert torch.equal(backbone.conv1.weight, saved["conv1.weight"])
