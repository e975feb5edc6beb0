"""Physics of a GelSight grasp: Shore hardness conversions, contact mechanics and the
two analytical Young's-modulus estimators (Hooke and Hertz/MDR) of the original pipeline.

See ``docs/physics.md`` for the formulas, units and constants. The package's public names
are those of ``contact`` and ``shore`` (each module's ``__all__`` is the one list).
"""

from tactile_compliance.physics import contact, shore
from tactile_compliance.physics.contact import *  # noqa: F403
from tactile_compliance.physics.shore import *  # noqa: F403

__all__ = [*contact.__all__, *shore.__all__]
