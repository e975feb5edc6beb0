"""Acquisition: frames from a sensor, its calibration, and recording grasps to disk
(``live``, ``calibrate``, ``calibrate-depth``, ``depth``, ``record``). See docs/sensors.md
and docs/inference.md.
"""

from tactile_compliance.acquisition.calibration import SensorCalibration
from tactile_compliance.acquisition.readings import Readings
from tactile_compliance.acquisition.recording import ObjectInfo, record_grasp
from tactile_compliance.acquisition.sensors import open_source

__all__ = ["ObjectInfo", "Readings", "SensorCalibration", "open_source", "record_grasp"]
