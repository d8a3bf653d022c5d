"""eurocslam: stereo-inertial SLAM for EuRoC MAV data, with ROS 2 MCAP output and no ROS install.

The library reports notes and progress through `logging` (loggers under `eurocslam`); it prints
nothing itself. The command line (`eurocslam.cli`) shows them on stderr as plain lines.
"""

import logging

__version__ = "0.1.0"

logging.getLogger(__name__).addHandler(logging.NullHandler())
