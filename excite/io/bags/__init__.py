"""Drives logged in ROS bags: ROS 1 ``.bag``, ROS 2 bag folders (sqlite3 or MCAP storage) and
bare ``.mcap`` files, read with ``rosbags`` (pure Python, no ROS installation).

Trajectory sources (``topic``):

- a topic of ``geometry_msgs/PoseStamped``, ``PoseWithCovarianceStamped``, ``TransformStamped``
  or ``nav_msgs/Odometry``: the pose of the message's child frame (``child_frame_id``, else the
  frame the user names) in ``header.frame_id``, at ``header.stamp``;
- a TF chain ``/tf:PARENT.CHILD`` (evo's convention): the pose of ``CHILD`` in ``PARENT``,
  composed over every hop between them; dynamic hops come from ``/tf`` (the first dynamic hop's
  stamps are the samples, further dynamic hops are interpolated at them) and static hops from
  ``/tf_static``.

The poses go through the same smoothing fit as a TUM file
(:func:`excite.io.poses.trajectory_from_poses`): a bag and a TUM export of it score alike.

**Body frame.** The poses describe one frame of the robot (``base_link``, a camera, ...); excite
takes that frame as the vehicle frame V (rear-axle centre, x forward, y left, z up). With
``vehicle_frame`` the poses are moved to another frame of the robot through ``/tf_static``
(``T_W_V = T_W_C · T_C_V``). Poses logged in camera-optical axes (x right, y down, z forward, as
visual SLAM writes them) are mapped to vehicle axes with ``axes="optical"``.

**Measured IMU.** With ``imu_topic`` (``sensor_msgs/Imu``), the drive's angular rate and specific
force at the IMU samples of the evaluator are the *measured* ones (linearly interpolated to the
rig's IMU rate), not the derivatives of the smoothed poses: real excitation and real vibration
enter the information model. The IMU message frame is taken as the rig's body frame B. The
orientation, position and velocity keep coming from the poses. How well the two agree is
measured by :func:`imu_agreement` (1-s means of measured against pose-derived rate and specific
force, the constant offset between them and the rotation that best aligns them) and printed
by ``excite score``; a large mounting mismatch means the rig's ``T_V_B`` is not the IMU's.

**GNSS fixes.** With ``gnss_topic`` (``sensor_msgs/NavSatFix``) the drive carries the fixes'
times (a message without a fix, or no message, is an outage) and their reported covariance as the
log of the rig's GNSS antenna (:mod:`.gnss`): it is scored with the fixes the log holds.

**An odometry's own covariance.** With ``odometry_topic`` (``nav_msgs/Odometry`` or
``PoseWithCovarianceStamped``) the drive carries each message's pose covariance, read as that of
the odometry's increment since its previous message, as the log of the rig's lidar or camera
``odometry_sensor`` (:mod:`.covariance`): with the sensor's ``noise.use_reported_covariance`` a
stretch the odometry reports worse counts less.

Decoding is streamed (one message at a time) and the fields excite needs are read straight from
the serialized bytes (CDR for ROS 2, the ROS 1 wire format): a fraction of the cost of building
full message objects. :func:`write_bag` writes a drive as a bag (ROS 1 ``.bag`` or a ROS 2
folder with MCAP storage), so every format has a round trip.

Every problem is a :class:`BagError` naming the file, the topic and what is wrong (lists of
topics or frames in it are cut at a few dozen names).

**Bounds.** Every decompression is bounded before it allocates: a chunk (ROS 1 bz2/lz4, MCAP
zstd/lz4) may expand to at most :data:`~.mcap.MAX_CHUNK_BYTES` and to at most
:data:`~.mcap.MAX_RATIO` times its compressed size, and one read of a bag may decompress at most
:func:`~.mcap.Budget.for_file` bytes in all; a chunk past a bound, an unknown compression or a
corrupt stream is a :class:`BagError`, never an allocation of the size a header claims. TF
chains are resolved in time linear in the frames.

**A car's own signals** (:mod:`.vehicle`): wheel speeds and a steering angle from
``sensor_msgs/JointState`` (:func:`read_wheel_speeds`), a radar's ego-velocity from
``geometry_msgs/TwistWithCovarianceStamped`` or ``TwistStamped`` (:func:`read_ego_velocity`),
for the Ackermann and radar kinds (other types on those topics are an error naming these).

The package by concern: :mod:`.decode` (message types and decoding straight from the bytes),
:mod:`.stream` (opening a bag, streaming its messages under the decompression bounds),
:mod:`.mcap` (excite's own MCAP reader and the bounded decompression), :mod:`.tf` (TF trees and
chains), :mod:`.imu` (measured IMU and its agreement with the poses), :mod:`.gnss` (NavSatFix fixes),
:mod:`.covariance` (an odometry's pose covariance),
:mod:`.vehicle` (wheel speeds, steering, radar ego-velocity), :mod:`.reader` (the entry
points: topics, poses, IMU, routes), :mod:`.writer` (writing and cropping bags).
"""


from __future__ import annotations

from ...errors import BagError
from ..sniff import is_bag
from .decode import AXES, IMU_TYPE, POSE_TYPES, TF_STATIC_TOPIC, TF_TOPIC, TF_TYPES, PoseSeries, Series
from .covariance import COVARIANCE_TYPES, PoseCovariances, odometry_log, read_pose_covariances
from .gnss import NAVSAT_TYPE, FixAgreement, FixSeries, fix_agreement, fix_log, read_fixes
from .imu import ImuAgreement, ImuSeries, ImuTrajectory, imu_agreement
from .mcap import MAX_CHUNK_BYTES, MAX_RATIO, Budget, decompress
from .reader import (BagSource, TopicInfo, bag_info, read_bag_route, read_imu, read_poses, read_static_tf,
                     rig_from_tf)
from .vehicle import (EGO_VELOCITY_TYPES, JOINT_STATE_TYPE, EgoVelocitySeries, WheelSpeeds, can_recording,
                      ego_velocity_at, ego_velocity_noise, read_ego_velocity, read_wheel_speeds, write_vehicle_bag)
from .writer import crop_bag, write_bag

__all__ = [
    "BagError", "BagSource", "TopicInfo", "PoseSeries", "ImuSeries", "ImuTrajectory", "ImuAgreement",
    "is_bag", "bag_info", "read_poses", "read_imu", "read_static_tf", "read_bag_route",
    "imu_agreement", "write_bag", "POSE_TYPES", "TF_TYPES", "IMU_TYPE",
    "FixSeries", "FixAgreement", "read_fixes", "fix_log", "fix_agreement", "NAVSAT_TYPE",
    "PoseCovariances", "read_pose_covariances", "odometry_log", "COVARIANCE_TYPES",
    # a car's own signals: wheel speeds (JointState), a radar's ego-velocity (Twist)
    "WheelSpeeds", "EgoVelocitySeries", "read_wheel_speeds", "read_ego_velocity", "can_recording",
    "ego_velocity_at", "ego_velocity_noise", "write_vehicle_bag", "JOINT_STATE_TYPE", "EGO_VELOCITY_TYPES",
    # a rig from a bag's /tf_static; used by excite's other packages: cropping for mining, the bounds
    "Series", "rig_from_tf", "crop_bag", "Budget", "decompress",
    "MAX_CHUNK_BYTES", "MAX_RATIO", "TF_TOPIC", "TF_STATIC_TOPIC", "AXES",
]
