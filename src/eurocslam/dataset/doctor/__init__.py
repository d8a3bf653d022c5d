"""`eurocslam doctor`: check an EuRoC ASL sequence folder (or a ROS bag / MCAP) before trusting it.

Every problem becomes a `Finding` (error, warning or info) naming the file, line and key; the
doctor itself never raises on bad input: a reader `DatasetError`, an unreadable file or a bug in
one check becomes an error finding and the other checks still run.

Severity follows what the reader does with the problem:
  error   the reader refuses the sequence, or its output would be wrong (no stereo pairs, image
          size different from the calibration, seconds mixed with nanoseconds, broken calibration)
  warning the reader copes (skips and counts, sorts, converts) but the data is not as it should be
          (missing images, gaps, duplicates, partial time overlap, implausible calibration)
  info    worth knowing, harmless (no ground truth, a byte-order mark, blank lines)

Fast on full sequences: every image's PNG header (IHDR: size, bit depth, colour type) and its last
12 bytes (the IEND chunk: truncation) are read; only an evenly spaced sample is fully decoded
(`full=True` decodes all of them).

Modules: `report` (the `Finding` type, `DoctorReport`, text and JSON), `csv_scan` (tolerant CSV
scanning), `image_checks` (PNG headers, decoded sample), `asl_checks` (`diagnose(path)`: an ASL
folder), `bag_checks` (`diagnose_bag(path)`: a bag or MCAP, same report and finding type).
"""
