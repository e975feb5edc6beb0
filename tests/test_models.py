"""Tests of the three compliance models, the input strategies and the model registry.

Every registered model is checked under every input strategy: output shape and range,
gradients, which inputs reach the output, that disabled inputs have no parameters, and
that ``forward`` equals ``forward_features`` on the backbone's features. Models are built
once per (model, strategy) and shared, because VGG16 alone has 134 M parameters.
"""

from __future__ import annotations

import copy
import json
from collections.abc import Callable, Iterator

import pytest
import torch
from torch import nn

from tactile_compliance.models import (
    InputStrategy,
    ResTf,
    TactileModel,
    create_backbone,
    create_model,
    get_model_class,
    list_models,
    model_hyperparameters,
    register_model,
)
from tactile_compliance.models import registry as registry_module
from tactile_compliance.models.res_tf import sinusoidal_positional_encoding
from tactile_compliance.models.settings import (
    FROM_PAPER,
    SearchDimension,
    paper_settings,
    search_dimensions,
)

MODELS = [m for m in list_models() if get_model_class(m).takes_images]  # images
#: The strategies the image models take (frame-free ones go to scalar_mlp, tested below).
STRATEGIES = [s for s in InputStrategy if s.image is not None]
BATCH = 2

# Substrings that every parameter of an input's tower carries (the models' naming
# convention: force_encoder, width_encoder, estimation_decoder / estimate_encoder).
TOWER_MARKERS = {"force": "force", "width": "width", "estimates": "estimat"}


def _uses(strategy: InputStrategy, input_name: str) -> bool:
    return strategy.uses(input_name)


@pytest.fixture(autouse=True, scope="module")
def _one_thread() -> Iterator[None]:
    """Run single-threaded: the tensors here are tiny, and on shared cores several torch
    thread pools spin-waiting against each other slow small ops down by orders of magnitude."""
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


@pytest.fixture(scope="module")
def get_model() -> Iterator[Callable[[str, InputStrategy], TactileModel]]:
    """Build each (model, strategy) once with a fixed seed; tests that mutate use copies."""
    cache: dict[tuple[str, InputStrategy], TactileModel] = {}

    def build(name: str, strategy: InputStrategy) -> TactileModel:
        key = (name, strategy)
        if key not in cache:
            torch.manual_seed(0)
            cache[key] = create_model(name, strategy)
        model = cache[key]
        model.zero_grad(set_to_none=True)
        return model

    yield build
    cache.clear()  # release the VGG copies (~0.5 GB each) before other test modules run


@pytest.fixture(scope="module")
def get_features(get_model) -> Iterator[Callable[[str, InputStrategy], torch.Tensor]]:
    """Eval-mode backbone features of ``make_batch(model)``, computed once per model."""
    cache: dict[tuple[str, InputStrategy], torch.Tensor] = {}

    def features(name: str, strategy: InputStrategy) -> torch.Tensor:
        key = (name, strategy)
        if key not in cache:
            model = get_model(name, strategy).eval()
            with torch.no_grad():
                cache[key] = model.encode_frames(make_batch(model)["frames"])
        return cache[key]

    yield features
    cache.clear()


def make_batch(model: TactileModel, seed: int = 0) -> dict[str, torch.Tensor]:
    """A small random batch at the smallest frame size the model accepts (>= 32 px)."""
    generator = torch.Generator().manual_seed(seed)
    size = max(32, model.min_image_size) if model.inputs.image is not None else 32
    return {
        "frames": torch.randn(BATCH, 3, 3, size, size, generator=generator),
        "force": torch.rand(BATCH, 3, generator=generator),
        "width": torch.rand(BATCH, 3, generator=generator),
        "estimates": torch.rand(BATCH, 2, generator=generator),
    }


def perturbed(batch: dict[str, torch.Tensor], input_name: str, column: int | None = None):
    """Copy of ``batch`` with one scalar input (or one column of it) shifted by 0.5."""
    changed = dict(batch)
    tensor = batch[input_name].clone()
    if column is None:
        tensor += 0.5
    else:
        tensor[:, column] += 0.5
    changed[input_name] = tensor
    return changed


