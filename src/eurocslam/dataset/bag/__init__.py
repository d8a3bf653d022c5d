"""ROS bags and MCAP as input: ROS 1 `.bag`, ROS 2 bag folders (`metadata.yaml`), `.db3` and
`.mcap` files, read with `rosbags` (pure Python, no ROS install). Implements `SequenceSource`.

Opening a bag makes one pass over it: IMU, ground truth and Leica messages are decoded into
arrays (they are small); camera messages only give their stamps (parsed from the first bytes of
the raw message, never decoded), so the stereo pairing is known before any image is decoded.
`frames()` then streams the camera messages a second time and decodes each pair as it completes:
memory does not grow with the length of the bag.

Stamps: header stamps, unless a camera message carries a zero header stamp, in which case both
cameras use the bag's log (receive) time; `stamp_source` and `notes` say which.

Calibration: a given `StereoRig`, else a folder of `sensor.yaml` files (`--calib DIR`), else the
`sensor.yaml` files attached to an MCAP (what `eurocslam convert` writes), else the bag's own
`sensor_msgs/CameraInfo` and `/tf_static` (a robot's bag: `bag_rig`), else the built-in EuRoC
calibration with a note; a bag whose images do not have the calibrated size is an error. IMU
noise figures (bags carry none) come from outside (`dataset/imu_noise.py`).

Topics: EuRoC's names by default, `--topic ROLE=TOPIC`, else found by message type
(`discovery`): a realsense-ros bag's infra pair, CameraInfo and IMU, also as separate
accelerometer and gyroscope streams (united on the gyro's stamps, `imu_union`).

Ground truth: `geometry_msgs/PoseStamped` (our MCAPs' `/groundtruth/pose`), `nav_msgs/Odometry`
or `PoseWithCovarianceStamped` give the body pose directly. `geometry_msgs/TransformStamped`
(EuRoC's raw Vicon, `/vicon/firefly_sbx/firefly_sbx`) is the pose of the Vicon marker frame: it
is moved to the body (IMU) frame with `vicon0/sensor.yaml`'s `T_BS` from `--calib DIR` when
present, else with EuRoC's published vicon0 `T_BS` (V1/V2 rooms). That raw Vicon pose is not the
ASL `state_groundtruth_estimate0` (no time-offset estimation, no velocity or biases).

Modules: `topics` (the roles and their message types), `discovery` and `roles` (which topic
plays which role), `files` (bag paths, opening, MCAP attachments), `messages` (stamps, numbers
and images from messages), `static` (tf tree, CameraInfo and frame ids read before the index
pass), `tf_tree`, `camera_info`, `bag_rig` (the rig from them), `calibration` (the order of the
sources, IMU noise, Vicon extrinsic), `stats` and `arrays` (what the index pass builds),
`imu_union`, `pairing` (stereo pairs), `reader` (`BagSequence`) and `writer` (`write_rosbag`,
EuRoC's topics; a robot's, realsense-ros style, is written by `eurocslam.synth.robot_bag`). The
checks on a bag are in `eurocslam.dataset.doctor.bag_checks`.
"""
