"""One exception root; one subclass per subsystem. Messages name the file, row or key at fault.

The CLI maps every `EurocSlamError` to a one-line message on stderr and a non-zero exit code;
anything else is a bug and is reported as such.
"""

from __future__ import annotations


class EurocSlamError(Exception):
    """Root of every error eurocslam raises on purpose (bad input, bad config, I/O)."""

    exit_code: int = 2


class DatasetError(EurocSlamError):
    """A sequence folder, CSV, image or sensor.yaml is missing or malformed."""


class CalibrationError(DatasetError):
    """A sensor.yaml is missing a key or holds values that cannot be a calibration."""


class ConfigError(EurocSlamError):
    """A configuration file has an unknown key, a missing key or a bad value."""


class OutputError(EurocSlamError):
    """An output (MCAP, trajectory file, plot) could not be written."""


class EvalError(EurocSlamError):
    """Trajectories could not be read, associated or aligned."""


class SlamError(EurocSlamError):
    """The estimator hit a state it cannot recover from."""


class PlaceRecognitionError(EurocSlamError):
    """Place recognition (vocabulary, keyframe database) cannot work with what it was given."""


class VocabularyError(PlaceRecognitionError):
    """A vocabulary file is missing, corrupt, truncated, of another kind or another version."""


class MapError(EurocSlamError):
    """A saved map (`OUT/map`) is missing, corrupt, of another version, or was built with another
    rig or vocabulary than the run that wants to use it."""
