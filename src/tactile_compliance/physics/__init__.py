"""Physics of a GelSight grasp: Shore hardness conversions, contact mechanics and the
two analytical Young's-modulus estimators (Hooke and Hertz/MDR) of the original pipeline.

See ``docs/physics.md`` for the formulas, units and constants.
"""

from tactile_compliance.physics.contact import (
    DEFAULT_GEL_MODULUS_PA,
    DEFAULT_GEL_POISSON,
    DEFAULT_OBJECT_POISSON,
    FINAL_PIPELINE_GEL_MODULUS_PA,
    SensorConstants,
    analytical_estimates_pa,
    effective_modulus_pa,
    estimate_elastic_modulus_pa,
    estimate_hertz_effective_modulus_pa,
    hertz_contact_radius_m,
    hertz_force_n,
    hertz_indentation_m,
    hertz_max_pressure_pa,
    object_modulus_from_effective_pa,
)
from tactile_compliance.physics.shore import (
    modulus_pa_to_shore00,
    shore00_to_modulus_pa,
    shore_a_to_modulus_pa_gent,
    shore_a_to_modulus_pa_reuss,
    shore_d_to_modulus_pa_reuss,
)

__all__ = [
    "DEFAULT_GEL_MODULUS_PA",
    "DEFAULT_GEL_POISSON",
    "DEFAULT_OBJECT_POISSON",
    "FINAL_PIPELINE_GEL_MODULUS_PA",
    "SensorConstants",
    "analytical_estimates_pa",
    "effective_modulus_pa",
    "estimate_elastic_modulus_pa",
    "estimate_hertz_effective_modulus_pa",
    "hertz_contact_radius_m",
    "hertz_force_n",
    "hertz_indentation_m",
    "hertz_max_pressure_pa",
    "modulus_pa_to_shore00",
    "object_modulus_from_effective_pa",
    "shore00_to_modulus_pa",
    "shore_a_to_modulus_pa_gent",
    "shore_a_to_modulus_pa_reuss",
    "shore_d_to_modulus_pa_reuss",
]