# ----------------------------------------------------------------- InputStrategy


def test_input_strategy_inputs() -> None:
    # Written out, not read from the table: the table is what is tested.
    table = {
        "Image": ("frames",),
        "ImageF": ("frames", "force"),
        "ImageFW": ("frames", "force", "width"),
        "ALL": ("frames", "force", "width", "estimates"),
        "FW": ("force", "width"),
        "FWE": ("force", "width", "estimates"),
        "DepthFW": ("depth", "force", "width"),
        "DepthALL": ("depth", "force", "width", "estimates"),
        "FWR": ("force", "width", "rig_estimates"),
    }
    assert [s.value for s in InputStrategy] == list(table)
    for name, inputs in table.items():
        strategy = InputStrategy.parse(name)
        assert strategy.input_names == inputs
        assert strategy.scalar_names == tuple(n for n in inputs if n not in ("frames", "depth"))
        assert (strategy.image is None) == (inputs[0] not in ("frames", "depth"))
        assert strategy.in_paper == (name in ("Image", "ImageF", "ImageFW", "ALL"))


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("image", InputStrategy.IMAGE),
        ("Image", InputStrategy.IMAGE),
        ("IMAGEF", InputStrategy.IMAGE_F),
        ("imagefw", InputStrategy.IMAGE_FW),
        ("image_fw", InputStrategy.IMAGE_FW),
        ("all", InputStrategy.ALL),
        (" ALL ", InputStrategy.ALL),
        (InputStrategy.IMAGE_F, InputStrategy.IMAGE_F),
    ],
)
def test_input_strategy_parse(text: str | InputStrategy, expected: InputStrategy) -> None:
    assert InputStrategy.parse(text) is expected


def test_input_strategy_parse_error_lists_names() -> None:
    with pytest.raises(ValueError, match=r"imagewf.*Image, ImageF, ImageFW, ALL"):
        InputStrategy.parse("imagewf")


# --------------------------------------------------------------- per model x strategy


@pytest.mark.parametrize("strategy", STRATEGIES, ids=str)
@pytest.mark.parametrize("name", MODELS)
def test_output_shape_and_range(get_model, name: str, strategy: InputStrategy) -> None:
    model = get_model(name, strategy)
    batch = make_batch(model)
    for training in (True, False):
        model.train(training)
        with torch.no_grad():
            out = model(**batch)
        assert out.shape == (BATCH,)
        assert torch.isfinite(out).all()
        assert ((out > 0) & (out < 1)).all(), out


@pytest.mark.parametrize("strategy", STRATEGIES, ids=str)
@pytest.mark.parametrize("name", MODELS)
def test_every_parameter_gets_a_gradient(get_model, name: str, strategy: InputStrategy) -> None:
    model = get_model(name, strategy)
    model.train()
    torch.manual_seed(1)  # dropout masks
    model(**make_batch(model)).sum().backward()
    backbone_ids = {id(p) for p in model.backbone.parameters()}
    backbone_norm = 0.0
    try:
        for param_name, param in model.named_parameters():
            if not param.requires_grad:
                continue
            assert param.grad is not None, f"{param_name} got no gradient"
            # One pass over the (up to 100 M) values: a NaN or inf anywhere makes the
            # sum of absolute values non-finite.
            magnitude = float(param.grad.abs().sum())
            assert torch.isfinite(torch.tensor(magnitude)), f"{param_name}: non-finite gradient"
            if id(param) in backbone_ids:
                backbone_norm += magnitude
            else:
                assert magnitude > 0, f"head parameter {param_name} has zero gradient"
        assert backbone_norm > 0, "no gradient reaches the backbone"
    finally:
        model.zero_grad(set_to_none=True)


