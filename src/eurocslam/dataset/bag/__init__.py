"""ROS bags and MCAP as input: ROS 1 `.bag`, ROS 2 bag folders (`metadata.yaml`), `.db3` and
`.mcap` files, read with `rosbags` (pure Python, no ROS install). Implements `SequenceSource`.

Opening a bag makes one pass over it: IMU, ground truth and Leica messages are decoded into
arrays (they are small); camera messages only give their stamps (parsed from the first bytes of
the raw message, never decoded), so the stereo pairing is known before any image is decoded.
`frames()` then streams the camera messages a second time and decodes each pair as it completes:
memory does not grow with the length of the bag.

Stamps: header stamps, unless a camera message carries a zero header stamp, in which case both
cameras use the bag's log (receive) time; `stamp_source` and `notes` say which.

Calibration (cameras and IMU; bags carry none): a given `StereoRig`, else a folder of
`sensor.yaml` files (`--calib DIR`), else the `sensor.yaml` files attached to an MCAP (what
`eurocslam convert` writes), else the built-in EuRoC calibration with a note; a bag whose images
do not have the calibrated size is an error.

Ground truth: `geometry_msgs/PoseStamped` (our MCAPs' `/groundtruth/pose`), `nav_msgs/Odometry`
or `PoseWithCovarianceStamped` give the body pose directly. `geometry_msgs/TransformStamped`
(EuRoC's raw Vicon, `/vicon/firefly_sbx/firefly_sbx`) is the pose of the Vicon marker frame: it
is moved to the body (IMU) frame with `vicon0/sensor.yaml`'s `T_BS` from `--calib DIR` when
present, else with EuRoC's published vicon0 `T_BS` (V1/V2 rooms). That raw Vicon pose is not the
ASL `state_groundtruth_estimate0` (no time-offset estimation, no velocity or biases).

Modules: `topics` (which topic plays which role), `files` (bag paths, opening, MCAP attachments),
`messages` (stamps, numbers and images from messages), `calibration` (a bag's rig, Vicon
extrinsic), `pairing` (stereo pairs), `reader` (`BagSequence`), `writer` (`write_rosbag`). The
checks on a bag are in `eurocslam.dataset.doctor.bag_checks`.
"""
