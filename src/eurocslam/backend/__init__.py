"""Stereo-inertial backend: IMU preintegration, initialisation, GTSAM smoother, health."""
