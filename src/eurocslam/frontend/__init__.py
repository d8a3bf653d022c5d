"""Stereo visual frontend: ORB features, stereo matching, tracking, keyframes."""