@pytest.mark.parametrize("input_name", ["force", "width", "estimates"])
@pytest.mark.parametrize("strategy", STRATEGIES, ids=str)
@pytest.mark.parametrize("name", MODELS)
def test_input_reaches_output_only_when_enabled(
    get_model, get_features, name: str, strategy: InputStrategy, input_name: str
) -> None:
    model = get_model(name, strategy).eval()
    batch = make_batch(model)
    features = get_features(name, strategy)
    scalars = {k: v for k, v in batch.items() if k != "frames"}
    with torch.no_grad():
        base = model.forward_features(features, **scalars)
        # Each column separately, so e.g. the Hertz estimate cannot silently be dropped.
        columns = range(scalars[input_name].shape[1])
        for column in columns:
            changed = perturbed(scalars, input_name, column)
            out = model.forward_features(features, **changed)
            if _uses(strategy, input_name):
                assert (out - base).abs().max() > 1e-7, f"{input_name}[{column}] has no effect"
            else:
                assert torch.equal(out, base), f"disabled {input_name} changed the output"
        if not _uses(strategy, input_name):
            # Passing None for a disabled input is the same as passing a tensor.
            without = {**scalars, input_name: None}
            assert torch.equal(model.forward_features(features, **without), base)


@pytest.mark.parametrize("strategy", STRATEGIES, ids=str)
@pytest.mark.parametrize("name", MODELS)
def test_disabled_inputs_have_no_parameters(get_model, name: str, strategy: InputStrategy) -> None:
    model = get_model(name, strategy)
    names = [n for n, _ in model.named_parameters()]
    for input_name, marker in TOWER_MARKERS.items():
        has_tower = any(marker in n for n in names)
        assert has_tower == _uses(strategy, input_name), (input_name, names)


@pytest.mark.parametrize("name", MODELS)
def test_parameter_count_grows_with_inputs(get_model, name: str) -> None:
    paper = [s for s in STRATEGIES if s.in_paper]
    counts = [sum(p.numel() for p in get_model(name, s).parameters()) for s in paper]
    assert counts == sorted(counts) and len(set(counts)) == len(counts), counts


