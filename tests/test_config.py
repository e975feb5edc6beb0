"""Experiment configuration: presets, overrides, clear errors, impossible combinations."""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
import pytest
import yaml

from tactile_compliance.config import (
    ConfigError,
    ExperimentConfig,
    apply_overrides,
    config_from_dict,
    config_to_dict,
    list_presets,
    load_config,
    preset_path,
    save_config,
)
from tactile_compliance.data.normalisation import NormalisationConstants
from tactile_compliance.runs.config_checks import check_config_against_samples


def _keys(d: dict, prefix: str = "") -> set[str]:
    out = set()
    for k, v in d.items():
        if isinstance(v, dict) and k != "hparams":
            out |= _keys(v, f"{prefix}{k}.")
        else:
            out.add(prefix + k)
    return out


def test_default_preset_loads_and_is_complete():
    cfg = load_config("default")
    assert cfg == ExperimentConfig()  # the YAML states the code defaults, nothing else
    raw = yaml.safe_load(preset_path("default").read_text())
    assert _keys(raw) == _keys(config_to_dict(cfg))  # every key is spelled out in the file
    assert cfg.split.test_fraction == 0.2 and cfg.split.val_fraction == 0.2
    assert cfg.sampling.n_bins == 9 and cfg.training.max_epochs == 200
    assert cfg.training.patience == 30 and cfg.training.l2_weight == 5e-5
    assert cfg.augmentation.noise_std == pytest.approx(15 / 255)
    assert cfg.normalisation_constants() == NormalisationConstants()
    assert {"default", "yuan"} <= set(list_presets())


def test_yuan_preset_uses_shore_range_and_image_only():
    cfg = load_config("yuan")
    assert cfg.inputs == "Image" and cfg.data.source == "yuan"
    shore = NormalisationConstants.for_shore_data()
    c = cfg.normalisation_constants()
    assert (c.label_log10_min, c.label_log10_max) == pytest.approx((3.0, 7.0))
    assert c.label_range_pa == pytest.approx(shore.label_range_pa)


def test_overrides_are_parsed_as_yaml():
    cfg = load_config(
        "default",
        [
            "split.condition=unseen",
            "training.lr=1e-4",
            "training.gamma=0.97",
            "training.precision=bf16-mixed",
            "split.subset=3",
            "data.image_size=[224, 224]",
            "model.hparams.dropout=0.3",
            "model.hparams.decoder=[512, 512]",
            "inputs=image_fw",
            "seed=7",
        ],
    )
    assert cfg.split.condition == "unseen"
    assert cfg.training.lr == 1e-4 and isinstance(cfg.training.lr, float)
    assert cfg.training.gamma == 0.97 and cfg.training.precision == "bf16-mixed"
    assert cfg.split.subset == 3
    assert cfg.data.image_size == (224, 224)
    assert cfg.model.hparams == {"dropout": 0.3, "decoder": [512, 512]}
    assert cfg.inputs == "ImageFW" and cfg.seed == 7
    assert load_config("default", ["training.gamma=null"]).training.gamma is None
    assert load_config("default", ["split.subset=Sphere"]).split.subset == "Sphere"


def test_unknown_key_names_the_dotted_key_and_valid_keys(tmp_path):
    with pytest.raises(ConfigError) as err:
        load_config("default", ["split.conditon=unseen"])
    msg = str(err.value)
    assert "split.conditon" in msg and "condition" in msg and "grouping" in msg
    path = tmp_path / "c.yaml"
    path.write_text("training:\n  learning_rate: 0.1\n")
    with pytest.raises(ValueError, match=r"unknown key 'training.learning_rate'.*\blr\b"):
        load_config(path)
    path.write_text("sampler: {}\n")
    with pytest.raises(ValueError, match=r"unknown key 'sampler'.*sampling"):
        load_config(path)


def test_wrong_type_names_the_dotted_path():
    with pytest.raises(ConfigError, match=r"training\.batch_size.*'many'"):
        load_config("default", ["training.batch_size=many"])
    with pytest.raises(ConfigError, match=r"split\.condition"):
        load_config("default", ["split.condition=sometimes"])
    with pytest.raises(ConfigError, match=r"data\.label_range_pa"):
        load_config("default", ["data.label_range_pa=[1e7, 1e3]"])
    with pytest.raises(ConfigError, match=r"inputs"):
        load_config("default", ["inputs=ImageE"])
    with pytest.raises(ConfigError, match="not a section"):
        load_config("default", ["training.lr.value=1"])
    with pytest.raises(ConfigError, match=r"section\.key=value"):
        load_config("default", ["training.lr"])


def test_impossible_combinations_raise():
    with pytest.raises(ConfigError, match=r"yuan.*Image"):
        load_config("yuan", ["inputs=ALL"])
    with pytest.raises(ConfigError, match="per_sample"):
        load_config("default", ["split.condition=unseen", "split.grouping=per_sample"])
    with pytest.raises(ConfigError, match=r"sampling\.t_balance"):
        load_config("default", ["sampling.strategy=balanced", "sampling.t_balance=1.5"])
    with pytest.raises(ConfigError, match=r"split\.subset"):
        load_config("default", ["split.subset=7"])
    with pytest.raises(ConfigError, match=r"training\.device"):
        load_config("default", ["training.device=tpu"])


