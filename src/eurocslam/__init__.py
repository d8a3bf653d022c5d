"""eurocslam: stereo-inertial SLAM for EuRoC MAV data, with ROS 2 MCAP output and no ROS install."""

__version__ = "0.1.0"