@pytest.mark.parametrize("strategy", STRATEGIES, ids=str)
@pytest.mark.parametrize("name", MODELS)
def test_forward_equals_forward_features(get_model, name: str, strategy: InputStrategy) -> None:
    model = get_model(name, strategy).eval()
    batch = make_batch(model, seed=3)
    frames = batch["frames"]
    with torch.no_grad():
        direct = model(**batch)
        # What a feature cache would store: the backbone applied frame by frame.
        per_frame = torch.stack([model.backbone(frames[:, t]) for t in range(3)], dim=1)
        assert per_frame.shape == (BATCH, 3, model.feature_dim)
        cached = model.forward_features(
            per_frame, force=batch["force"], width=batch["width"], estimates=batch["estimates"]
        )
    torch.testing.assert_close(direct, cached, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("strategy", STRATEGIES, ids=str)
@pytest.mark.parametrize("name", MODELS)
def test_enabled_input_missing_raises(get_model, name: str, strategy: InputStrategy) -> None:
    model = get_model(name, strategy).eval()
    batch = make_batch(model)
    features = torch.zeros(BATCH, 3, model.feature_dim)
    scalars = {k: v for k, v in batch.items() if k != "frames"}
    enabled = [n for n in TOWER_MARKERS if _uses(strategy, n)]
    for input_name in enabled:
        with pytest.raises(ValueError, match=rf"`{input_name}`"):
            model.forward_features(features, **{**scalars, input_name: None})
    if not enabled:
        # An Image model runs on the frames alone.
        with torch.no_grad():
            assert model(batch["frames"]).shape == (BATCH,)


@pytest.mark.parametrize("name", MODELS)
def test_bad_shapes_raise_clear_errors(get_model, name: str) -> None:
    model = get_model(name, InputStrategy.ALL).eval()
    batch = make_batch(model)
    with pytest.raises(ValueError, match="frames"):
        model(
            batch["frames"][:, 0],
            force=batch["force"],
            width=batch["width"],
            estimates=batch["estimates"],
        )
    with pytest.raises(ValueError, match="frames"):
        model(
            batch["frames"][:, :2],
            force=batch["force"],
            width=batch["width"],
            estimates=batch["estimates"],
        )
    if model.min_image_size > 1:
        too_small = torch.zeros(BATCH, 3, 3, model.min_image_size - 1, 80)
        with pytest.raises(ValueError, match="at least"):
            model(
                too_small, force=batch["force"], width=batch["width"], estimates=batch["estimates"]
            )
    with pytest.raises(ValueError, match="`force`"):
        model(
            batch["frames"],
            force=batch["force"][:, :2],
            width=batch["width"],
            estimates=batch["estimates"],
        )
    with pytest.raises(ValueError, match="features"):
        model.forward_features(torch.zeros(BATCH, 3, model.feature_dim + 1))
    # float64 scalars (straight from numpy) are accepted.
    with torch.no_grad():
        out = model(
            batch["frames"],
            force=batch["force"].double(),
            width=batch["width"].double(),
            estimates=batch["estimates"].double(),
        )
    assert out.dtype == torch.float32


@pytest.mark.parametrize("name", MODELS)
def test_force_and_width_reach_their_own_towers(get_model, get_features, name: str) -> None:
    """Regression test for the published bug (force and width swapped in the call)."""
    base_model = get_model(name, InputStrategy.IMAGE_FW)
    for silenced, live in (("force", "width"), ("width", "force")):
        model = copy.deepcopy(base_model).eval()
        tower = getattr(model, f"{silenced}_encoder")
        with torch.no_grad():
            for param in tower.parameters():
                param.zero_()
        batch = make_batch(model)
        # Only a tower changes, never the backbone, so the cached features still apply.
        features = get_features(name, InputStrategy.IMAGE_FW)
        scalars = {k: v for k, v in batch.items() if k != "frames"}
        with torch.no_grad():
            base = model.forward_features(features, **scalars)
            via_silenced = model.forward_features(features, **perturbed(scalars, silenced))
            via_live = model.forward_features(features, **perturbed(scalars, live))
        # With its own tower zeroed, an input can no longer matter; the other one still does.
        assert torch.equal(via_silenced, base), f"{silenced} bypasses {silenced}_encoder"
        assert (via_live - base).abs().max() > 1e-7, f"{live} does not reach the output"
        del model


def test_vgg_lstm_estimates_reach_their_own_embeddings(get_model, get_features) -> None:
    model = copy.deepcopy(get_model("vgg_lstm", InputStrategy.ALL)).eval()
    with torch.no_grad():
        for param in model.estimate_encoder["elastic"].parameters():
            param.zero_()
    batch = make_batch(model)
    features = get_features("vgg_lstm", InputStrategy.ALL)
    scalars = {k: v for k, v in batch.items() if k != "frames"}
    with torch.no_grad():
        base = model.forward_features(features, **scalars)
        elastic = model.forward_features(features, **perturbed(scalars, "estimates", 0))
        hertz = model.forward_features(features, **perturbed(scalars, "estimates", 1))
    assert torch.equal(elastic, base)
    assert (hertz - base).abs().max() > 1e-7


def _recorded_dropout(model: TactileModel) -> tuple[list[torch.Tensor], list[torch.Tensor], object]:
    """Record what ``model.dropout`` gets and returns at each call (its masks)."""
    inputs: list[torch.Tensor] = []
    outputs: list[torch.Tensor] = []

    def hook(module, args, output):
        inputs.append(args[0].detach().clone())
        outputs.append(output.detach().clone())

    return inputs, outputs, model.dropout.register_forward_hook(hook)


def _lstm_steps_with_masks(
    model: TactileModel,
    features: torch.Tensor,
    scalars: dict[str, torch.Tensor],
    dropped: list[torch.Tensor],
    recurrent: bool,
) -> tuple[list[torch.Tensor], torch.Tensor]:
    """The step loop of the published LRCN, written out with ``nn.LSTMCell``, reusing the
    dropped-out hidden states the model produced: (h_t before dropout per step, logits)."""
    constant = [
        model.estimate_encoder["elastic"](scalars["estimates"][:, 0:1]),
        model.estimate_encoder["hertz"](scalars["estimates"][:, 1:2]),
    ]
    hidden = torch.zeros(features.shape[0], model.lstm.hidden_size)
    cell = torch.zeros_like(hidden)
    states, outputs = [], []
    for t in range(3):
        step = torch.cat(
            [
                features[:, t],
                model.force_encoder(scalars["force"][:, t : t + 1]),
                model.width_encoder(scalars["width"][:, t : t + 1]),
                *constant,
            ],
            dim=1,
        )
        hidden, cell = model.lstm(step, (hidden, cell))
        states.append(hidden)
        outputs.append(model.output(dropped[t]))
        if recurrent:
            hidden = dropped[t]  # the published code carries the dropped-out h forward
    logits = torch.cat(outputs, dim=1) @ torch.softmax(model.step_weights, dim=0)
    return states, logits


def test_vgg_lstm_dropout_modes(get_model, get_features) -> None:
    """``recurrent`` (the default, as published) feeds the dropped-out h_t into step t + 1;
    ``output`` only drops the path to y_t. Same parameters; eval mode is unaffected."""
    recurrent = get_model("vgg_lstm", InputStrategy.ALL)
    assert recurrent.hparams["lstm_dropout_mode"] == "recurrent"
    assert recurrent.hparams["lstm_dropout"] == pytest.approx(0.2)
    output = create_model("vgg_lstm", "ALL", lstm_dropout_mode="output")
    output.load_state_dict(recurrent.state_dict(), strict=True)
    assert sum(p.numel() for p in output.parameters()) == sum(
        p.numel() for p in recurrent.parameters()
    )
    features = get_features("vgg_lstm", InputStrategy.ALL)
    scalars = {k: v for k, v in make_batch(recurrent).items() if k != "frames"}
    was_training = recurrent.training
    try:
        logits = {}
        for mode, model in (("recurrent", recurrent), ("output", output)):
            model.train()
            seen_in, seen_out, handle = _recorded_dropout(model)
            torch.manual_seed(5)
            with torch.no_grad():
                logits[mode] = model._head(features, scalars)
                states, expected = _lstm_steps_with_masks(
                    model, features, scalars, seen_out, recurrent=mode == "recurrent"
                )
            handle.remove()
            assert len(seen_out) == 3
            # The dropout really dropped something (p = 0.2 over 2 x 256 units)...
            for before, after in zip(seen_in, seen_out, strict=True):
                assert (after == 0).any() and not torch.equal(after, before)
            # ...and each step's h_t is the LSTMCell of the previous step's carried state.
            for t in range(3):
                torch.testing.assert_close(seen_in[t], states[t], rtol=1e-5, atol=1e-6)
            torch.testing.assert_close(logits[mode], expected, rtol=1e-5, atol=1e-6)
        # Same seed, same masks: step 1 is identical, what follows is not.
        assert not torch.allclose(logits["recurrent"], logits["output"])
        recurrent.eval()
        output.eval()
        with torch.no_grad():
            assert torch.equal(recurrent._head(features, scalars), output._head(features, scalars))
    finally:
        recurrent.train(was_training)
        del output
    with pytest.raises(ValueError, match=r"lstm_dropout_mode.*recurrent, output"):
        create_model("vgg_lstm", "ALL", lstm_dropout_mode="hidden")


@pytest.mark.parametrize("name", MODELS)
def test_hparams_rebuild_the_same_model(get_model, name: str) -> None:
    model = get_model(name, InputStrategy.ALL).eval()
    # What a checkpoint stores must survive JSON and rebuild an identical architecture.
    restored_hparams = json.loads(json.dumps(model.hparams))
    assert set(restored_hparams) <= set(model_hyperparameters(name))
    rebuilt = create_model(model.model_name, model.inputs.value, **restored_hparams).eval()
    rebuilt.load_state_dict(model.state_dict(), strict=True)
    assert rebuilt.hparams == model.hparams
    batch = make_batch(model)
    with torch.no_grad():
        torch.testing.assert_close(rebuilt(**batch), model(**batch), rtol=0, atol=0)
    assert model.backbone_weights == "none"


def test_model_metadata(get_model) -> None:
    expected_dims = {"top10nn": 128, "vgg_lstm": 4096, "res_tf": 512}
    for name in MODELS:
        model = get_model(name, InputStrategy.IMAGE)
        assert model.model_name == name
        assert model.inputs is InputStrategy.IMAGE
        assert model.feature_dim == expected_dims[name]
        assert model.feature_dim == model.backbone.feature_dim
        assert set(model.default_training) == {"lr", "batch_size", "gamma"}
        assert model.recommended_image_size == ((224, 224) if name == "vgg_lstm" else None)
        assert ("backbone_weights" in model_hyperparameters(name)) == model.pretrained_backbone


def test_the_torch_free_names_and_frame_rules_are_the_built_models(get_model) -> None:
    """``known_model_names`` and ``models.frame_rules`` answer before torch loads (a typo
    or too small frames in one line); they must be what the built models say."""
    from tactile_compliance.models import known_model_names, list_models
    from tactile_compliance.models.frame_rules import RECOMMENDED_FRAME_SIZE, min_frame_side

    # The torch-free scan of the sources finds exactly what the registry's discovery does.
    assert known_model_names() == sorted(list_models())
    assert set(known_model_names()) >= set(MODELS) and "scalar_mlp" in known_model_names()
    for name in MODELS:
        model = get_model(name, InputStrategy.IMAGE)
        assert min_frame_side(name) == model.min_image_size, name
        assert RECOMMENDED_FRAME_SIZE.get(name) == model.recommended_image_size, name
    assert min_frame_side("scalar_mlp") is None and min_frame_side("top10nn") == 65


# ------------------------------------------------------------------ model specifics


def test_top10nn_needs_65_pixels(get_model) -> None:
    model = get_model("top10nn", InputStrategy.IMAGE).eval()
    assert model.min_image_size == 65
    with torch.no_grad():
        assert model(torch.zeros(1, 3, 3, 65, 65)).shape == (1,)
    with pytest.raises(ValueError, match="65x65"):
        model(torch.zeros(1, 3, 3, 64, 64))


def test_res_tf_options() -> None:
    with pytest.raises(ValueError, match="divisible"):
        ResTf("Image", embedding_dim=30, num_heads=4)
    with pytest.raises(ValueError, match="backbone"):
        ResTf("Image", backbone="vgg16")
    with pytest.raises(ValueError, match="decoder_sizes"):
        ResTf("Image", decoder_sizes=[0])
    torch.manual_seed(0)
    tuned_image = ResTf("Image", **ResTf.tuned_configs["Image"]["model"])
    assert len(tuned_image.transformer.layers) == 5
    assert tuned_image.image_output.out_features == 1024
    big = ResTf("Image", backbone="resnet50", num_layers=1)
    assert big.feature_dim == 2048
    with torch.no_grad():
        assert big.eval()(torch.randn(1, 3, 3, 32, 32)).shape == (1,)


def test_sinusoidal_positional_encoding() -> None:
    encoding = sinusoidal_positional_encoding(3, 6)
    assert encoding.shape == (3, 6)
    torch.testing.assert_close(encoding[0], torch.tensor([0.0, 1.0, 0.0, 1.0, 0.0, 1.0]))
    assert encoding[1, 0] == pytest.approx(torch.sin(torch.tensor(1.0)).item())
    assert encoding[1, 1] == pytest.approx(torch.cos(torch.tensor(1.0)).item())
    assert encoding[2, 2] == pytest.approx(torch.sin(torch.tensor(2.0 / 10000 ** (2 / 6))).item())
    assert sinusoidal_positional_encoding(3, 5).shape == (3, 5)


# ----------------------------------------------------------------------- registry


def test_list_models() -> None:
    assert list_models() == ["res_tf", "scalar_mlp", "top10nn", "vgg_lstm"]


def test_create_model_unknown_name_lists_models() -> None:
    names = r"res_tf, scalar_mlp, top10nn, vgg_lstm"
    with pytest.raises(ValueError, match=rf"unknown model 'resnet'.*{names}"):
        create_model("resnet")


def test_create_model_unknown_hyperparameter_is_named() -> None:
    with pytest.raises(ValueError, match=r"hidden_sise.*top10nn"):
        create_model("top10nn", "Image", hidden_sise=3)


def test_create_model_bad_inputs() -> None:
    with pytest.raises(ValueError, match="input strategy"):
        create_model("top10nn", "pictures")


def test_create_model_passes_hyperparameters() -> None:
    model = create_model("TOP10NN", "imagef", img_feature_size=64, fwe_size=8)
    assert model.inputs is InputStrategy.IMAGE_F
    assert model.feature_dim == 64
    assert model.force_encoder.out_features == 8
    assert model.hparams["img_feature_size"] == 64


def test_register_a_new_model() -> None:
    class TinyModel(TactileModel):
        def __init__(self, inputs: InputStrategy | str = "ALL", channels: int = 4) -> None:
            super().__init__(inputs, {"channels": channels})
            self.backbone = create_backbone("resnet18")
            self.out = nn.Linear(3 * self.backbone.feature_dim, 1)

        def _head(self, features, scalars):
            return self.out(features.flatten(1)).squeeze(1)

    try:
        register_model("tiny_test_model")(TinyModel)
        assert "tiny_test_model" in list_models()
        assert get_model_class("tiny_test_model") is TinyModel
        model = create_model("tiny_test_model", "Image", channels=2)
        assert model.model_name == "tiny_test_model" and model.hparams == {"channels": 2}
        with pytest.raises(ValueError, match="already registered"):
            register_model("tiny_test_model")(type("Other", (TinyModel,), {}))
        with pytest.raises(ValueError, match="colour"):
            create_model("tiny_test_model", colour=1)
    finally:
        registry_module._REGISTRY.pop("tiny_test_model", None)
    assert "tiny_test_model" not in list_models()


# ------------------------------------------------------------- paper settings, spaces


@pytest.mark.parametrize("name", MODELS)
def test_hparam_checks_cover_the_constructor(name: str) -> None:
    # ``hparams`` is built from ``hparam_checks``: a constructor argument missing there
    # would silently not reach a checkpoint.
    cls = get_model_class(name)
    assert set(cls.hparam_checks) == set(model_hyperparameters(name)) - {"backbone_weights"}


def test_paper_settings_come_from_the_model_classes() -> None:
    assert paper_settings("vgg_lstm", "ALL") == {
        "training.lr": 3e-4,
        "training.batch_size": 16,
        "training.gamma": 0.97974,
    }
    assert paper_settings("top10nn", "imagef") == {
        "training.lr": 3e-6,
        "training.batch_size": 32,
        "training.gamma": None,
    }
    # Res-Tf: its constructor defaults are the tuned ALL model, so ALL only sets training;
    # the tuned Image configuration adds its hyperparameters.
    assert paper_settings("res_tf", InputStrategy.ALL) == {
        "training.lr": 1.1e-4,
        "training.batch_size": 24,
        "training.gamma": 0.977,
    }
    image = paper_settings("res_tf", "Image")
    assert image["training.lr"] == 8e-5 and image["training.batch_size"] == 40
    assert image["model.hparams.num_layers"] == 5 and image["model.hparams.decoder_sizes"] == [256]
    with pytest.raises(ValueError, match="unknown model"):
        paper_settings("resnet", "ALL")


def test_search_dimensions_follow_the_inputs_and_the_paper() -> None:
    keys = {d.key for d in search_dimensions("vgg_lstm", "ImageF")}
    assert "model.hparams.force_dim" in keys and "model.hparams.width_dim" not in keys
    assert "model.hparams.elastic_dim" not in keys
    top = {d.key: d for d in search_dimensions("top10nn", "ImageFW")}
    assert "model.hparams.fwe_size" in top and "model.hparams.estimation_sizes" not in top
    assert all(d.default is not FROM_PAPER for d in top.values())
    res = {d.key: d.default for d in search_dimensions("res_tf", "ALL")}
    # Off-grid paper values start from the nearest choice (lr 1.1e-4, batch 24, [512]).
    assert res["training.lr"] == 1e-4 and res["training.batch_size"] == 32
    assert res["training.gamma"] == 0.975 and res["model.hparams.decoder_sizes"] == (512, 512, 256)
    assert res["model.hparams.estimation_dropout"] == 0.1  # Res-Tf's own default, not Top10NN's


def test_search_dimension_validation() -> None:
    dim = SearchDimension.hparam("fwe_size", (8, 16, 32), needs=("force", "width"))
    assert dim.key == "model.hparams.fwe_size"
    assert not dim.applies_to("Image") and dim.applies_to("ImageF")
    assert dim.nearest(30) == 32 and dim.nearest(16) == 16 and dim.nearest("x") == 8
    with pytest.raises(ValueError, match="no choices"):
        SearchDimension("training.lr", ())
    with pytest.raises(ValueError, match="needs"):
        SearchDimension("training.lr", (1e-3,), needs=("torque",))
    with pytest.raises(ValueError, match="no choice"):
        SearchDimension("training.lr", (1e-3,), default=0.5)

    class Broken(TactileModel):
        hpo_space = (SearchDimension.hparam("colour", (1, 2)),)

        def __init__(self, inputs: InputStrategy | str = "ALL", channels: int = 4) -> None:
            super().__init__(inputs, {"channels": channels})

    try:
        register_model("broken_space_model")(Broken)
        with pytest.raises(ValueError, match=r"colour.*not a constructor hyperparameter"):
            search_dimensions("broken_space_model", "ALL")
    finally:
        registry_module._REGISTRY.pop("broken_space_model", None)


# ------------------------------------------------------------------ frame-free model


@pytest.mark.parametrize("strategy", [InputStrategy.FW, InputStrategy.FWE], ids=str)
def test_scalar_mlp_reads_its_scalars_and_nothing_else(strategy: InputStrategy) -> None:
    torch.manual_seed(0)
    model = create_model("scalar_mlp", strategy).eval()
    batch = {k: v for k, v in make_batch(model).items() if k != "frames"}
    with torch.no_grad():
        out = model(**batch)
        assert out.shape == (BATCH,) and ((out > 0) & (out < 1)).all()
        for name in ("force", "width", "estimates"):
            changed = model(**perturbed(batch, name))
            # Each input it takes moves the output; the one it does not take is ignored.
            assert torch.equal(changed, out) != strategy.uses(name), name
    with pytest.raises(ValueError, match="needs `width`"):
        model(force=batch["force"])


@pytest.mark.parametrize(
    ("model", "inputs", "message"),
    [
        ("top10nn", "FW", "reads frames or depth maps, but inputs=FW has none"),
        ("res_tf", "FWE", "inputs=FWE has none"),
        ("scalar_mlp", "ALL", "takes no images, but inputs=ALL includes frames"),
        ("scalar_mlp", "DepthFW", "includes depth"),
    ],
)
def test_a_model_refuses_a_strategy_it_cannot_take(model: str, inputs: str, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        create_model(model, inputs)


@pytest.mark.parametrize("name", ["top10nn", "res_tf"])
def test_a_depth_strategy_has_the_same_architecture_as_its_frame_strategy(name: str) -> None:
    # Depth maps enter the backbone as three equal channels: same weights, other images.
    frames = create_model(name, "ALL")
    depth = create_model(name, "DepthALL")
    shapes = {k: tuple(v.shape) for k, v in frames.state_dict().items()}
    assert shapes == {k: tuple(v.shape) for k, v in depth.state_dict().items()}
