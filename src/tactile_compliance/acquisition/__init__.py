"""Acquisition: frames from a sensor, its calibration, and recording grasps to disk.

Below inference (nothing here knows an estimator); used by ``live``, ``calibrate``,
``calibrate-depth``, ``depth`` and ``record``.

* :func:`open_source` - live frame sources: GelSight Mini, Wedge over HTTP MJPEG, DIGIT,
  cameras, videos, folders (``sensors.py``).
* :class:`SensorCalibration` - a sensor's geometry, no-contact frame, px/mm and depth
  model (``calibration.py``; the ``calibrate`` and ``calibrate-depth`` commands).
* :func:`record_grasp` - record your own grasps in the public dataset's raw layout
  (``recording.py``; the ``record`` command), with force and width :class:`Readings`.

See ``docs/sensors.md`` and ``docs/inference.md``.
"""

from tactile_compliance.acquisition.calibration import SensorCalibration
from tactile_compliance.acquisition.recording import ObjectInfo, Readings, record_grasp
from tactile_compliance.acquisition.sensors import open_source

__all__ = ["ObjectInfo", "Readings", "SensorCalibration", "open_source", "record_grasp"]
