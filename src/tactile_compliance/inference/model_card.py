"""The model card (``README.md``) of an exported safetensors directory: what the model
takes, what it was trained on, how it scored, written from its ``config.json``
(docs/inference.md, "Deployable weights (safetensors)")."""

from __future__ import annotations

import json
import math
import re
from typing import Any

from tactile_compliance.data.normalisation import NormalisationConstants
from tactile_compliance.models import InputStrategy

__all__ = ["DEFAULT_LICENSE", "check_license", "model_card"]

#: The model card's licence when none is given: the weights follow the licence of the data
#: they were trained on, which the exporter cannot know (Hugging Face's "other").
DEFAULT_LICENSE = "other"


#: A licence as the model card's front matter takes it: an SPDX identifier (``mit``,
#: ``cc-by-4.0``, ``apache-2.0``), ``LicenseRef-...`` or ``other``; one YAML scalar, so no
#: line break, markup or quote can reach the card.
_LICENSE = re.compile(r"[A-Za-z0-9][A-Za-z0-9.+-]{0,63}")


def check_license(license: Any) -> str:
    """``license`` if it is an SPDX-style identifier (:data:`_LICENSE`), else ValueError."""
    if not isinstance(license, str) or not _LICENSE.fullmatch(license):
        raise ValueError(
            f"--license {license!r} is not a licence identifier: give an SPDX id such as mit, "
            f"apache-2.0 or cc-by-4.0 (letters, digits and . + -), or other"
        )
    return license


# Store sources that are recordings of real sensors (the importers' names).
_REAL_SOURCES = {"burgess": "real (Burgess et al. dataset layout)", "yuan": "real (Yuan videos)"}


def _number(value: Any) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "n/a"
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def _training_data(config: dict[str, Any]) -> list[str]:
    store = config.get("training_store")
    data = (config.get("training_config") or {}).get("data") or {}
    if not store:
        where = data.get("store") or "unknown"
        return [
            f"- Store: `{where}`; the checkpoint predates store provenance records, so "
            f"whether it was synthetic or real is not recorded.",
        ]
    source = str(store.get("source"))
    if source == "synthetic":
        kind = "synthetic (the package's GelSight simulator, `tactile-compliance simulate`)"
    else:
        kind = _REAL_SOURCES.get(source, f"source `{source}` (not a known real-data importer)")
    params = store.get("creation_parameters") or {}
    lines = [
        f"- Data: **{kind}**.",
        f"- Store: `{store.get('path')}`, {store.get('num_samples')} samples at "
        f"{'x'.join(map(str, store.get('image_size') or []))} px (H x W), channel order "
        f"{store.get('channel_order')}, created {store.get('created')} by tactile-compliance "
        f"{store.get('package_version')}.",
    ]
    if params:
        text = json.dumps(params, sort_keys=True)
        lines.append(f"- Creation parameters: `{text[:600]}{'...' if len(text) > 600 else ''}`")
    fingers = data.get("fingers")
    if fingers:
        lines.append(f"- Fingers used: {', '.join(fingers)}.")
    return lines


def _split_protocol(config: dict[str, Any]) -> str:
    cfg = config.get("training_config") or {}
    split, sampling = cfg.get("split") or {}, cfg.get("sampling") or {}
    if not split:
        return "not recorded"
    return (
        f"condition **{split.get('condition')}** (objects in the test set "
        f"{'also' if split.get('condition') == 'seen' else 'never'} seen in training), "
        f"grouping {split.get('grouping')}, test fraction {split.get('test_fraction')}, "
        f"validation fraction {split.get('val_fraction')}, split seed "
        f"{split.get('seed') if split.get('seed') is not None else 'the run seed'}; "
        f"training sampling {sampling.get('strategy')}; run seed {cfg.get('seed')}"
    )


