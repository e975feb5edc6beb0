"""A gripper rig as data: the generator's ``GripperRig``, its JSON file and the named rigs.

A rig file is what ``calibrate-rig`` writes from a user's own recordings of a rigid object
(``synthetic.rig_fit``); ``simulate --rig`` and ``sim2real --rig`` take a file or a name of
:data:`RIGS`. The named ``wedge-2023`` rig is such a file, shipped in the package
(``synthetic/rigs/wedge-2023.json``). See docs/synthetic.md, "The rig: calibrate-rig".
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, fields
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from tactile_compliance.outputs import check_format_version
from tactile_compliance.physics.contact import DEFAULT_GEL_MODULUS_PA
from tactile_compliance.synthetic.rng import log_uniform

__all__ = [
    "DATASET_RIG",
    "RANDOMISATION_FIELDS",
    "RIGS",
    "RIG_FILE_KIND",
    "RIG_FORMAT_VERSION",
    "WEDGE_2023_RIG",
    "GripperRig",
    "is_rig_file",
    "read_rig_file",
    "resolve_rig",
    "rig_file_text",
]

RIG_FILE_KIND = "tactile-compliance rig"
"""The ``kind`` field of a rig file (what ``--out`` recognises as its own)."""

RIG_FORMAT_VERSION = 1
"""The one rig-file format this package reads and writes."""


@dataclass(frozen=True)
class GripperRig:
    """The gripper, its mount and its force controller, and the sensor's gel and lights:
    what ``calibrate-rig`` fits from grasps of a rigid object (no modulus label needed).

    Attributes:
        peak_force_n: mean and standard deviation of the target force ``F_t`` [N].
        finger_stiffness_n_per_m: range of the finger/mount stiffness ``K_f`` [N/m]; each
            recording session draws one, log-uniformly (equal bounds: one value). The
            rig's own compliance, in series with the gel and the object.
        edge_glow_grey_per_mm: range of the gain of the sensor's green-edge glow [grey
            levels per mm of imprint depth at the left edge] (``render.SensorLook``);
            each session draws one, log-uniformly. ``(0, 0)``: no glow.
        gel_modulus_pa: the sensor gel's median Young's modulus [Pa]; each session's two
            gels scatter about it by a factor 10^N(0, 0.05). A rigid ball's contact area
            at a known force measures it on a real sensor.
        light_balance: factors on the drawn strengths of the sensor's three lights (G, R,
            B) [-] (``render.SensorLook.light_gain``): the colour balance of an imprint.
            A rigid ball's difference image measures it on a real sensor.
        soft_contact_spread: factor on the radius of a compliant object's imprint [-],
            weighted by the object's share ``c_o`` of the deformation (radius x ``1 - c_o
            (1 - spread)``, volume kept: ``mechanics.gel_compression``); 1: the contact
            mechanics as they are. Grasps of soft reference objects of known modulus
            measure it (``calibrate-rig --soft``), a rigid ball cannot.
        soft_edge_glow: extra edge glow of compliant contacts [-]: each frame's glow gain
            x ``1 + soft_edge_glow c_o``; 0: none. Fitted with ``soft_contact_spread``.

    Domain randomisation (what real set-ups of one rig vary; each drawn per session or
    per grasp from the generator's keyed streams, ``synthetic.rng``; the defaults are the
    generator's own ranges, so a rig without them makes the same data):

    Attributes:
        force_baseline_sd_n: sd of the force reading's offset per grasp [N] (a real
            rig's baseline is not zeroed).
        reference_contact_probability: share of grasps whose reference (no-contact)
            frame is taken in light contact [-], as a recording that starts touching.
        reference_contact_n: range of the force of that light contact [N] (uniform).
        light_jitter: sd of each light's strength factor about the rig's balance [-].
        read_noise_grey: range of the camera's read-noise sigma [grey levels] (uniform).
        gel_thickness_mm: range of the gel's thickness [mm] (uniform, per gel).
        gel_modulus_sd_decades: sd of each gel's modulus about ``gel_modulus_pa``
            [decades].
        background_jitter: factor on the spread of the no-contact frame's colours [-].
    """

    peak_force_n: tuple[float, float] = (60.0, 2.0)
    finger_stiffness_n_per_m: tuple[float, float] = (1e5, 6e5)
    edge_glow_grey_per_mm: tuple[float, float] = (0.0, 0.0)
    gel_modulus_pa: float = DEFAULT_GEL_MODULUS_PA
    light_balance: tuple[float, float, float] = (1.0, 1.0, 1.0)
    soft_contact_spread: float = 1.0
    soft_edge_glow: float = 0.0
    force_baseline_sd_n: float = 0.15
    reference_contact_probability: float = 0.0
    reference_contact_n: tuple[float, float] = (0.1, 1.1)
    light_jitter: float = 0.08
    read_noise_grey: tuple[float, float] = (2.0, 3.0)
    gel_thickness_mm: tuple[float, float] = (3.5, 5.5)
    gel_modulus_sd_decades: float = 0.05
    background_jitter: float = 1.0

    def __post_init__(self) -> None:
        mean, sd = self.peak_force_n
        lo, hi = self.finger_stiffness_n_per_m
        if not (mean > 10.0 and sd >= 0.0):
            # The published frame selection rejects grasps that never reach 10 N.
            raise ValueError(f"peak force must be above 10 N with sd >= 0, got {mean} +- {sd} N")
        if not 0.0 < lo <= hi:
            raise ValueError(f"finger stiffness range must be 0 < lo <= hi N/m, got {lo}, {hi}")
        if not self.gel_modulus_pa > 0.0:
            raise ValueError(f"gel modulus must be positive, got {self.gel_modulus_pa} Pa")
        if not all(factor > 0.0 for factor in self.light_balance):
            raise ValueError(f"light balance factors must be positive, got {self.light_balance}")
        if not 0.0 < self.soft_contact_spread <= 2.0:
            raise ValueError(
                f"soft contact spread must be in (0, 2], got {self.soft_contact_spread}"
            )
        if not self.soft_edge_glow >= 0.0:
            raise ValueError(f"soft edge glow must be >= 0, got {self.soft_edge_glow}")
        for name in ("reference_contact_n", "read_noise_grey", "gel_thickness_mm"):
            lo_v, hi_v = getattr(self, name)
            if not 0.0 <= lo_v <= hi_v or (name == "gel_thickness_mm" and lo_v <= 0.0):
                raise ValueError(f"{name} must be a range 0 <= lo <= hi, got {lo_v}, {hi_v}")
        if not 0.0 <= self.reference_contact_probability <= 1.0:
            raise ValueError(
                "reference contact probability must be in [0, 1], got "
                f"{self.reference_contact_probability}"
            )
        spreads = ("force_baseline_sd_n", "light_jitter", "gel_modulus_sd_decades")
        for name in (*spreads, "background_jitter"):
            if not getattr(self, name) >= 0.0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        glow_lo, glow_hi = self.edge_glow_grey_per_mm
        if (glow_lo, glow_hi) != (0.0, 0.0) and not 0.0 < glow_lo <= glow_hi:
            raise ValueError(
                f"edge glow range must be (0, 0) or 0 < lo <= hi, got {glow_lo}, {glow_hi}"
            )

    def draw_finger_stiffness_n_per_m(self, rng: np.random.Generator) -> float:
        return log_uniform(rng, *self.finger_stiffness_n_per_m)

    @property
    def stiffness_n_per_m(self) -> float:
        """The rig's own stiffness [N/m]: the geometric middle of ``finger_stiffness_n_per_m``
        (what the rig-corrected analytical estimate subtracts, ``physics.estimators``)."""
        lo, hi = self.finger_stiffness_n_per_m
        return math.sqrt(lo * hi)

    def to_dict(self) -> dict[str, Any]:
        """The fields as JSON values (tuples as lists)."""
        return json.loads(json.dumps(asdict(self)))

    @classmethod
    def from_dict(cls, data: Any, what: str = "rig") -> GripperRig:
        """Read :meth:`to_dict` (ValueError naming ``what`` and the field when invalid)."""
        if not isinstance(data, dict):
            raise ValueError(f"{what}: the rig must be a mapping, got {type(data).__name__}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"{what}: unknown rig field(s) {unknown}; known: {sorted(known)}")
        values: dict[str, Any] = {}
        for name, value in data.items():
            try:
                if isinstance(value, list):
                    values[name] = tuple(float(v) for v in value)
                else:
                    values[name] = float(value)
            except (TypeError, ValueError) as err:
                raise ValueError(f"{what}: rig field {name!r} is not numeric: {value!r}") from err
        lengths = {"peak_force_n": 2, "finger_stiffness_n_per_m": 2}
        lengths |= {"edge_glow_grey_per_mm": 2, "light_balance": 3, "gel_modulus_pa": 0}
        lengths |= {"soft_contact_spread": 0, "soft_edge_glow": 0}
        lengths |= {"reference_contact_n": 2, "read_noise_grey": 2, "gel_thickness_mm": 2}
        lengths |= dict.fromkeys(
            (
                "force_baseline_sd_n",
                "reference_contact_probability",
                "light_jitter",
                "gel_modulus_sd_decades",
                "background_jitter",
            ),
            0,
        )
        for name, value in values.items():
            size = len(value) if isinstance(value, tuple) else 0
            if size != lengths[name] or not np.all(np.isfinite(value)):
                raise ValueError(
                    f"{what}: rig field {name!r} must be {lengths[name]} finite values"
                )
        try:
            return cls(**values)
        except ValueError as err:
            raise ValueError(f"{what}: {err}") from err


RANDOMISATION_FIELDS = (
    "force_baseline_sd_n",
    "reference_contact_probability",
    "reference_contact_n",
    "light_jitter",
    "read_noise_grey",
    "gel_thickness_mm",
    "gel_modulus_sd_decades",
    "background_jitter",
)
"""The domain-randomisation fields of :class:`GripperRig` (``calibrate-rig --randomise``)."""

DATASET_RIG = GripperRig()
"""The rig of the public dataset as the design notes describe it (~60 N presses): the
generator's default, not fitted on any recording."""


def rig_file_text(rig: GripperRig, name: str, fit: dict[str, Any] | None = None) -> str:
    """The JSON text of a rig file: ``kind``, ``format_version``, ``name``, ``rig`` (the
    fields of :class:`GripperRig`) and ``fit`` (what ``calibrate-rig`` fitted it on and
    its residuals; informative, never read back)."""
    data = {
        "kind": RIG_FILE_KIND,
        "format_version": RIG_FORMAT_VERSION,
        "name": name,
        "rig": rig.to_dict(),
        "fit": fit or {},
    }
    return json.dumps(data, indent=2) + "\n"


def _read_json(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ValueError(f"{path}: not a readable rig file ({err})") from err
    if not isinstance(data, dict) or data.get("kind") != RIG_FILE_KIND:
        raise ValueError(f"{path}: not a rig file (no kind {RIG_FILE_KIND!r}; see calibrate-rig)")
    return data


def is_rig_file(path: str | Path) -> bool:
    """Whether ``path`` is a rig file this package wrote (``--out`` may replace it)."""
    try:
        _read_json(Path(path))
    except ValueError:
        return False
    return True


def read_rig_file(path: str | Path) -> tuple[str, GripperRig]:
    """``(name, rig)`` of a rig file.

    Raises:
        ValueError: unreadable, not a rig file, another format version or invalid fields.
    """
    path = Path(path)
    data = _read_json(path)
    check_format_version(data.get("format_version"), RIG_FORMAT_VERSION, f"{path}: rig file")
    return str(data.get("name") or path.stem), GripperRig.from_dict(data.get("rig"), str(path))


def _packaged(name: str) -> GripperRig:
    resource = resources.files("tactile_compliance.synthetic").joinpath(f"rigs/{name}.json")
    with resources.as_file(resource) as path:
        return read_rig_file(path)[1]


WEDGE_2023_RIG = _packaged("wedge-2023")
"""The GelSight Wedge rig of ``real/wedge-grasps`` (the lab's 2023 example grasps), as
``calibrate-rig`` fitted it on the three golf-ball grasps (``synthetic/rigs/
wedge-2023.json``; docs/synthetic.md, "The rig: calibrate-rig")."""

RIGS: dict[str, GripperRig] = {"dataset": DATASET_RIG, "wedge-2023": WEDGE_2023_RIG}
"""Named rigs, as ``simulate --rig`` and ``sim2real --rig`` accept them."""


def resolve_rig(rig: str | Path | GripperRig) -> tuple[str, GripperRig]:
    """``(name, rig)`` of a rig object, a name of :data:`RIGS` or a rig file's path.

    Raises:
        ValueError: an unknown name that is no file either, or an invalid rig file.
    """
    if isinstance(rig, GripperRig):
        return "custom", rig
    text = str(rig)
    if text in RIGS and not Path(text).is_file():
        return text, RIGS[text]
    if Path(text).is_file():
        return read_rig_file(text)
    raise ValueError(
        f"unknown rig {text!r}: give a name ({', '.join(RIGS)}) or a rig file that "
        "calibrate-rig wrote"
    )
