"""Outputs: ROS 2 messages (CDR), MCAP writer, trajectory files, PLY."""