def _metrics_section(config: dict[str, Any]) -> list[str]:
    evaluation = config.get("evaluation")
    checkpoint = config.get("checkpoint") or {}
    lines = [f"Split protocol: {_split_protocol(config)}.", ""]
    if not evaluation:
        best = (checkpoint.get("metrics") or {}).get("best_val_nmse")
        return [
            *lines,
            f"No `metrics.json` was found next to the checkpoint, so there are no test "
            f"metrics here; the checkpoint records the best validation N-MSE "
            f"{_number(best)}.",
        ]
    names = ["log10_accuracy", "nmse", "r2", "mae_decades", "within_half_decade"]
    rows = [("model, test split", evaluation.get("test") or {})]
    rows.append(("model, validation split", evaluation.get("val") or {}))
    for name, values in (evaluation.get("reference") or {}).items():
        rows.append((f"reference `{name}`, test split", values))
    lines += [
        f"Samples: {evaluation.get('n_train')} train, {evaluation.get('n_val')} validation, "
        f"{evaluation.get('n_test')} test; best epoch {evaluation.get('best_epoch')} of "
        f"{evaluation.get('epochs_trained')} (the best-validation checkpoint is exported).",
        "",
        "| predictor | n | " + " | ".join(names) + " |",
        "|---|---|" + "---|" * len(names),
    ]
    for label, values in rows:
        cells = " | ".join(_number(values.get(n)) for n in names)
        lines.append(f"| {label} | {_number(values.get('n'))} | {cells} |")
    lines += [
        "",
        "`log10_accuracy`: share within one decade of the true modulus; `nmse`: mean "
        "squared error of the normalised log label; `r2`: on the normalised label; "
        "`mae_decades`: mean |log10 E_pred - log10 E|; `within_half_decade`: share within "
        "0.5 decade (definitions: `tactile_compliance.runs.metrics`). The references are "
        "the training median, the sample's own analytical estimate and gradient-boosted "
        "trees on the scalar inputs.",
    ]
    return lines


def _inputs_line(strategy: InputStrategy, scalars: list[str]) -> str:
    """What the model reads, in words: its image input and its scalars."""
    image = strategy.image
    what = (
        "no images"
        if image is None
        else {"frames": "three tactile frames"}.get(
            image.name, f"the {image.name} maps of three tactile frames"
        )
    )
    return what + (f" plus {', '.join(scalars)} at the same three frames." if scalars else " only.")


def _image_lines(strategy: InputStrategy, config: dict[str, Any]) -> list[str]:
    """The card's lines on the image input's size and encoding (none: frame-free)."""
    run_inputs = config["run_inputs"]
    image = strategy.image
    if image is None:
        return []
    height, width = run_inputs["image_size"]
    if image.name == "depth":
        return [f"- Depth maps: in mm, resized to **{height} x {width} px** (H x W)."]
    return [
        f"- Frames: {config.get('frame_kind')}; resized to **{height} x {width} px** (H x W); "
        f'channel order **{run_inputs["channel_order"]}** (pass `channel_order="BGR"` for '
        "OpenCV frames)."
    ]


def _analytical_lines(run_inputs: dict[str, Any]) -> list[str]:
    """What the card says of the rig-corrected estimates and missing estimates."""
    lines = []
    if run_inputs.get("rig_stiffness_n_per_m") is not None:
        lines.append(
            "- Rig-corrected estimates (`rig_estimates`): made with the rig's own closure "
            f"taken out at {run_inputs['rig_stiffness_n_per_m']:.4g} N/m (`record --rig`)."
        )
    if run_inputs.get("missing_estimates"):
        lines.append(
            "- Trained with estimate dropout: NaN analytical estimates are taken as missing "
            "(a grasp whose fits failed still gets an estimate)."
        )
    return lines


