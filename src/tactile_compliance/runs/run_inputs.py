"""The run's input contract: one record, resolved once (:meth:`RunInputs.resolve`) when
a run's data is prepared, stored in ``best.pt`` and read, never worked out again, by
evaluation, the estimators, ``export``, ``predict``, streaming and ``live``."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from tactile_compliance.data.inputs import ANALYTICAL_INPUTS, InputStrategy
from tactile_compliance.data.normalisation import NormalisationConstants
from tactile_compliance.data.plausibility import check_size
from tactile_compliance.physics.estimators import (
    DEFAULT_ESTIMATOR,
    WEDGE_UNITS,
    AnalyticalEstimator,
    SensorUnits,
)

if TYPE_CHECKING:
    from tactile_compliance.config import ExperimentConfig
    from tactile_compliance.data.store import GraspStore

#: Of stored frames and of what every model sees (``predict`` flips BGR input).
CHANNEL_ORDER = "RGB"


@dataclass(frozen=True)
class RunInputs:
    """What a trained model takes and how its training data was made.

    Attributes:
        image_size: (H, W) px the model's image input (frames or depth maps) is resized
            to; None for a frame-free strategy.
        store_image_size: (H, W) px of the training store's frames; readers of raw
            sources (grasp directories, videos) resize to it first, as the importer did.
        constants: normalisation constants (frames, scalars, label range).
        inputs: the input strategy (``models.inputs``).
        sensor: depth model and pixel density of the training data's analytical estimates.
        estimator: the estimator that made them; it runs at ``sensor``'s pixel density.
        channel_order: of the frames the model sees (:data:`CHANNEL_ORDER`).
        rig_stiffness_n_per_m: the rig stiffness [N/m] of the training data's
            rig-corrected estimates, for a strategy that takes them (``FWR``; None
            otherwise): ``live`` and the stream compute them from depth maps with it.
        missing_estimates: the model was trained with ``training.estimate_dropout``, so
            it takes NaN analytical estimates as missing (``MISSING_SCALAR``, as training
            hid them) and still estimates a grasp whose fits failed; False: NaN estimates
            are refused (``predict`` skips such grasps).
    """

    image_size: tuple[int, int] | None
    store_image_size: tuple[int, int]
    constants: NormalisationConstants
    inputs: InputStrategy
    sensor: SensorUnits = WEDGE_UNITS
    estimator: AnalyticalEstimator = DEFAULT_ESTIMATOR
    channel_order: str = CHANNEL_ORDER
    rig_stiffness_n_per_m: float | None = None
    missing_estimates: bool = False

    def __post_init__(self) -> None:
        set_field = object.__setattr__  # a frozen dataclass normalises its own fields
        set_field(self, "inputs", InputStrategy.parse(self.inputs))
        set_field(self, "store_image_size", check_size(self.store_image_size, "store_image_size"))
        if (self.image_size is None) != (self.inputs.image is None):
            raise ValueError(
                f"image_size must be given exactly when inputs={self.inputs.value} has an "
                f"image input, got {self.image_size!r}"
            )
        if self.image_size is not None:
            set_field(self, "image_size", check_size(self.image_size, "image_size"))
        set_field(self, "estimator", self.estimator.at(self.sensor.px_per_mm))
        if self.channel_order != CHANNEL_ORDER:
            raise ValueError(f"channel_order must be {CHANNEL_ORDER!r}, got {self.channel_order!r}")
        k = self.rig_stiffness_n_per_m
        if self.inputs.uses("rig_estimates") != (k is not None):
            raise ValueError(
                f"rig_stiffness_n_per_m must be given exactly when inputs={self.inputs.value} "
                f"takes the rig-corrected estimates, got {k!r}"
            )
        if k is not None and not (isinstance(k, (int, float)) and math.isfinite(k) and k > 0):
            raise ValueError(f"rig_stiffness_n_per_m must be a stiffness in N/m > 0, got {k!r}")
        if self.missing_estimates and not self.analytical_inputs:
            raise ValueError(
                f"missing_estimates needs analytical estimates, and inputs={self.inputs.value} "
                "takes none"
            )

    @property
    def analytical_inputs(self) -> tuple[str, ...]:
        """The analytical inputs its strategy takes (``data.inputs.ANALYTICAL_INPUTS``:
        ``estimates``, ``rig_estimates``), in table order."""
        return tuple(n for n in self.inputs.input_names if n in ANALYTICAL_INPUTS)

    @classmethod
    def resolve(
        cls,
        cfg: ExperimentConfig,
        store: GraspStore,
        model: Any,
        *,
        image_size: tuple[int, int] | None = None,
    ) -> RunInputs:
        """The record of a run of ``cfg`` on ``store`` with ``model`` (an instance or a
        class). The image size (frames or depth maps) is ``image_size`` (``pretrain
        --size``), else ``cfg.data.image_size``, else the model's
        ``recommended_image_size``, else the store's frame size; None for a frame-free
        strategy. The estimator is the store's (``GraspStore.analytical_estimator``), and
        so is the rig stiffness of a strategy that takes the rig-corrected estimates.

        Raises:
            ValueError: the strategy takes the rig-corrected estimates and the store has
                none.
        """
        strategy = InputStrategy.parse(cfg.inputs)
        rig_stiffness = None
        if strategy.uses("rig_estimates"):
            rig_stiffness = store.units.rig_stiffness_n_per_m
            if rig_stiffness is None:
                raise ValueError(
                    f"inputs={strategy.value} takes the rig-corrected estimates, and the store "
                    f"{store.path} has none: import grasps recorded with `record --rig "
                    "RIG.json`, or generated by `simulate` (every rig has a stiffness)"
                )
        size = (
            image_size
            or cfg.data.image_size
            or getattr(model, "recommended_image_size", None)
            or store.image_size
        )
        return cls(
            image_size=None if strategy.image is None else tuple(size),  # type: ignore[arg-type]
            store_image_size=store.image_size,
            constants=cfg.normalisation_constants(),
            inputs=strategy,
            sensor=store.sensor_units,
            estimator=store.analytical_estimator,
            rig_stiffness_n_per_m=rig_stiffness,
            missing_estimates=cfg.training.estimate_dropout > 0,
        )

    def check_sensor(self, units: SensorUnits, *, trained: str, used: str) -> None:
        """Refuse data whose analytical estimates or depth maps are in other units than the
        training data's, when this run takes either (ALL, FWE, DepthFW, DepthALL, FWR; the
        others are not checked): the one check of ``predict``, ``live`` and ``evaluate``.

        Raises:
            ValueError: one line naming ``trained`` and ``used`` and both units.
        """
        if self.analytical_inputs or self.inputs.uses("depth"):
            self.sensor.check_same(units, trained=trained, used=used)

    def source_mismatch(
        self, frame_size: tuple[int, int] | None, units: SensorUnits, *, used: str
    ) -> list[str]:
        """Warnings (one line each, none when all agree) for a source ``used`` whose frames
        are ``frame_size`` (H, W) px as it gives them (None: unknown) and whose sensor is
        ``units``, where they differ from the training store's frames
        (``store_image_size``, for a model with an image input) or sensor (for a model
        that :meth:`check_sensor` does not refuse on it): the shared check of ``predict``
        and ``live``, which show each warning once.
        """
        out = []
        if (
            self.inputs.image is not None
            and frame_size is not None
            and tuple(int(n) for n in frame_size) != tuple(self.store_image_size)
        ):
            h, w = self.store_image_size
            out.append(
                f"the model was trained on {h}x{w} px frames, {used} gives "
                f"{frame_size[0]}x{frame_size[1]} px: they are resized to what it takes, but "
                "a sensor seen at another scale or crop may not give the estimates it learnt; "
                "train on this sensor's frames, or check the estimates against known objects"
            )
        if not self.sensor.same(units):
            out.append(
                f"the model was trained on a sensor with {self.sensor.describe()}, {used} "
                f"has {units.describe()}: check its estimates against known objects"
            )
        return out

    def rig_mismatch(self, rig_stiffness_n_per_m: float | None, *, used: str) -> list[str]:
        """A warning (one line; none when they agree or the model takes no rig-corrected
        estimates) for a source ``used`` whose rig-corrected estimates were made at
        ``rig_stiffness_n_per_m`` [N/m] (None: it has none) where that differs from the
        training data's (1e-6 relative): ``predict``'s check; ``live`` computes the pair
        itself, at the checkpoint's stiffness."""
        trained, given = self.rig_stiffness_n_per_m, rig_stiffness_n_per_m
        if trained is None or (given is not None and math.isclose(trained, given, rel_tol=1e-6)):
            return []
        if given is None:
            return [
                f"the model takes rig-corrected estimates (made at {trained:.4g} N/m), and "
                f"{used} has none: record with `record --rig RIG.json`"
            ]
        return [
            f"the model was trained on rig-corrected estimates made at {trained:.4g} N/m, "
            f"{used} has them at {given:.4g} N/m: another rig; check its estimates against "
            "known objects"
        ]

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON values; inverse of :meth:`from_dict`."""
        return {
            "image_size": None if self.image_size is None else list(self.image_size),
            "store_image_size": list(self.store_image_size),
            "channel_order": self.channel_order,
            "normalisation": self.constants.to_dict(),
            "inputs": self.inputs.value,
            "sensor": self.sensor.to_dict(),
            "analytical_estimator": self.estimator.name,
            **(
                {}
                if self.rig_stiffness_n_per_m is None
                else {"rig_stiffness_n_per_m": self.rig_stiffness_n_per_m}
            ),
            **({"missing_estimates": True} if self.missing_estimates else {}),
        }

    @classmethod
    def from_dict(cls, data: Any, source: str = "run inputs") -> RunInputs:
        """Read :meth:`to_dict`; a missing or invalid field is a ValueError naming ``source``."""
        try:
            return cls(
                image_size=data["image_size"],
                store_image_size=data["store_image_size"],
                constants=NormalisationConstants.from_dict(data["normalisation"]),
                inputs=data["inputs"],
                sensor=SensorUnits.from_dict(data["sensor"]),
                estimator=AnalyticalEstimator(data["analytical_estimator"]),
                channel_order=data["channel_order"],
                rig_stiffness_n_per_m=data.get("rig_stiffness_n_per_m"),
                missing_estimates=bool(data.get("missing_estimates", False)),
            )
        except (KeyError, TypeError, ValueError, AttributeError) as err:
            problem = f"missing {err}" if isinstance(err, KeyError) else str(err)
            raise ValueError(f"{source}: invalid run inputs: {problem}") from err
