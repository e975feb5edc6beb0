"""Physics of a GelSight grasp: Shore hardness conversions, contact mechanics and the two
analytical Young's-modulus estimators. See docs/physics.md.

The public names are those of ``contact``, ``dataset_estimates`` and ``shore`` (each
module's ``__all__`` is the one list).
"""

from tactile_compliance.physics import contact, dataset_estimates, shore
from tactile_compliance.physics.contact import *  # noqa: F403
from tactile_compliance.physics.dataset_estimates import *  # noqa: F403
from tactile_compliance.physics.shore import *  # noqa: F403

__all__ = [*contact.__all__, *dataset_estimates.__all__, *shore.__all__]
