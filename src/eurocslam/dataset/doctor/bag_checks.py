"""The doctor on a ROS bag / MCAP input: topics and counts, rates and gaps against the
calibration, stamp order and duplicates, header stamp vs log time, stereo pairing and time
overlap, and where the calibration came from (a bag's CameraInfo and `/tf_static`: each camera's
model, frame and place on the body, the baseline; a bad CameraInfo or tf tree is the error the
reader raises), as `Finding`s (check "bag") of the same report as an ASL folder's."""

from __future__ import annotations

import time
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from eurocslam.dataset.bag.camera_info import check_camera_info, is_rectified
from eurocslam.dataset.bag.reader import BagSequence
from eurocslam.dataset.bag.topics import IMU_ROLES, INFO_ROLES, REQUIRED_ROLES, ROLES, TopicMap
from eurocslam.dataset.calib import StereoRig
from eurocslam.dataset.doctor.report import (
    ERROR,
    INFO,
    SEVERITY_RANK,
    WARNING,
    DoctorReport,
    Finding,
)
from eurocslam.dataset.imu_noise import NoiseFigures
from eurocslam.dataset.types import I64
from eurocslam.errors import EurocSlamError
from eurocslam.timebase import NS_PER_S

# notes of the reader that deserve a warning (the rest are informational)
WARNING_NOTES = (
    "zero header stamp",
    "carries no figures",  # IMU noise: defaults used
    "so P is used",  # P and /tf_static disagree
    "lever arm is ignored",
    "taken as aligned",
)


def _periods(t: I64) -> I64:
    ts = np.unique(t)
    return np.diff(ts) if ts.size > 1 else np.zeros(0, dtype=np.int64)


def check_bag_sequence(seq: BagSequence, file: str | None = None) -> list[Finding]:
    """Checks on an opened bag: topics and message counts, rates against the calibration, gaps,
    stamp order and duplicates, header stamp vs log time, stereo pairing, time overlap of the
    cameras with the IMU and ground truth. In the order they were made (not sorted); each names
    `file` (default: the bag's name)."""
    out: list[Finding] = []
    file = file or seq.path.name

    def add(level: str, msg: str) -> None:
        out.append(Finding(level, "bag", msg, file))

    add(INFO, f"{seq.kind}: {seq.path}")
    add(INFO, f"calibration: {seq.calib_source}")
    out.extend(Finding(INFO, "bag", line, file) for line in _calibration_lines(seq))
    for note in seq.notes:
        add(WARNING if any(m in note for m in WARNING_NOTES) else INFO, note)
    for role in ROLES:
        if role in INFO_ROLES.values():
            continue  # the calibration lines above
        st = seq.stats.get(role)
        if st is None:
            if role in IMU_ROLES:  # stereo-only, or the other IMU form: the notes say which
                continue
            # a robot's bag (calibrated by its CameraInfo) has no ground truth as a rule
            robot = seq.calib_source.startswith("CameraInfo")
            level = INFO if role == "leica" or robot else WARNING
            add(level, f"{role}: no topic (looked for {', '.join(seq.topic_map.candidates(role))})")
            continue
        lt = st.log_array()
        span = float(lt.max() - lt.min()) / NS_PER_S if st.count else 0.0
        add(INFO, f"{role}: {st.topic} [{st.msgtype}] {st.count} messages over {span:.1f} s")
        if st.count == 0:
            required = role in REQUIRED_ROLES or role == "imu"  # an empty IMU topic is refused
            add(ERROR if required else WARNING, f"{st.topic}: no messages")
            continue
        h = st.header_array()
        nz = h[h != 0]
        back = int(np.count_nonzero(np.diff(nz) < 0)) if nz.size > 1 else 0
        if back:
            add(WARNING, f"{st.topic}: header stamps go backwards {back} times (in bag order)")
        dup = int(nz.size - np.unique(nz).size)
        if dup:
            add(WARNING, f"{st.topic}: {dup} duplicate header stamps")
        if nz.size:
            off = (st.log_array()[h != 0] - nz) / 1e6
            med = float(np.median(off))
            level = WARNING if abs(med) > 1000.0 else INFO
            add(level, f"{st.topic}: log time - header stamp: median {med:.3f} ms, "
                f"max {float(np.max(np.abs(off))):.3f} ms")  # fmt: skip
    # rates and gaps against the calibration
    imu_rate = seq.rig.imu.rate_hz if seq.rig.imu is not None else 0.0
    nominal = {
        "cam0": seq.rig.cam0.rate_hz,
        "cam1": seq.rig.cam1.rate_hz,
        "imu": imu_rate,
        "gyro": imu_rate,  # the united stream is on the gyro's stamps
        "accel": 0.0,  # its own rate: gaps measured against it
    }
    for role, rate in nominal.items():
        st = seq.stats.get(role)
        if st is None or st.count < 3:
            continue
        if role in ("cam0", "cam1"):
            t = seq.camera_stamps(role)
        elif role == "imu":
            t = seq.imu.t_ns
        else:
            t = st.header_array()
        dt = _periods(t)
        if dt.size == 0:
            continue
        med = float(np.median(dt)) / NS_PER_S
        measured = 1.0 / med if med > 0 else float("inf")
        if rate > 0 and abs(measured - rate) / rate > 0.1:
            add(WARNING, f"{st.topic}: rate {measured:.1f} Hz, calibration says {rate:g} Hz")
        elif rate > 0:
            add(INFO, f"{st.topic}: rate {measured:.1f} Hz (calibration {rate:g} Hz)")
        else:
            add(INFO, f"{st.topic}: rate {measured:.1f} Hz")
        period = 1.0 / rate if rate > 0 else med
        gaps = dt[dt > 2.5 * period * NS_PER_S]
        if gaps.size:
            add(WARNING, f"{st.topic}: {gaps.size} gaps longer than 2.5 periods "
                f"(longest {float(gaps.max()) / NS_PER_S:.3f} s)")  # fmt: skip
    # stereo pairing
    n_pairs = sum(1 for e in seq.frame_index if e.has_left and e.has_right)
    only0 = sum(1 for e in seq.frame_index if e.has_left and not e.has_right)
    only1 = sum(1 for e in seq.frame_index if e.has_right and not e.has_left)
    add(INFO, f"stereo pairs: {n_pairs} joined on {seq.stamp_source}")
    if n_pairs == 0:
        add(ERROR, "no stereo pair: cam0 and cam1 share no timestamp")
    if only0 or only1:
        add(WARNING, f"unpaired frames: {only0} in cam0 only, {only1} in cam1 only")
    for role, info in seq.image_info.items():
        add(INFO, f"{role}: {info.width}x{info.height} {info.encoding}")
    # time overlap
    ft = seq.frame_times
    if ft.size:
        f0, f1 = int(ft[0]), int(ft[-1])
        i0, i1 = (int(seq.imu.t_ns[0]), int(seq.imu.t_ns[-1])) if len(seq.imu) else (f0, f1)
        if i1 < f0 or i0 > f1:
            add(ERROR, "the IMU and the cameras do not overlap in time")
        elif i0 > f0 or i1 < f1:
            add(WARNING, "the IMU covers the cameras only partly (starts "
                f"{(i0 - f0) / NS_PER_S:+.3f} s, ends {(i1 - f1) / NS_PER_S:+.3f} s from the "
                "first/last frame)")  # fmt: skip
        gt = seq.groundtruth
        if gt is not None and len(gt):
            g0, g1 = int(gt.t_ns[0]), int(gt.t_ns[-1])
            if g1 < f0 or g0 > f1:
                add(WARNING, "the ground truth does not overlap the cameras in time")
    for line in seq.skips.lines():
        add(WARNING, line)
    return out


