"""A new model is one module: a fresh process loads the checkpoint of a model that no list
names, whether the module is in ``models/`` or an installed plugin (an entry point)."""

from __future__ import annotations

import importlib.util
import json
import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import torch

from tactile_compliance.data.normalisation import NormalisationConstants
from tactile_compliance.models import registry
from tactile_compliance.runs.checkpoint import save_checkpoint
from tactile_compliance.runs.run_inputs import RunInputs

SRC = Path(__file__).resolve().parents[1] / "src"
MODELS_DIR = SRC / "tactile_compliance" / "models"

# A frame-free model (cheap to build), written the way docs/models.md says to.
PLUGIN_SOURCE = textwrap.dedent(
    '''
    import torch
    from torch import nn

    from tactile_compliance.models import InputStrategy, TactileModel, register_model


    @register_model("plugin_mlp")
    class PluginMlp(TactileModel):
        """Force and width -> one linear layer."""

        takes_images = False

        def __init__(self, inputs: InputStrategy | str = "FW", hidden: int = 5) -> None:
            super().__init__(inputs, {"hidden": hidden})
            self.mlp = nn.Sequential(nn.Linear(6, hidden), nn.ELU(), nn.Linear(hidden, 1))

        def _head(self, features, scalars):
            return self.mlp(torch.cat([scalars["force"], scalars["width"]], 1)).squeeze(1)
    '''
)

# Loads the checkpoint through the normal path and prints the model's outputs.
LOAD = textwrap.dedent(
    """
    import json, sys
    import torch
    {setup}
    from tactile_compliance.runs.checkpoint import load_checkpoint

    loaded = load_checkpoint(sys.argv[1], "cpu")
    force, width = torch.load(sys.argv[2])
    with torch.no_grad():
        out = loaded.model(None, force=force, width=width)
    print(json.dumps([type(loaded.model).__name__, out.tolist()]))
    """
)

# The module's directory joins the models package's search path, as a module saved in
# src/tactile_compliance/models/ would be found (the test must not write into src/).
IN_MODELS_DIR = "import tactile_compliance.models as models; models.__path__.append(sys.argv[3])"


def _write_plugin(root: Path, *, entry_point: bool) -> None:
    root.mkdir()
    (root / "tc_plugin_mlp.py").write_text(PLUGIN_SOURCE)
    if entry_point:
        # What `pip install` of a distribution declaring
        # [project.entry-points."tactile_compliance.models"] leaves in site-packages.
        info = root / "tc_plugin_mlp-0.1.dist-info"
        info.mkdir()
        (info / "METADATA").write_text("Metadata-Version: 2.1\nName: tc-plugin-mlp\nVersion: 0.1\n")
        (info / "entry_points.txt").write_text(
            f"[{registry.ENTRY_POINT_GROUP}]\nplugin_mlp = tc_plugin_mlp\n"
        )


def _save_plugin_checkpoint(root: Path, path: Path) -> list[float]:
    """Register the plugin in this process, save a checkpoint of it, return its outputs."""
    spec = importlib.util.spec_from_file_location("tc_plugin_mlp", root / "tc_plugin_mlp.py")
    module = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(module)
        torch.manual_seed(3)
        model = module.PluginMlp("FW", hidden=4).eval()
    finally:
        registry._REGISTRY.pop("plugin_mlp", None)
    save_checkpoint(
        path,
        model,
        run_inputs=RunInputs(None, (32, 32), NormalisationConstants(), model.inputs),
        config={},
        seed=0,
    )
    force, width = torch.rand(2, 3, generator=torch.Generator().manual_seed(1)).split(1)
    torch.save((force, width), path.parent / "inputs.pt")
    with torch.no_grad():
        return model(None, force=force, width=width).tolist()


def _fresh_python(code: str, *args: Path, extra_path: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(extra_path), str(SRC)]))
    env["OMP_NUM_THREADS"] = "1"
    return subprocess.run(
        [sys.executable, "-c", code, *map(str, args)],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )


@pytest.mark.parametrize("where", ["models_dir", "entry_point"])
def test_a_model_in_its_own_module_loads_in_a_fresh_process(tmp_path: Path, where: str) -> None:
    root = tmp_path / "plugin"
    _write_plugin(root, entry_point=where == "entry_point")
    checkpoint = tmp_path / "best.pt"
    expected = _save_plugin_checkpoint(root, checkpoint)
    setup = IN_MODELS_DIR if where == "models_dir" else ""
    # The entry point's module is importable (PYTHONPATH), but nothing imports it by name.
    extra = root if where == "entry_point" else tmp_path
    result = _fresh_python(
        LOAD.format(setup=setup), checkpoint, tmp_path / "inputs.pt", root, extra_path=extra
    )
    assert result.returncode == 0, result.stderr
    name, outputs = json.loads(result.stdout.splitlines()[-1])
    assert name == "PluginMlp"
    assert outputs == pytest.approx(expected, abs=1e-6)


def test_the_registry_finds_every_module_of_models_and_nothing_else(tmp_path: Path) -> None:
    # A lookup through the registry module itself (not the package's names) finds every
    # `@register_model` of models/*.py; the plugin module on sys.path, without an entry
    # point or a place in models/, is not found, so the test above can fail.
    declared = sorted(
        name
        for path in MODELS_DIR.glob("*.py")
        for name in re.findall(r'@register_model\("(\w+)"\)', path.read_text())
    )
    root = tmp_path / "plugin"
    _write_plugin(root, entry_point=False)
    checkpoint = tmp_path / "best.pt"
    _save_plugin_checkpoint(root, checkpoint)
    setup = (
        "from tactile_compliance.models.registry import list_models; "
        "print(json.dumps(list_models()), flush=True)"
    )
    result = _fresh_python(
        LOAD.format(setup=setup), checkpoint, tmp_path / "inputs.pt", root, extra_path=root
    )
    assert json.loads(result.stdout.splitlines()[0]) == declared and len(declared) >= 4
    assert result.returncode != 0
    assert "unknown model 'plugin_mlp'" in result.stderr


def test_a_plugin_that_fails_to_import_is_skipped_with_a_warning(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    class Broken:
        name, value = "broken", "no_such_module_xyz"

        def load(self):
            raise ModuleNotFoundError("No module named 'no_such_module_xyz'")

    monkeypatch.setattr(registry, "_discovered", False)
    monkeypatch.setattr(registry.importlib.metadata, "entry_points", lambda group: [Broken()])
    with pytest.warns(RuntimeWarning, match=r"model plugin 'broken' \(no_such_module_xyz\)"):
        registry.discover_models()
    assert "res_tf" in registry.list_models()
