"""Physics of a GelSight grasp: Shore hardness conversions, contact mechanics and the
analytical Young's-modulus estimators (Hooke and Hertz/MDR): ours (``contact``) and the
dataset-compatible one whose values the public dataset stored (``dataset_estimates``).

See ``docs/physics.md`` for the formulas, units and constants. The package's public names
are those of ``contact``, ``dataset_estimates`` and ``shore`` (each module's ``__all__`` is
the one list).
"""

from tactile_compliance.physics import contact, dataset_estimates, shore
from tactile_compliance.physics.contact import *  # noqa: F403
from tactile_compliance.physics.dataset_estimates import *  # noqa: F403
from tactile_compliance.physics.shore import *  # noqa: F403

__all__ = [*contact.__all__, *dataset_estimates.__all__, *shore.__all__]