def _calibration_lines(seq: BagSequence) -> list[str]:
    """Where each camera's calibration came from in the bag: CameraInfo topic, model, frame,
    its place on the body; the baseline."""
    out = []
    rig = seq.rig
    for role in ("cam0", "cam1"):
        info = seq.static.camera_infos.get(role)
        cam = getattr(rig, role)
        if info is None:
            continue
        frame = seq.static.frame_ids.get(role) or info.frame_id or "(no frame_id)"
        p = cam.T_body_cam[:3, 3]
        if not seq.calib_source.startswith("CameraInfo"):
            out.append(f"{role}: {info.topic} present, not used (calibration from elsewhere)")
            continue
        rect = is_rectified(check_camera_info(info), seq.stats[role].topic)
        how = "rectified: P's pinhole" if rect else "raw: K and D"
        out.append(
            f"{role}: {info.topic}: {info.width}x{info.height}, distortion "
            f"'{info.distortion_model or 'none'}' ({len(info.D)} coefficients), {how}, frame "
            f"'{frame}', at ({p[0]:.4f}, {p[1]:.4f}, {p[2]:.4f}) m in the body frame"
        )
    if seq.static.camera_infos:
        out.append(f"stereo baseline {rig.baseline:.4f} m")
    if len(seq.static.tf):
        out.append(f"/tf_static: {len(seq.static.tf.frames)} frames")
    return out


def check_bag(
    path: Path | str,
    rig: StereoRig | None = None,
    *,
    calib: Path | str | None = None,
    topics: TopicMap | Mapping[str, str] | None = None,
    imu_noise: NoiseFigures | None = None,
) -> list[Finding]:
    """`check_bag_sequence` on a path; a bag that cannot be opened (or whose calibration cannot
    be one: a bad CameraInfo or tf tree) gives one error finding."""
    try:
        seq = BagSequence(path, rig, calib=calib, topics=topics, imu_noise=imu_noise)
    except EurocSlamError as e:
        return [Finding(ERROR, "bag", str(e), Path(path).name)]
    return check_bag_sequence(seq, Path(path).name)


def diagnose_bag(
    path: Path | str,
    *,
    calib: Path | str | None = None,
    topics: TopicMap | Mapping[str, str] | None = None,
    imu_noise: NoiseFigures | None = None,
) -> DoctorReport:
    """The doctor on a ROS bag / MCAP input: `check_bag`'s findings as a report (errors first)."""
    t0 = time.perf_counter()
    found = check_bag(path, calib=calib, topics=topics, imu_noise=imu_noise)
    return DoctorReport(
        sequence=str(path),
        mav0=None,
        findings=tuple(sorted(found, key=lambda f: SEVERITY_RANK[f.severity])),
        streams=(),
        stereo_pairs=0,
        image_headers_read=0,
        images_decoded=0,
        elapsed_s=time.perf_counter() - t0,
    )