def test_augmentation_with_frozen_backbone_warns_not_errors():
    with pytest.warns(UserWarning, match="cached image features"):
        cfg = load_config("default", ["model.freeze_backbone=true"])
    assert cfg.model.freeze_backbone
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_config("default", ["model.freeze_backbone=true", "augmentation.enabled=false"])


def test_save_and_reload_roundtrip(tmp_path):
    cfg = load_config(
        "default",
        [
            "split.subset=soft",
            "training.gamma=0.95",
            "model.hparams.layers=4",
            "data.image_size=128",
        ],
    )
    path = save_config(cfg, tmp_path / "out" / "config.yaml")
    assert load_config(path) == cfg
    assert config_from_dict(config_to_dict(cfg)) == cfg


def test_base_inheritance_and_cycles(tmp_path):
    (tmp_path / "parent.yaml").write_text("base: default\ntraining:\n  lr: 1.0e-3\n")
    (tmp_path / "child.yaml").write_text("base: parent.yaml\ntraining:\n  batch_size: 8\n")
    cfg = load_config(tmp_path / "child.yaml")
    assert cfg.training.lr == 1e-3 and cfg.training.batch_size == 8
    assert cfg.training.max_epochs == 200  # from default
    (tmp_path / "a.yaml").write_text("base: b.yaml\n")
    (tmp_path / "b.yaml").write_text("base: a.yaml\n")
    with pytest.raises(ConfigError, match="circular"):
        load_config(tmp_path / "a.yaml")


def test_file_errors(tmp_path):
    with pytest.raises(ConfigError, match=r"presets: .*default"):
        load_config("no_such_preset")
    with pytest.raises(ConfigError, match="does not exist"):
        load_config(tmp_path / "missing.yaml")
    dup = tmp_path / "dup.yaml"
    dup.write_text("seed: 1\nseed: 2\n")
    with pytest.raises(ConfigError, match="duplicate key"):
        load_config(dup)
    bad = tmp_path / "bad.yaml"
    bad.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="mapping"):
        load_config(bad)


def test_apply_overrides_returns_a_new_config():
    cfg = load_config("default")
    new = apply_overrides(cfg, ["seed=3"])
    assert new.seed == 3 and cfg.seed == 0


def test_yaml_int_precision_is_accepted():
    assert config_from_dict({"training": {"precision": 32}}).training.precision == "32"


def test_check_config_against_samples():
    samples = pd.DataFrame(
        {
            "force_n_0": [np.nan],
            "force_n_1": [np.nan],
            "force_n_2": [np.nan],
            "width_m_0": [0.05],
            "width_m_1": [0.05],
            "width_m_2": [0.04],
            "elastic_estimate_pa": [1e5],
            "hertz_estimate_pa": [1e5],
        }
    )
    with pytest.raises(ConfigError, match="needs force"):
        check_config_against_samples(load_config("default"), samples)
    check_config_against_samples(load_config("default", ["inputs=Image"]), samples)
    with pytest.raises(ConfigError, match="source"):
        check_config_against_samples(load_config("yuan"), samples, source="burgess")


def test_frames_too_small_for_a_built_in_model_are_refused_from_the_config(tmp_path):
    """``check_frame_size_early``: before torch, from data.image_size or the store header
    (the run's own check stays: tests/test_training.py)."""
    from tactile_compliance.runs.config_checks import check_frame_size_early
    from toy_store import make_toy_store

    small = load_config("default", ["model.name=top10nn", "data.image_size=[48,48]"])
    with pytest.raises(ConfigError, match=r"top10nn needs frames of at least 65x65 px.*48x48"):
        check_frame_size_early(small)
    check_frame_size_early(load_config("default", ["model.name=vgg_lstm"]))  # 224 px
    check_frame_size_early(load_config("default", ["inputs=FW"]))  # frame-free
    store = make_toy_store(tmp_path / "store", n_objects=2, grasps=1, size=(32, 32))
    from_store = load_config("default", ["model.name=top10nn", f"data.store={store.path}"])
    with pytest.raises(ConfigError, match="the store's frames are 32x32"):
        check_frame_size_early(from_store)
    check_frame_size_early(
        load_config("default", ["model.name=res_tf", f"data.store={store.path}"])
    )


def test_parsed_values_are_set_before_the_overrides_which_win() -> None:
    """`train --size` carries its parsed tuple (no `--set` string); a --set of it wins."""
    from tactile_compliance.config import load_config

    assert load_config("default", values={"data.image_size": (64, 48)}).data.image_size == (64, 48)
    both = load_config("default", ["data.image_size=[32,32]"], {"data.image_size": (64, 48)})
    assert both.data.image_size == (32, 32)
