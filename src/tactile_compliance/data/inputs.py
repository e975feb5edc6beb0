"""The one table of model inputs (:data:`INPUTS`) and the input strategies built from it.

Every consumer (the dataset, the forward path, the inference checks, the ONNX input
names, the config's column check, the scalar reference, the export metadata) iterates
over a strategy's entries of this table instead of keeping its own list. Torch-free: the
command line reads it to check a configuration before torch loads. Adding an input:
docs/models.md, "Adding an input".
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum
from typing import Any, Literal

from tactile_compliance.data.normalisation import (
    NormalisationConstants,
    normalise_depth,
    normalise_estimates,
    normalise_force,
    normalise_width,
)
from tactile_compliance.data.plausibility import (
    DEPTH,
    ESTIMATE,
    FORCE,
    FRAME,
    WIDTH,
    PlausibleRange,
)
from tactile_compliance.data.store import (
    ESTIMATE_COLUMNS,
    FORCE_COLUMNS,
    RIG_ESTIMATE_COLUMNS,
    WIDTH_COLUMNS,
)
from tactile_compliance.suggest import did_you_mean

__all__ = [
    "ANALYTICAL_INPUTS",
    "INPUTS",
    "MIN_FRAME_SIDE_PX",
    "NUM_FRAMES",
    "PAPER_STRATEGIES",
    "InputSpec",
    "InputStrategy",
    "scalar_inputs",
]

#: Frames per sample (start, middle, end of the grasp): the images and the per-frame
#: scalars (force, width) have this many entries per grasp.
NUM_FRAMES = 3

#: Image inputs must be at least this many pixels high and wide, even when they are
#: resized: a smaller tactile frame holds no contact geometry (a thumbnail, a single
#: pixel), and upscaling it would only hide the mistake. Models may need more
#: (``TactileModel.min_image_size``).
MIN_FRAME_SIDE_PX = 8

InputKind = Literal["image", "scalar"]


@dataclass(frozen=True)
class InputSpec:
    """One model input: what it is, its shape per grasp, unit, store source, plausibility
    rule and normalisation.

    Attributes:
        name: the keyword everywhere (batch key, ``predict`` argument, ONNX input name).
        kind: ``"image"`` (one per strategy, through the model's backbone) or ``"scalar"``
            (a few numbers per grasp, through the head).
        meaning: what it is, for error messages and the model card.
        shape: its shape for one grasp, as text (``"(3, H, W, 3)"``, ``"(3,)"``).
        rule: plausible physical values (``data.plausibility``); its unit is the input's.
        hint: the advice an error about this input ends with.
        normalise: physical values -> what the model sees, ``(values, constants)``.
        columns: the store columns of a scalar input, in order (its ``size`` values);
            images come from the store's arrays, not columns.
        decades: the values span decades (moduli in Pa): the scalar reference compares
            their log10, clamped like the normalisation clamps them.
    """

    name: str
    kind: InputKind
    meaning: str
    shape: str
    rule: PlausibleRange
    hint: str
    normalise: Callable[[Any, NormalisationConstants], Any] | None = None
    columns: tuple[str, ...] = ()
    decades: bool = False

    @property
    def unit(self) -> str:
        """The physical unit the caller gives this input in (the rule's)."""
        return self.rule.unit

    @property
    def size(self) -> int:
        """Values per grasp of a scalar input (its number of store columns)."""
        return len(self.columns)

    def describe(self) -> str:
        """E.g. ```force` (normal force at the three frames, N, shape (3,))``."""
        return f"`{self.name}` ({self.meaning}, {self.unit}, shape {self.shape})"


#: Every input a model can take, in the order models and ONNX graphs list them: the
#: image inputs first, then the scalars.
INPUTS: dict[str, InputSpec] = {
    spec.name: spec
    for spec in (
        InputSpec(
            name="frames",
            kind="image",
            meaning="three difference images (start, middle, end of the press), RGB",
            shape=f"({NUM_FRAMES}, H, W, 3)",
            rule=FRAME,
            hint="pass uint8 (0..255) or float difference images in [0, 1]; the estimator "
            "normalises them itself",
        ),
        InputSpec(
            name="depth",
            kind="image",
            meaning="gel depth maps of the three frames (indentation, positive into the gel)",
            shape=f"({NUM_FRAMES}, h, w)",
            rule=DEPTH,
            hint="pass millimetres, as `tactile-compliance depth` or the store's depth maps "
            "give them",
            normalise=normalise_depth,
        ),
        InputSpec(
            name="force",
            kind="scalar",
            meaning="normal force at the three frames",
            shape=f"({NUM_FRAMES},)",
            rule=FORCE,
            hint="pass the raw reading in newtons (the model divides by 60 N itself)",
            normalise=normalise_force,
            columns=FORCE_COLUMNS,
        ),
        InputSpec(
            name="width",
            kind="scalar",
            meaning="gripper width at the three frames",
            shape=f"({NUM_FRAMES},)",
            rule=WIDTH,
            hint="pass metres, not millimetres (the gripper opens to 0.08 m)",
            normalise=normalise_width,
            columns=WIDTH_COLUMNS,
        ),
        InputSpec(
            name="estimates",
            kind="scalar",
            meaning="analytical estimates (elastic E, Hertz E*)",
            shape="(2,)",
            rule=ESTIMATE,
            hint="values are clamped to [1e2, 1e14] Pa like in training; NaN means "
            "'missing' and cannot be used by a model that takes the estimates",
            normalise=normalise_estimates,
            columns=ESTIMATE_COLUMNS,
            decades=True,
        ),
        InputSpec(
            name="rig_estimates",
            kind="scalar",
            meaning="rig-corrected analytical estimates (elastic E, Hertz E*): the rig's "
            "own closure F / k_rig taken out of the widths",
            shape="(2,)",
            rule=ESTIMATE,
            hint="`record --rig RIG.json` and the generator make them, at the stiffness the "
            "checkpoint names; NaN means 'missing' and cannot be used by a model that takes "
            "them",
            normalise=normalise_estimates,
            columns=RIG_ESTIMATE_COLUMNS,
            decades=True,
        ),
    )
}


#: The inputs the analytical estimators make from a grasp's depth maps, forces and widths
#: (``physics.estimators``): ``live`` and the stream compute them on the fly.
ANALYTICAL_INPUTS = frozenset({"estimates", "rig_estimates"})


def scalar_inputs() -> tuple[InputSpec, ...]:
    """The table's scalar inputs, in table order."""
    return tuple(spec for spec in INPUTS.values() if spec.kind == "scalar")


class InputStrategy(str, Enum):
    """Which inputs a model takes: a set of :data:`INPUTS` entries. The values are the
    names reports and configuration files use (the paper's for its four strategies)."""

    IMAGE = "Image"
    IMAGE_F = "ImageF"
    IMAGE_FW = "ImageFW"
    ALL = "ALL"
    FW = "FW"
    FWE = "FWE"
    DEPTH_FW = "DepthFW"
    DEPTH_ALL = "DepthALL"
    FWR = "FWR"

    @property
    def input_names(self) -> tuple[str, ...]:
        """The names of its inputs, in table order (image first)."""
        return _STRATEGY_INPUTS[self]

    @property
    def inputs(self) -> tuple[InputSpec, ...]:
        """Its entries of :data:`INPUTS`, image first."""
        return tuple(INPUTS[name] for name in self.input_names)

    @property
    def image(self) -> InputSpec | None:
        """Its image input (frames or depth maps), None for a frame-free strategy."""
        return next((spec for spec in self.inputs if spec.kind == "image"), None)

    @property
    def scalars(self) -> tuple[InputSpec, ...]:
        """Its scalar inputs, in table order."""
        return tuple(spec for spec in self.inputs if spec.kind == "scalar")

    @property
    def scalar_names(self) -> tuple[str, ...]:
        """The names of its scalar inputs, e.g. ``("force", "width")``."""
        return tuple(spec.name for spec in self.scalars)

    def uses(self, name: str) -> bool:
        """Whether input ``name`` (an :data:`INPUTS` key) is one of its inputs."""
        return name in self.input_names

    @property
    def in_paper(self) -> bool:
        """Whether the paper has this strategy (the others are marked beyond the paper)."""
        return self in PAPER_STRATEGIES

    @classmethod
    def names(cls) -> tuple[str, ...]:
        """Every strategy's name: the paper's four in its table order, then ours."""
        return tuple(member.value for member in cls)

    @classmethod
    def parse(cls, value: InputStrategy | str) -> InputStrategy:
        """A member, its value or its member name, in any case and with ``_``/``-`` ignored
        ("image_fw", "depth-fw"): the names arrive from the command line and YAML files,
        where the capitalisation is easy to miss. ValueError lists the valid names."""
        if isinstance(value, cls):
            return value
        if not isinstance(value, str):
            raise ValueError(
                f"input strategy must be a string, got {type(value).__name__}: {value!r}; "
                f"valid names: {', '.join(cls.names())}"
            )
        key = value.strip().replace("_", "").replace("-", "").lower()
        for member in cls:
            if key in (member.value.lower(), member.name.replace("_", "").lower()):
                return member
        raise ValueError(
            f"unknown input strategy {value!r}{did_you_mean(value, cls.names())}; valid names "
            f"(case-insensitive): {', '.join(cls.names())}"
        )

    def __str__(self) -> str:
        # The table's spelling, so f-strings and reports show "ImageFW", not the enum repr.
        return self.value


_STRATEGY_INPUTS: dict[InputStrategy, tuple[str, ...]] = {
    InputStrategy.IMAGE: ("frames",),
    InputStrategy.IMAGE_F: ("frames", "force"),
    InputStrategy.IMAGE_FW: ("frames", "force", "width"),
    InputStrategy.ALL: ("frames", "force", "width", "estimates"),
    InputStrategy.FW: ("force", "width"),
    InputStrategy.FWE: ("force", "width", "estimates"),
    InputStrategy.DEPTH_FW: ("depth", "force", "width"),
    InputStrategy.DEPTH_ALL: ("depth", "force", "width", "estimates"),
    InputStrategy.FWR: ("force", "width", "rig_estimates"),
}

#: The paper's four strategies (Table I's rows), in its order.
PAPER_STRATEGIES: tuple[InputStrategy, ...] = (
    InputStrategy.IMAGE,
    InputStrategy.IMAGE_F,
    InputStrategy.IMAGE_FW,
    InputStrategy.ALL,
)


def _check_table() -> None:
    # Import-time guard for whoever edits the table: a strategy names known inputs, in
    # table order, with at most one image.
    order = list(INPUTS)
    for strategy, names in _STRATEGY_INPUTS.items():
        unknown = [n for n in names if n not in INPUTS]
        images = [n for n in names if n in INPUTS and INPUTS[n].kind == "image"]
        if unknown or len(images) > 1 or list(names) != sorted(names, key=order.index):
            raise RuntimeError(f"input strategy {strategy.value}: bad inputs {names}")
    missing = set(InputStrategy) - set(_STRATEGY_INPUTS)
    if missing:
        raise RuntimeError(f"strategies without inputs: {sorted(m.value for m in missing)}")
    for spec in INPUTS.values():
        if spec.kind == "scalar" and (not spec.columns or spec.normalise is None):
            raise RuntimeError(f"scalar input {spec.name} needs store columns and a normaliser")


_check_table()
