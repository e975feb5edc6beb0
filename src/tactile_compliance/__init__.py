"""tactile-compliance: Young's modulus from one GelSight grasp (3 tactile frames, force, width)."""

__version__ = "0.1.0"
