"""Shore durometer hardness -> Young's modulus (and back for Shore 00): empirical fits.

Every function takes a number or an array and returns the same kind: a float for a
scalar, a float64 array otherwise. A hardness outside [0, 100] or NaN is a ValueError
naming the value.

See docs/physics.md, "Shore hardness -> Young's modulus".
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from tactile_compliance.physics.contact import ArrayOrFloat, _like_inputs

__all__ = [
    "modulus_pa_to_shore00",
    "shore00_to_modulus_pa",
    "shore_a_to_modulus_pa_gent",
    "shore_a_to_modulus_pa_reuss",
    "shore_d_to_modulus_pa_reuss",
]

_PA_PER_MPA = 1.0e6

# Larson 2017 fit for Shore 00 silicones: E[MPa] = A * exp(B * S00).
_LARSON_A_MPA = 0.0037
_LARSON_B_PER_SHORE = 0.0718

# Gent's (1958) Shore A relation: E[MPa] = N (56 + K S) / (M (254 - T S)). The relation
# as usually quoted has T = 2.54 (mm of indenter travel per 100 points, with its pole at
# S = 100); the "Gent, Shore A" column of the dataset's object table
# (dataset_objects_and_compliance.csv) is reproduced, to its 3 significant digits for
# all 63 objects with a Shore A value, only with T = 2.4 (T = 2.54 is up to 50 % off, at
# S = 90). The labels derive from that table, so we use T = 2.4.
_GENT_NUMERATOR_MPA = 0.0981  # kgf/mm^2 -> MPa
_GENT_OFFSET = 56.0
_GENT_SLOPE = 7.62336
_GENT_DENOMINATOR = 0.137505
_GENT_TRAVEL_MM = 254.0
_GENT_TRAVEL_PER_SHORE = 2.4

# Exponential Shore A/D fit: E[MPa] = exp(C * S + D); Shore D is shifted by +50 onto A.
_REUSS_C_PER_SHORE = 0.0235
_REUSS_D = -0.6403
_SHORE_D_TO_A_OFFSET = 50.0

_HARDNESS_MIN = 0.0
_HARDNESS_MAX = 100.0
# Round-tripping through exp/log can land a hair outside [0, 100]; accept that much.
_SHORE_ROUNDING_SLACK = 1e-9


def _as_float_array(value: ArrayOrFloat, what: str) -> npt.NDArray[np.float64]:
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{what} must be a number or an array of numbers, got {value!r}") from exc


def _describe_bad(values: npt.NDArray[np.float64], bad: npt.NDArray[np.bool_]) -> str:
    """Name the offending values (a few of them for big arrays) for the error message."""
    offending = values[bad]
    shown = ", ".join(repr(float(v)) for v in offending[:5])
    more = f" (and {offending.size - 5} more)" if offending.size > 5 else ""
    return shown + more


def _checked_hardness(shore: ArrayOrFloat, scale: str) -> npt.NDArray[np.float64]:
    values = _as_float_array(shore, f"Shore {scale} hardness")
    bad = np.isnan(values) | (values < _HARDNESS_MIN) | (values > _HARDNESS_MAX)
    if np.any(bad):
        raise ValueError(
            f"Shore {scale} hardness must be in [0, 100] and not NaN, got "
            f"{_describe_bad(values, bad)}"
        )
    return values


def shore00_to_modulus_pa(shore_00: ArrayOrFloat) -> ArrayOrFloat:
    """Young's modulus [Pa] from Shore 00 hardness [0-100] (Larson 2017 silicone fit).

    ``E[MPa] = 0.0037 * exp(0.0718 * S00)``, i.e. ``log10 E[Pa] = 3.5682 + 0.031182 S00``.
    Shore 00 60 (the GelSight gel) gives 0.2748 MPa; 50 gives 0.134 MPa.

    Raises:
        ValueError: a hardness outside [0, 100] or NaN.
    """
    values = _checked_hardness(shore_00, "00")
    modulus_pa = _LARSON_A_MPA * np.exp(_LARSON_B_PER_SHORE * values) * _PA_PER_MPA
    return _like_inputs(modulus_pa, shore_00)


def modulus_pa_to_shore00(modulus_pa: ArrayOrFloat) -> ArrayOrFloat:
    """Shore 00 hardness [0-100] from Young's modulus [Pa]: the inverse of the Larson fit.

    ``S00 = ln(E[MPa] / 0.0037) / 0.0718``. The fit only covers the durometer scale, i.e.
    moduli from 3.7 kPa (S00 = 0) to about 4.86 MPa (S00 = 100).

    Raises:
        ValueError: a modulus that is NaN, not positive, or outside that range (the
            hardness would leave [0, 100]).
    """
    values = _as_float_array(modulus_pa, "modulus_pa")
    bad = ~np.isfinite(values) | (values <= 0.0)
    if np.any(bad):
        raise ValueError(f"modulus_pa must be finite and > 0 Pa, got {_describe_bad(values, bad)}")
    shore = np.log(values / (_LARSON_A_MPA * _PA_PER_MPA)) / _LARSON_B_PER_SHORE
    outside = (shore < _HARDNESS_MIN - _SHORE_ROUNDING_SLACK) | (
        shore > _HARDNESS_MAX + _SHORE_ROUNDING_SLACK
    )
    if np.any(outside):
        low_pa = float(shore00_to_modulus_pa(_HARDNESS_MIN))
        high_pa = float(shore00_to_modulus_pa(_HARDNESS_MAX))
        raise ValueError(
            f"modulus_pa {_describe_bad(values, outside)} is outside the Shore 00 scale "
            f"(Larson fit covers {low_pa:.4g} Pa to {high_pa:.4g} Pa)"
        )
    shore = np.clip(shore, _HARDNESS_MIN, _HARDNESS_MAX)
    return _like_inputs(shore, modulus_pa)


def shore_a_to_modulus_pa_gent(shore_a: ArrayOrFloat) -> ArrayOrFloat:
    """Young's modulus [Pa] from Shore A hardness [0-100] (Gent 1958, dataset variant).

    ``E[MPa] = 0.0981 (56 + 7.62336 S) / (0.137505 (254 - 2.4 S))``: the form that
    reproduces the "Gent, Shore A" column of the dataset's object table (2.4, not the usual
    2.54: see the constants above and docs/physics.md).

    Raises:
        ValueError: a hardness outside [0, 100] or NaN.
    """
    values = _checked_hardness(shore_a, "A")
    numerator = _GENT_NUMERATOR_MPA * (_GENT_OFFSET + _GENT_SLOPE * values)
    denominator = _GENT_DENOMINATOR * (_GENT_TRAVEL_MM - _GENT_TRAVEL_PER_SHORE * values)
    return _like_inputs(numerator / denominator * _PA_PER_MPA, shore_a)


def shore_a_to_modulus_pa_reuss(shore_a: ArrayOrFloat) -> ArrayOrFloat:
    """Young's modulus [Pa] from Shore A hardness [0-100] (exponential "Reuss" fit).

    ``E[MPa] = exp(0.0235 S - 0.6403)``.

    Raises:
        ValueError: a hardness outside [0, 100] or NaN.
    """
    values = _checked_hardness(shore_a, "A")
    modulus_pa = np.exp(_REUSS_C_PER_SHORE * values + _REUSS_D) * _PA_PER_MPA
    return _like_inputs(modulus_pa, shore_a)


def shore_d_to_modulus_pa_reuss(shore_d: ArrayOrFloat) -> ArrayOrFloat:
    """Young's modulus [Pa] from Shore D hardness [0-100] (exponential "Reuss" fit).

    The Shore A fit evaluated at ``S = S_D + 50``: ``E[MPa] = exp(0.0235 (S_D + 50) - 0.6403)``.

    Raises:
        ValueError: a hardness outside [0, 100] or NaN.
    """
    values = _checked_hardness(shore_d, "D")
    shifted = values + _SHORE_D_TO_A_OFFSET
    modulus_pa = np.exp(_REUSS_C_PER_SHORE * shifted + _REUSS_D) * _PA_PER_MPA
    return _like_inputs(modulus_pa, shore_d)