def model_card(
    config: dict[str, Any], *, files: tuple[str, str], parameters: int | None = None
) -> str:
    """The ``README.md`` of an exported model, generated from its ``config.json``.

    Args:
        config: the directory's ``config.json`` as ``pretrained_config`` makes it.
        files: the names of its weights file and its ``config.json``, which the card lists.
        parameters: the number of weights, shown when given.

    Raises:
        ValueError: the config's licence is not an SPDX-style identifier
            (:func:`check_license`), so nothing but one YAML scalar reaches the front matter.
    """
    weights_file, config_file = files
    run_inputs = config["run_inputs"]
    norm = run_inputs["normalisation"]
    strategy = InputStrategy.parse(run_inputs["inputs"])
    scalars = [f"{spec.name} ({spec.unit})" for spec in strategy.scalars]
    lo, hi = NormalisationConstants.from_dict(norm).label_range_pa
    frozen = config.get("frozen_backbone")
    weights = config.get("backbone_weights", "none")
    checkpoint = config.get("checkpoint") or {}
    source = (config.get("training_store") or {}).get("source")
    if source in _REAL_SOURCES:
        validity = "a different sensor, gel or gripper needs its own validation."
    elif source == "synthetic":
        validity = (
            "the model was trained on synthetic data and has not been validated on a real sensor."
        )
    else:
        validity = (
            f"the training data's origin ({source or 'not recorded'}) is neither a known real "
            "dataset nor the simulator: treat the model as not validated on a real sensor."
        )
    hparams = json.dumps(config.get("hparams") or {}, sort_keys=True)
    backbone = (
        "randomly initialised (no ImageNet weights were used)"
        if weights == "none"
        else f"initialised from `{weights}`"
    )
    if frozen:
        backbone += f"; frozen during training (sha256 {str(frozen.get('sha256'))[:16]}...)"
    lines = [
        "---",
        "library_name: tactile-compliance",
        f"license: {check_license(config.get('license') or DEFAULT_LICENSE)}",
        "tags:",
        "- tactile-sensing",
        "- gelsight",
        "- youngs-modulus",
        "---",
        "",
        f"# {config['model_name']} ({strategy.value}): Young's modulus from one GelSight grasp",
        "",
        "Generated by `tactile-compliance export CHECKPOINT --safetensors DIR` (tactile-"
        f"compliance {config.get('package_version')}) from checkpoint "
        f"`{checkpoint.get('file')}` (sha256 `{checkpoint.get('sha256')}`, trained with "
        f"tactile-compliance {checkpoint.get('package_version')}, seed "
        f"{checkpoint.get('seed')}).",
        "",
        "## Model",
        "",
        f"- Architecture: `{config['model_name']}` with hyperparameters `{hparams}`"
        + (f", {parameters:,} parameters." if parameters is not None else "."),
        f"- Backbone: {backbone}. `model.safetensors` holds the whole state dict, backbone "
        "included.",
        f"- Output: log10 of Young's modulus E, trained on labels in [{lo:.3g}, {hi:.3g}] Pa.",
        "",
        "## Inputs",
        "",
        f"- Input strategy: **{strategy.value}**: " + _inputs_line(strategy, scalars),
        *_image_lines(strategy, config),
        "- The three frames: first frame with F >= 5 N, first frame with F >= 0.975 F_max, and "
        "the frame midway between them (in time when timestamps are given).",
        f"- Image statistics (per channel {run_inputs['channel_order']}, on [0, 1] "
        f"difference images): mean {norm['image_mean']}, std {norm['image_std']}.",
        f"- Scalar normalisation: force / {norm['force_scale_n']} N, width / "
        f"{norm['width_scale_m']} m; analytical estimates clamped to "
        f"{norm['estimate_clamp_pa']} Pa, log10, minus {norm['estimate_log10_min']}, divided "
        f"by {norm['estimate_log10_span']}; label log10 E in [{norm['label_log10_min']}, "
        f"{norm['label_log10_max']}].",
        f"- Analytical estimator (for estimates computed at inference from depth maps): "
        f"`{run_inputs['analytical_estimator']}`.",
        *_analytical_lines(run_inputs),
        "",
        "## Training data",
        "",
        *_training_data(config),
        "",
        "## Evaluation",
        "",
        *_metrics_section(config),
        "",
        "## Intended use and limits",
        "",
        "- Research use: estimating the Young's modulus of an object squeezed once by a "
        "parallel gripper with a GelSight-type sensor, with the frames selected by the "
        "force rule above and the frame size, channel order and normalisation above.",
        f"- Predictions are bounded to the training label range [{lo:.3g}, {hi:.3g}] Pa; "
        "objects outside it are predicted at the edge.",
        "- The metrics hold for the split protocol above on this training store; " + validity,
        "- Not for safety-critical decisions.",
        "",
        "## Loading",
        "",
        "```python",
        "from tactile_compliance.inference import ComplianceEstimator",
        "",
        'estimator = ComplianceEstimator.from_pretrained("DIR")',
        "result = estimator.predict("
        + ", ".join(f"{spec.name}={spec.name.upper()}" for spec in strategy.inputs)
        + ")",
        "```",
        "",
        f"Files: `{weights_file}` (sha256 `{config.get('weights_sha256')}`), `{config_file}` "
        "(everything above, machine-readable), this card.",
        "",
    ]
    return "\n".join(lines)
