"""Image backbones (VGG16, ResNet18/34/50) defined in the project, torchvision-compatible.

Each maps ``(N, 3, H, W)`` images to ``(N, feature_dim)`` and has ``min_input_size``;
weights: docs/models.md, "Backbone weights".
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import re
import socket
import urllib.error
import urllib.parse
import urllib.request
from collections.abc import Callable, Iterator, Mapping
from contextvars import ContextVar
from pathlib import Path
from typing import Any

import torch
from torch import nn

from tactile_compliance.data.safe_pickle import UnreadableTorchFileError, load_torch_file
from tactile_compliance.models.frame_rules import VGG16_MIN_INPUT_PX

__all__ = [
    "BACKBONE_WEIGHTS_URLS",
    "PRETRAIN_KEY",
    "VGG16",
    "BackboneWeightsError",
    "ResNet",
    "create_backbone",
    "file_sha256",
    "list_backbones",
    "load_mapped",
    "load_weights_file",
    "no_downloads",
]

#: Key of the provenance record (store, split, epochs, depth loss) in a weights file
#: written by ``tactile-compliance pretrain``; its state dict is under ``state_dict``.
PRETRAIN_KEY = "tactile_compliance_pretrain"

#: Official torchvision ImageNet weights (the IMAGENET1K_V1 files). The 8 hex digits in
#: each file name are the start of the file's sha256, which torch.hub checks.
BACKBONE_WEIGHTS_URLS: dict[str, str] = {
    "vgg16": "https://download.pytorch.org/models/vgg16-397923af.pth",
    "resnet18": "https://download.pytorch.org/models/resnet18-f37072fd.pth",
    "resnet34": "https://download.pytorch.org/models/resnet34-b627a593.pth",
    "resnet50": "https://download.pytorch.org/models/resnet50-0676ba61.pth",
}

# Keys of the torchvision classification layer, which our feature extractors do not have.
_IGNORED_PREFIXES: dict[str, tuple[str, ...]] = {
    "vgg16": ("classifier.6.",),
    "resnet18": ("fc.",),
    "resnet34": ("fc.",),
    "resnet50": ("fc.",),
}

# torchvision's file naming convention: "<name>-<first hex digits of the sha256>.pth".
# Only names of our backbones count, so a user's "run-100000.pth" is not mistaken for one.
_HASH_IN_NAME = re.compile(
    r"^(?P<stem>vgg16|resnet18|resnet34|resnet50)-(?P<hash>[0-9a-f]{8,64})\.pth$"
)

# False inside no_downloads(): "imagenet" then means "the torch.hub cache or nothing".
_DOWNLOADS_ALLOWED: ContextVar[bool] = ContextVar("backbone_downloads_allowed", default=True)

# Seconds allowed for the connectivity probe before an ImageNet download; kept short so
# an offline machine gets an answer at once instead of a hanging download.
_PROBE_TIMEOUT_S = 3.0


# --------------------------------------------------------------------------- VGG16

_VGG16_CONFIG: list[int | str] = [
    64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512, "M",
]  # fmt: skip


class VGG16(nn.Module):
    """VGG16 up to fc7, ``(N, 4096)``; module indices as in torchvision's ``vgg16``."""

    feature_dim: int = 4096
    # Five 2x2 max-pools without padding: anything smaller than 32 pixels pools to nothing.
    min_input_size: int = VGG16_MIN_INPUT_PX

    def __init__(self, dropout: float = 0.5) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        in_channels = 3
        for item in _VGG16_CONFIG:
            if item == "M":
                layers.append(nn.MaxPool2d(kernel_size=2, stride=2))
            else:
                assert isinstance(item, int)
                layers.append(nn.Conv2d(in_channels, item, kernel_size=3, padding=1))
                layers.append(nn.ReLU(inplace=True))
                in_channels = item
        self.features = nn.Sequential(*layers)
        self.avgpool = nn.AdaptiveAvgPool2d((7, 7))
        # fc6 -> ReLU -> Dropout -> fc7; indices 0 and 3 as in torchvision (fc8 = index 6
        # is left out on purpose: the models consume the 4096-d fc7 features).
        self.classifier = nn.Sequential(
            nn.Linear(512 * 7 * 7, 4096),
            nn.ReLU(inplace=True),
            nn.Dropout(p=dropout),
            nn.Linear(4096, 4096),
        )
        # torchvision's scheme, so "none" weights behave like an untrained torchvision model.
        for module in self.modules():
            if isinstance(module, nn.Conv2d):
                nn.init.kaiming_normal_(module.weight, mode="fan_out", nonlinearity="relu")
                if module.bias is not None:
                    nn.init.zeros_(module.bias)
            elif isinstance(module, nn.Linear):
                nn.init.normal_(module.weight, 0.0, 0.01)
                nn.init.zeros_(module.bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.features(x)
        x = self.avgpool(x)
        return self.classifier(torch.flatten(x, 1))


# -------------------------------------------------------------------------- ResNets


def _conv3x3(in_planes: int, out_planes: int, stride: int = 1) -> nn.Conv2d:
    return nn.Conv2d(in_planes, out_planes, kernel_size=3, stride=stride, padding=1, bias=False)


def _conv1x1(in_planes: int, out_planes: int, stride: int = 1) -> nn.Conv2d:
    return nn.Conv2d(in_planes, out_planes, kernel_size=1, stride=stride, bias=False)


class _ResidualBlock(nn.Module):
    """``relu(branch(x) + downsample(x))`` (torchvision's names); subclasses build the branch."""

    expansion: int = 1

    def __init__(
        self, inplanes: int, planes: int, stride: int = 1, downsample: nn.Module | None = None
    ) -> None:
        super().__init__()
        self._build_branch(inplanes, planes, stride)
        self.relu = nn.ReLU(inplace=True)
        self.downsample = downsample

    def _build_branch(self, inplanes: int, planes: int, stride: int) -> None:
        raise NotImplementedError

    def _branch(self, x: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        identity = x if self.downsample is None else self.downsample(x)
        return self.relu(self._branch(x) + identity)


class BasicBlock(_ResidualBlock):
    """Two 3x3 convolutions with a residual connection (ResNet18/34)."""

    def _build_branch(self, inplanes: int, planes: int, stride: int) -> None:
        self.conv1 = _conv3x3(inplanes, planes, stride)
        self.bn1 = nn.BatchNorm2d(planes)
        self.conv2 = _conv3x3(planes, planes)
        self.bn2 = nn.BatchNorm2d(planes)

    def _branch(self, x: torch.Tensor) -> torch.Tensor:
        out = self.relu(self.bn1(self.conv1(x)))
        return self.bn2(self.conv2(out))


class Bottleneck(_ResidualBlock):
    """1x1-3x3-1x1 bottleneck with a residual connection (ResNet50); stride on the 3x3."""

    expansion: int = 4

    def _build_branch(self, inplanes: int, planes: int, stride: int) -> None:
        self.conv1 = _conv1x1(inplanes, planes)
        self.bn1 = nn.BatchNorm2d(planes)
        self.conv2 = _conv3x3(planes, planes, stride)
        self.bn2 = nn.BatchNorm2d(planes)
        self.conv3 = _conv1x1(planes, planes * self.expansion)
        self.bn3 = nn.BatchNorm2d(planes * self.expansion)

    def _branch(self, x: torch.Tensor) -> torch.Tensor:
        out = self.relu(self.bn1(self.conv1(x)))
        out = self.relu(self.bn2(self.conv2(out)))
        return self.bn3(self.conv3(out))


class ResNet(nn.Module):
    """ResNet trunk without ``avgpool``/``fc`` (torchvision's parameter names); output:
    the spatial mean of ``layer4``, ``(N, 512 * block.expansion)``."""

    # The stem and every stage pad their inputs, so even a 1x1 image yields features.
    min_input_size: int = 1

    def __init__(self, block: type[_ResidualBlock], layers: list[int]) -> None:
        super().__init__()
        self.inplanes = 64
        self.conv1 = nn.Conv2d(3, 64, kernel_size=7, stride=2, padding=3, bias=False)
        self.bn1 = nn.BatchNorm2d(64)
        self.relu = nn.ReLU(inplace=True)
        self.maxpool = nn.MaxPool2d(kernel_size=3, stride=2, padding=1)
        self.layer1 = self._make_layer(block, 64, layers[0])
        self.layer2 = self._make_layer(block, 128, layers[1], stride=2)
        self.layer3 = self._make_layer(block, 256, layers[2], stride=2)
        self.layer4 = self._make_layer(block, 512, layers[3], stride=2)
        self.feature_dim: int = 512 * block.expansion
        for module in self.modules():
            if isinstance(module, nn.Conv2d):
                nn.init.kaiming_normal_(module.weight, mode="fan_out", nonlinearity="relu")
            elif isinstance(module, nn.BatchNorm2d):
                nn.init.ones_(module.weight)
                nn.init.zeros_(module.bias)

    def _make_layer(
        self, block: type[_ResidualBlock], planes: int, blocks: int, stride: int = 1
    ) -> nn.Sequential:
        downsample: nn.Module | None = None
        if stride != 1 or self.inplanes != planes * block.expansion:
            downsample = nn.Sequential(
                _conv1x1(self.inplanes, planes * block.expansion, stride),
                nn.BatchNorm2d(planes * block.expansion),
            )
        layers: list[nn.Module] = [block(self.inplanes, planes, stride, downsample)]
        self.inplanes = planes * block.expansion
        layers.extend(block(self.inplanes, planes) for _ in range(1, blocks))
        return nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.maxpool(self.relu(self.bn1(self.conv1(x))))
        x = self.layer4(self.layer3(self.layer2(self.layer1(x))))
        return x.mean(dim=(2, 3))


_BACKBONE_FACTORIES: dict[str, Callable[[], nn.Module]] = {
    "vgg16": VGG16,
    "resnet18": lambda: ResNet(BasicBlock, [2, 2, 2, 2]),
    "resnet34": lambda: ResNet(BasicBlock, [3, 4, 6, 3]),
    "resnet50": lambda: ResNet(Bottleneck, [3, 4, 6, 3]),
}


def list_backbones() -> list[str]:
    """Names accepted by :func:`create_backbone`, sorted."""
    return sorted(_BACKBONE_FACTORIES)


# -------------------------------------------------------------------------- weights


class BackboneWeightsError(RuntimeError):
    """Backbone weights cannot be had or do not fit: offline, a wrong sha256, an
    unreadable file, or another network's state dict. The message names the source."""


def file_sha256(path: str | Path) -> str:
    """sha256 of a file's bytes, read in 1 MiB blocks (weights, splits, exports)."""
    digest = hashlib.sha256()
    with Path(path).open("rb") as handle:
        for chunk in iter(lambda: handle.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def _offline_message(name: str, url: str, reason: str) -> str:
    filename = url.rsplit("/", 1)[-1]
    return (
        f"cannot download the ImageNet weights for {name!r} ({reason}). "
        f"Download {url} on a machine with internet access, copy it here and pass the file "
        f"instead of 'imagenet', e.g. `--weights /path/to/{filename}` "
        f"(in Python: weights='/path/to/{filename}'), or put it into "
        f"{Path(torch.hub.get_dir()) / 'checkpoints'} where torch.hub finds it; "
        f"or use weights='none' for random initialisation."
    )


def _probe(url: str, timeout: float = _PROBE_TIMEOUT_S) -> None:
    """Connect to the host (or HTTPS proxy) that would serve ``url``: OSError in seconds
    on an offline machine instead of urllib's long timeouts."""
    proxy = urllib.request.getproxies().get("https")
    parsed = urllib.parse.urlsplit(proxy if proxy else url)
    host = parsed.hostname
    if host is None:
        raise OSError(f"cannot parse a host name from {proxy or url!r}")
    port = parsed.port or (443 if parsed.scheme == "https" else 80)
    with socket.create_connection((host, port), timeout=timeout):
        pass


@contextlib.contextmanager
def no_downloads() -> Iterator[None]:
    """Within this block, ``"imagenet"`` weights come from the torch.hub cache only: loading
    a checkpoint must work offline and never fetch half a gigabyte behind the user's back.
    A file missing from the cache is a FileNotFoundError naming the ``--weights PATH``
    alternative."""
    token = _DOWNLOADS_ALLOWED.set(False)
    try:
        yield
    finally:
        _DOWNLOADS_ALLOWED.reset(token)


def _load_imagenet_state_dict(name: str) -> dict[str, torch.Tensor]:
    url = BACKBONE_WEIGHTS_URLS[name]
    filename = url.rsplit("/", 1)[-1]
    cached = Path(torch.hub.get_dir()) / "checkpoints" / filename
    if not cached.is_file() and not _DOWNLOADS_ALLOWED.get():
        raise FileNotFoundError(
            f"the ImageNet weights of {name!r} are not in the torch.hub cache ({cached}) and "
            f"loading a checkpoint never downloads. Pass a local copy of {url} with "
            f"`--weights /path/to/{filename}` (in Python: backbone_weights='/path/to/"
            f"{filename}'), or copy it to {cached}."
        )
    if not cached.is_file():
        # Only probe when a download is really needed: a cached file must load offline.
        try:
            _probe(url)
        except OSError as exc:
            raise BackboneWeightsError(
                _offline_message(name, url, f"no connection: {exc}")
            ) from exc
    try:
        return torch.hub.load_state_dict_from_url(
            url, map_location="cpu", progress=True, check_hash=True, weights_only=True
        )
    except (urllib.error.URLError, OSError, TimeoutError) as exc:
        raise BackboneWeightsError(_offline_message(name, url, f"download failed: {exc}")) from exc


def load_weights_file(backbone: nn.Module, name: str, path: str | os.PathLike[str]) -> None:
    """Load a local weights file (a state dict, or ``{"state_dict": ...}``) into
    ``backbone`` (``name``: which keys to ignore), checking that it fits.

    Raises:
        FileNotFoundError: no such file.
        BackboneWeightsError: unreadable, not a state dict, another network's, or a
            torchvision-style ``NAME-HASH.pth`` whose sha256 does not start with ``HASH``.
    """
    path = Path(path).expanduser()
    if not path.is_file():
        raise FileNotFoundError(
            f"backbone weights file {path} does not exist; pass 'none', 'imagenet' or the "
            f"path of a state dict (.pth)"
        )
    match = _HASH_IN_NAME.match(path.name)
    if match is not None:
        # torchvision convention: the name carries the sha256 prefix. Checking it catches
        # truncated downloads and files renamed to the wrong backbone.
        expected = match.group("hash")
        actual = file_sha256(path)
        if not actual.startswith(expected):
            raise BackboneWeightsError(
                f"sha256 mismatch for {path}: the file name promises a hash starting with "
                f"{expected}, the file's sha256 is {actual}. The file is corrupted or "
                f"incomplete; download it again (or rename it if it is a different file)."
            )
    try:
        loaded = load_torch_file(path, "backbone weights file")
    except UnreadableTorchFileError as exc:
        raise BackboneWeightsError(
            f"cannot read backbone weights from {path}: {exc.reason}. Expected a state dict "
            f"saved with torch.save (tensors only)."
        ) from exc
    # Accept checkpoints that wrap the state dict (Lightning and many training scripts).
    if (
        isinstance(loaded, Mapping)
        and "state_dict" in loaded
        and isinstance(loaded["state_dict"], Mapping)
    ):
        loaded = loaded["state_dict"]
    if not isinstance(loaded, Mapping) or not all(
        isinstance(v, torch.Tensor) for v in loaded.values()
    ):
        raise BackboneWeightsError(
            f"{path} does not contain a state dict (a mapping of parameter names to tensors)"
        )
    load_backbone_weights(backbone, name, dict(loaded), str(path))


def load_backbone_weights(
    backbone: nn.Module, name: str, state_dict: Mapping[str, torch.Tensor], source: str
) -> None:
    """Copy ``state_dict`` into ``backbone``, ignoring only the torchvision classifier keys;
    a misfit is a BackboneWeightsError naming ``source`` (a path or URL) and the keys."""
    ignored = _IGNORED_PREFIXES.get(name, ())
    filtered = {k: v for k, v in state_dict.items() if not k.startswith(ignored)}
    own = backbone.state_dict()
    missing = sorted(set(own) - set(filtered))
    unexpected = sorted(set(filtered) - set(own))
    mismatched = sorted(
        f"{k}: file {tuple(filtered[k].shape)} vs model {tuple(own[k].shape)}"
        for k in set(own) & set(filtered)
        if filtered[k].shape != own[k].shape
    )
    if missing or unexpected or mismatched:

        def _preview(keys: list[str]) -> str:
            shown = ", ".join(keys[:8])
            return shown + (f", ... ({len(keys)} in total)" if len(keys) > 8 else "")

        problems = []
        if missing:
            problems.append(f"missing keys: {_preview(missing)}")
        if unexpected:
            problems.append(f"unexpected keys: {_preview(unexpected)}")
        if mismatched:
            problems.append(f"shape mismatches: {_preview(mismatched)}")
        raise BackboneWeightsError(
            f"weights from {source} do not fit backbone {name!r} "
            f"(is it a torchvision {name} state dict?): " + "; ".join(problems)
        )
    backbone.load_state_dict(filtered, strict=True)


def load_mapped(path: str | os.PathLike[str]) -> Any:
    """``torch.load`` (CPU, weights only) memory-mapped: tensors are read only when used."""
    try:
        return torch.load(path, map_location="cpu", weights_only=True, mmap=True)
    except Exception:  # an old-format (non-zip) file cannot be mapped: read it whole
        return torch.load(path, map_location="cpu", weights_only=True)


def create_backbone(name: str, weights: str | os.PathLike[str] = "none") -> nn.Module:
    """Build a per-frame image encoder ``(N, 3, H, W) -> (N, feature_dim)``.

    Args:
        name: one of :func:`list_backbones`, case-insensitive.
        weights: ``"none"`` (random initialisation; never touches the network),
            ``"imagenet"`` (the torch.hub cache, else a download that fails within
            seconds offline) or the path of a local state dict (docs/models.md, "Backbone
            weights").

    Returns:
        The backbone, with ``feature_dim`` and ``min_input_size`` attributes.

    Raises:
        ValueError: unknown backbone name.
        BackboneWeightsError: "imagenet" without internet, or a weights file that is
            corrupted or does not fit.
        FileNotFoundError: a weights path that does not exist.
    """
    key = name.strip().lower()
    if key not in _BACKBONE_FACTORIES:
        raise ValueError(f"unknown backbone {name!r}; available: {', '.join(list_backbones())}")
    backbone = _BACKBONE_FACTORIES[key]()
    weights_str = os.fspath(weights)
    if weights_str.lower() == "imagenet":
        state_dict = _load_imagenet_state_dict(key)
        load_backbone_weights(backbone, key, state_dict, BACKBONE_WEIGHTS_URLS[key])
    elif weights_str.lower() != "none":
        load_weights_file(backbone, key, weights_str)
    return backbone
