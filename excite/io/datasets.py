"""The public recordings the examples and tests use, and how to fetch them.

Each dataset names its public source, its licence and, per file, the URL it is downloaded from
(pinned to a commit of the source repository), its size and its SHA-256. :func:`fetch` downloads
what is missing into a folder (by default ``../shared/data`` beside the repository, where the
examples and the tests look), checks every file against its checksum and never leaves a partial
file behind; :func:`check` verifies a folder offline. ``excite data list | fetch | check`` are the
command line's doors to them.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import urllib.request
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, Callable

from ..errors import DataError

CHUNK = 1 << 20


@dataclass(frozen=True)
class DataFile:
    """One file of a dataset: where it lands (relative to the data folder), its SHA-256 and size,
    and the URL it comes from."""

    path: str
    sha256: str
    size: int
    url: str


@dataclass(frozen=True)
class Dataset:
    name: str
    description: str
    source: str
    licence: str
    files: tuple[DataFile, ...]

    @property
    def size(self) -> int:
        return sum(f.size for f in self.files)


DATASETS: dict[str, Dataset] = {d.name: d for d in (
    Dataset('kitti_00',
            'KITTI odometry sequence 00: ground-truth poses of the left camera (a car, ~3.7 km of suburb, 470 s) and their times',
            source='MichaelGrupp/evo test data (test/data/KITTI_00_gt*.txt); KITTI by KIT and Toyota Technological Institute',
            licence='CC BY-NC-SA 3.0',
            files=(
                DataFile('kitti_00_poses.txt', '90791a4113df979b149fa9e1104e960ea59f525a8318a202dbb6aec1a3d88793', 728871,
                         'https://raw.githubusercontent.com/MichaelGrupp/evo/26d0953d4da0f0cb56f90ba6269a15e72f69d3ad/test/data/KITTI_00_gt.txt'),
                DataFile('kitti_00_times.txt', '99a2899466cdc28dd292b4856d214a8b0aab035b91b02bb6afcb4ff363e7d421', 59033,
                         'https://raw.githubusercontent.com/MichaelGrupp/evo/26d0953d4da0f0cb56f90ba6269a15e72f69d3ad/test/data/KITTI_00_gt_times.txt'),
            )),
    Dataset('euroc_v102',
            'EuRoC MAV V1_02_medium: ground truth of a micro aerial vehicle, 200 Hz',
            source='MichaelGrupp/evo test data (test/data/V102_groundtruth.csv); EuRoC by ETH Zurich ASL',
            licence='research use (ETH Zurich ASL)',
            files=(
                DataFile('euroc_v102_groundtruth.csv', 'fed415eee44313584b9c4f61010dac146d5e4a4a35301db25b1ecd7d4d91b5f0', 2837076,
                         'https://raw.githubusercontent.com/MichaelGrupp/evo/26d0953d4da0f0cb56f90ba6269a15e72f69d3ad/test/data/V102_groundtruth.csv'),
            )),
    Dataset('georeferenced_utm',
            'a georeferenced trajectory in UTM coordinates, 1000 poses (TUM)',
            source='MichaelGrupp/evo test data (test/data/georeferenced.tum)',
            licence='GPL-3.0 (evo)',
            files=(
                DataFile('georeferenced_utm.tum', '584844af2855d288deb3288918f5879665d0f5dfaef7db76a717263d720b83d9', 201219,
                         'https://raw.githubusercontent.com/MichaelGrupp/evo/26d0953d4da0f0cb56f90ba6269a15e72f69d3ad/test/data/georeferenced.tum'),
            )),
    Dataset('ros_example',
            'a ROS 1 bag of one car drive (~889 s): ground truth and two SLAM estimates as PoseStamped',
            source='MichaelGrupp/evo test data (test/data/ROS_example.bag)',
            licence='GPL-3.0 (evo)',
            files=(
                DataFile('ROS_example.bag', 'b2e4ae2465d3a43933569f8b9b7b593730617ff8262f2e81b71674b3fe37c55b', 3708268,
                         'https://raw.githubusercontent.com/MichaelGrupp/evo/26d0953d4da0f0cb56f90ba6269a15e72f69d3ad/test/data/ROS_example.bag'),
            )),
    Dataset('nav2_turtlebot',
            'a ROS 2 MCAP recording (~97 s) of a TurtleBot 4 driven by Nav2, with its /tf_static sensor tree',
            source='MichaelGrupp/evo test data (test/data/nav2_turtlebot.mcap)',
            licence='GPL-3.0 (evo)',
            files=(
                DataFile('nav2_turtlebot.mcap', '56b182e06492094a21798c9bbc31ff4c60f5e4de44f72dea76e324c432f449c6', 505395,
                         'https://raw.githubusercontent.com/MichaelGrupp/evo/26d0953d4da0f0cb56f90ba6269a15e72f69d3ad/test/data/nav2_turtlebot.mcap'),
            )),
    Dataset('tf_example_ros2',
            'a ROS 2 bag folder (sqlite3, ~52 s) whose trajectory is a TF chain',
            source='MichaelGrupp/evo test data (test/data/tf_example/)',
            licence='GPL-3.0 (evo)',
            files=(
                DataFile('tf_example_ros2/metadata.yaml', 'ea3dc199802fe9512cedde236b451a48088be33969d7faf8d9779031ce09482e', 1052,
                         'https://raw.githubusercontent.com/MichaelGrupp/evo/26d0953d4da0f0cb56f90ba6269a15e72f69d3ad/test/data/tf_example/metadata.yaml'),
                DataFile('tf_example_ros2/tf_example.db3', '6781a89f3666909db716bf66618ddf6f011de33ce434197ee6ce7fbbefe33566', 106496,
                         'https://raw.githubusercontent.com/MichaelGrupp/evo/26d0953d4da0f0cb56f90ba6269a15e72f69d3ad/test/data/tf_example/tf_example.db3'),
            )),
    Dataset('husky_robot_localization',
            'a ROS 1 bag (~395 s) of a Clearpath Husky with a real IMU, wheel odometry and GPS',
            source='cra-ros-pkg/robot_localization test data (test/test1.bag)',
            licence='BSD-3-Clause',
            files=(
                DataFile('husky_robot_localization.bag', 'fd759aa942a3ef549412ff724d15e7280a347a366996a012cf9079329ec28f4a', 1470835,
                         'https://raw.githubusercontent.com/cra-ros-pkg/robot_localization/1cb953379378d13b3e0935ed73d0c7407bd80543/test/test1.bag'),
            )),
    Dataset('comma2k19_rav4_seg40',
            'one minute of a Toyota RAV4 on a highway: phone-grade IMU, CAN wheel speeds and steering, radar, GNSS, the fused pose',
            source='commaai/comma2k19, Example_1 segment 40',
            licence='MIT',
            files=(
                DataFile('comma2k19_rav4_seg40/global_pose/frame_gps_times', 'e275dc136ac742a58191ca58b103e5361246197a241647bc07b1f928395fc5b4', 19328,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/global_pose/frame_gps_times'),
                DataFile('comma2k19_rav4_seg40/global_pose/frame_orientations', '0eee212a8a1e6cc79978d84217aba068bd3ab9f441a6c1eebb51052ba698d1bb', 38528,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/global_pose/frame_orientations'),
                DataFile('comma2k19_rav4_seg40/global_pose/frame_positions', '85864c9632030f5b6f0a6a8a78f2c9079e7555725d38a28ae029ed5dd4fc9057', 28928,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/global_pose/frame_positions'),
                DataFile('comma2k19_rav4_seg40/global_pose/frame_times', '2bec8428f9302b30a7edef3b86de0bc797c77e6964f404b3d982af1ce4dfcb5d', 9728,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/global_pose/frame_times'),
                DataFile('comma2k19_rav4_seg40/global_pose/frame_velocities', '2e2a3b5d222153b440db70b34ea91e4f0eda661d4b139f16d7b057754cd978c2', 28928,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/global_pose/frame_velocities'),
                DataFile('comma2k19_rav4_seg40/processed_log/CAN/radar/t', 'b41517d6f7081b389b9726208d1b100f052f80ea28fd589562067c53fbb7d3db', 80928,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/processed_log/CAN/radar/t'),
                DataFile('comma2k19_rav4_seg40/processed_log/CAN/radar/value', '4f4dddddf2a890aa4bb8acb83e3523327d3c9c1e6f327ac936754beabca4b6f9', 565728,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/processed_log/CAN/radar/value'),
                DataFile('comma2k19_rav4_seg40/processed_log/CAN/raw_can/address', '581d1e63b955b1218b3c4d667878e2c30f67c979df2c5b046f76c4741be0dd5e', 1083872,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/processed_log/CAN/raw_can/address'),
                DataFile('comma2k19_rav4_seg40/processed_log/CAN/raw_can/data', '04842858174a318e441f6a1e3f38583d52be135327a43de1e51750ce5cea4938', 1083872,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/processed_log/CAN/raw_can/data'),
                DataFile('comma2k19_rav4_seg40/processed_log/CAN/raw_can/src', 'c2ac62cdcb420cd416073f3c30eaaefb51307f2a6ab45e0e4f86eca09c14a935', 1083872,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/processed_log/CAN/raw_can/src'),
                DataFile('comma2k19_rav4_seg40/processed_log/CAN/raw_can/t', '57ee5a9875ac96c08e0e5be94a6e4529fa46bb675cbed1727837f98bcafbba79', 1083872,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/processed_log/CAN/raw_can/t'),
                DataFile('comma2k19_rav4_seg40/processed_log/CAN/speed/t', '53d2a88becfc45f9dcb804f2f78436f2bb6246d80386ff18ded10af679d5d6f3', 39920,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/processed_log/CAN/speed/t'),
                DataFile('comma2k19_rav4_seg40/processed_log/CAN/speed/value', 'ba40ded2c9d2a6d5f98801f5438d0cb5d811ccf1444e3a3f680d7addb707551f', 39920,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/processed_log/CAN/speed/value'),
                DataFile('comma2k19_rav4_seg40/processed_log/CAN/steering_angle/t', 'eb489c74b52cebccd30b803860d70aaafc44801a44b93e72585d602a982dbfc7', 39920,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/processed_log/CAN/steering_angle/t'),
                DataFile('comma2k19_rav4_seg40/processed_log/CAN/steering_angle/value', '6af86fe2fce790c6d3a51d512c625e4766699f473ec13207ea043c08d83a6bea', 39920,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/processed_log/CAN/steering_angle/value'),
                DataFile('comma2k19_rav4_seg40/processed_log/CAN/wheel_speed/t', '53d2a88becfc45f9dcb804f2f78436f2bb6246d80386ff18ded10af679d5d6f3', 39920,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/processed_log/CAN/wheel_speed/t'),
                DataFile('comma2k19_rav4_seg40/processed_log/CAN/wheel_speed/value', '021dd8d0ac5029b34d3d2ddfc53c2654944baf57da4cb45d7ac4b0f995c69d2f', 159296,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/processed_log/CAN/wheel_speed/value'),
                DataFile('comma2k19_rav4_seg40/processed_log/GNSS/live_gnss_qcom/t', 'b6235345d9e056975660a6f8bba19281d2e3a3f40f614a3df9cd319bd7ab528b', 368,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/processed_log/GNSS/live_gnss_qcom/t'),
                DataFile('comma2k19_rav4_seg40/processed_log/GNSS/live_gnss_qcom/value', '1b544d6597976d494c40bddcbc36fc3020f7b00611dee7f4ba452200db0ea428', 1568,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/processed_log/GNSS/live_gnss_qcom/value'),
                DataFile('comma2k19_rav4_seg40/processed_log/GNSS/live_gnss_ublox/t', '238794a8b336a9dc69e6787116d6e8fe4ce9013e4f454ca2bcde010b43011e95', 4760,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/processed_log/GNSS/live_gnss_ublox/t'),
                DataFile('comma2k19_rav4_seg40/processed_log/GNSS/live_gnss_ublox/value', '1136d8819a640d482c06ed6460efdb84a625ddf765ed581b1cf28f030dabfff3', 27920,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/processed_log/GNSS/live_gnss_ublox/value'),
                DataFile('comma2k19_rav4_seg40/processed_log/GNSS/raw_gnss_qcom/t', 'b994638a16fc14c8b5561ce2e50a342490f722eab7c618eb2aec50f51522099e', 4928,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/processed_log/GNSS/raw_gnss_qcom/t'),
                DataFile('comma2k19_rav4_seg40/processed_log/GNSS/raw_gnss_qcom/value', '9c0b72b83ab20617fe774ac3dcf23fe24f597ab2112a3b908d6539149295fdf4', 48128,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/processed_log/GNSS/raw_gnss_qcom/value'),
                DataFile('comma2k19_rav4_seg40/processed_log/GNSS/raw_gnss_ublox/t', '1189929515072dbb3f2b87a4cca60fdf8d62f03ae20e448c6ed62aeb10438562', 73952,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/processed_log/GNSS/raw_gnss_ublox/t'),
                DataFile('comma2k19_rav4_seg40/processed_log/GNSS/raw_gnss_ublox/value', '369d0a467aad1a45b8d7910629c282d15f7d421dd8f33b34bc02ba97ac909576', 738368,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/processed_log/GNSS/raw_gnss_ublox/value'),
                DataFile('comma2k19_rav4_seg40/processed_log/IMU/accelerometer/t', '9df28fe965d5936bb91a020b688e35304ee4b823e388cb814d077b1f934a8558', 50176,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/processed_log/IMU/accelerometer/t'),
                DataFile('comma2k19_rav4_seg40/processed_log/IMU/accelerometer/value', '313949234c212c4f02b0a7c5f1c14173ac2b4dac50297782f50dc4e43fc9579b', 150272,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/processed_log/IMU/accelerometer/value'),
                DataFile('comma2k19_rav4_seg40/processed_log/IMU/gyro/t', '9df28fe965d5936bb91a020b688e35304ee4b823e388cb814d077b1f934a8558', 50176,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/processed_log/IMU/gyro/t'),
                DataFile('comma2k19_rav4_seg40/processed_log/IMU/gyro/value', '7af1d2f8b2ec8b78a0af59dde3a3e40bf8a8d425fb0c96a7fc71cadc0830b50c', 150272,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/processed_log/IMU/gyro/value'),
                DataFile('comma2k19_rav4_seg40/processed_log/IMU/gyro_bias/t', '9df28fe965d5936bb91a020b688e35304ee4b823e388cb814d077b1f934a8558', 50176,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/processed_log/IMU/gyro_bias/t'),
                DataFile('comma2k19_rav4_seg40/processed_log/IMU/gyro_bias/value', '1c3dce954b63d437c16c76d7c1df91ea4c8c58fb8edcc06e5c3de5cee35d9859', 150272,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/processed_log/IMU/gyro_bias/value'),
                DataFile('comma2k19_rav4_seg40/processed_log/IMU/gyro_uncalibrated/t', '9df28fe965d5936bb91a020b688e35304ee4b823e388cb814d077b1f934a8558', 50176,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/processed_log/IMU/gyro_uncalibrated/t'),
                DataFile('comma2k19_rav4_seg40/processed_log/IMU/gyro_uncalibrated/value', '7f0020194f66c06922d3b34890407db3790da5a83a6e6c9c0b0f01d8f19e279c', 150272,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/processed_log/IMU/gyro_uncalibrated/value'),
                DataFile('comma2k19_rav4_seg40/processed_log/IMU/magnetometer/t', '6dd128290581bbd86f6998eb4fc4590c7e1300dab9eafc938ccd72a100b34bbb', 4864,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/processed_log/IMU/magnetometer/t'),
                DataFile('comma2k19_rav4_seg40/processed_log/IMU/magnetometer/value', '3561b468184a4ae695f7fc1e11c96d1032e5bb725b85b29cc05fcbd943ffc901', 14336,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/processed_log/IMU/magnetometer/value'),
                DataFile('comma2k19_rav4_seg40/processed_log/IMU/magnetometer_uncalibrated/t', '6dd128290581bbd86f6998eb4fc4590c7e1300dab9eafc938ccd72a100b34bbb', 4864,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/processed_log/IMU/magnetometer_uncalibrated/t'),
                DataFile('comma2k19_rav4_seg40/processed_log/IMU/magnetometer_uncalibrated/value', '93db4146db941251fc6c8c8cde4351140e7b8b053e906afc010e0830afc6cbc9', 14336,
                         'https://raw.githubusercontent.com/commaai/comma2k19/4c7f1a6e1957745beadc1def0e7225f559b09a2a/Example_1/b0c9d2329ad1606b%7C2018-08-02--08-34-47/40/processed_log/IMU/magnetometer_uncalibrated/value'),
            )),
)}


def default_folder() -> Path:
    """``$EXCITE_DATA_DIR``, else ``../shared/data`` relative to the working directory (where the
    examples, run from the repository's root, read the recordings)."""
    return Path(os.environ.get("EXCITE_DATA_DIR") or Path("..") / "shared" / "data")


def dataset(name: str) -> Dataset:
    try:
        return DATASETS[name]
    except KeyError:
        raise DataError(f"no dataset named {name!r} (datasets: {', '.join(DATASETS)})") from None


def sha256_of(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(CHUNK), b""):
            h.update(block)
    return h.hexdigest()


def check(name: str, folder: Path | None = None) -> list[str]:
    """What is wrong with ``name``'s files in ``folder`` (missing, another size or checksum):
    an empty list when every file is there and intact. Reads only the local files."""
    folder = Path(folder) if folder is not None else default_folder()
    problems = []
    for f in dataset(name).files:
        p = folder / f.path
        if not p.is_file():
            problems.append(f"{p}: missing")
        elif p.stat().st_size != f.size:
            problems.append(f"{p}: {p.stat().st_size} bytes, expected {f.size}")
        elif sha256_of(p) != f.sha256:
            problems.append(f"{p}: SHA-256 differs from the catalogue's")
    return problems


Opener = Callable[[str], BinaryIO]


def _open_url(url: str) -> BinaryIO:
    return urllib.request.urlopen(url, timeout=60)  # noqa: S310 (the catalogue's own https URLs)


def fetch(name: str, folder: Path | None = None, opener: Opener = _open_url,
          progress: Callable[[DataFile], None] | None = None) -> list[Path]:
    """Download the files of ``name`` that ``folder`` lacks (or holds damaged), each checked
    against its size and SHA-256 before it is moved into place; returns the files downloaded.
    A file that cannot be read from its URL or arrives different raises :class:`DataError`
    naming the file and the URL; nothing partial is left behind."""
    folder = Path(folder) if folder is not None else default_folder()
    done = []
    for f in dataset(name).files:
        target = folder / f.path
        if target.is_file() and target.stat().st_size == f.size and sha256_of(target) == f.sha256:
            continue
        if progress is not None:
            progress(f)
        target.parent.mkdir(parents=True, exist_ok=True)
        h, n = hashlib.sha256(), 0
        fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.", suffix=".part")
        try:
            with os.fdopen(fd, "wb") as out:
                try:
                    with opener(f.url) as src:
                        for block in iter(lambda: src.read(CHUNK), b""):
                            n += len(block)
                            if n > f.size:
                                raise DataError(f"{f.path}: {f.url} sends more than the expected {f.size} bytes")
                            h.update(block)
                            out.write(block)
                except OSError as exc:
                    raise DataError(f"{f.path}: cannot download {f.url}: {exc}") from None
            if n != f.size or h.hexdigest() != f.sha256:
                raise DataError(f"{f.path}: {f.url} gave {n} bytes whose SHA-256 is not the catalogue's "
                                f"({f.sha256[:12]}…): the source changed or the download was damaged")
            os.replace(tmp, target)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
        done.append(target)
    return done

