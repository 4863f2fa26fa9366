"""Rigs from the calibration files users already have, one module per format:

- :mod:`.kalibr` — Kalibr's camchain (``T_cam_imu``; OpenVINS's ``T_imu_cam``) and IMU files (its
  input ``imu.yaml`` and its output ``imu-*.yaml`` with ``imu0:``, …), OpenCV's header included;
- :mod:`.vins` — VINS-Fusion (``body_T_camN: !!opencv-matrix``);
- :mod:`.lio_sam` — LIO-SAM's ``params.yaml``;
- :mod:`.fast_lio` — FAST-LIO's (and FAST-LIVO's) configuration;
- :mod:`.urdf` — a URDF (sensor frames through joints);
- :mod:`.autoware` — Autoware's sensor-kit calibration files;
- a bag's ``/tf_static`` tree: :func:`excite.io.bags.rig_from_tf` (it reads bags), through
  :mod:`.tree`, which composes every tree of frames.

What they share (reading files within bounds, rotations to the precision of their printed
digits, names from frames, defaults marked for review, the rig YAML an import writes) is in
:mod:`.common`; :mod:`excite.rig.files` reads them and tells which format a file is in. Every imported rig is validated
by :func:`excite.rig.config.build_rig` before it is returned.
"""

from .autoware import rig_from_autoware
from .common import DEFAULT_IMU, DEFAULT_ODOMETRY_NOISE, ImportedRig, default_targets, rig_yaml
from .fast_lio import rig_from_fast_lio
from .kalibr import rig_from_kalibr
from .lio_sam import rig_from_lio_sam
from .tree import Hop, Tree, rig_from_tree
from .urdf import rig_from_urdf
from .vins import rig_from_vins

__all__ = ["ImportedRig", "rig_yaml", "default_targets", "DEFAULT_IMU", "DEFAULT_ODOMETRY_NOISE",
           "rig_from_kalibr", "rig_from_vins", "rig_from_lio_sam", "rig_from_fast_lio", "rig_from_urdf",
           "rig_from_autoware", "rig_from_tree", "Tree", "Hop"]
