"""Load the inputs of `eval`: estimates and ground truth from files, folders and MCAPs.

Estimate inputs:

* a TUM or EuRoC CSV file (format detected from the content, `trajectory_io`);
* a run output folder: `trajectory_final.tum` (smoothed, "final") and `trajectory_online.tum`
  (causal, per frame, "online"); falls back to `run.mcap` (`/slam/path_final`, `/slam/pose`)
  when neither file exists;
* an MCAP (detected from its magic bytes): a `geometry_msgs/PoseStamped`,
  `PoseWithCovarianceStamped`, `nav_msgs/Odometry`, `nav_msgs/Path` (last message) or
  `tf2_msgs/TFMessage` topic (`child_frame` picks the transform, as in `--child-frame`).

Ground-truth inputs: an EuRoC sequence folder (`mav0/state_groundtruth_estimate0/data.csv`), a
TUM-VI one (`mav0/mocap0/data.csv`: the IMU's pose where the motion-capture room sees it), that
`data.csv`, a TUM file, an MCAP topic (default `/groundtruth/pose`), or KITTI's `poses/NN.txt`
(or its sequence folder `sequences/NN`), stamped by the sequence's `times.txt` (`kitti_gt`).

Stamps come from `header.stamp` (not the MCAP log time).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from eurocslam.dataset.kitti_files import is_kitti_sequence, looks_like_kitti_poses
from eurocslam.errors import EurocSlamError, EvalError
from eurocslam.eval.kitti_gt import kitti_groundtruth
from eurocslam.timebase import stamp_ns
from eurocslam.trajectory import Trajectory
from eurocslam.trajectory_io import TimeUnit, count_repeated_stamps, read_trajectory

MCAP_MAGIC = b"\x89MCAP0\r\n"
DEFAULT_EST_TOPIC = "/slam/pose"
DEFAULT_GT_TOPIC = "/groundtruth/pose"
RUN_FINAL = "trajectory_final.tum"
RUN_ONLINE = "trajectory_online.tum"
RUN_MCAP = "run.mcap"
FINAL_TOPIC = "/slam/path_final"  # nav_msgs/Path written by `run` at the end


def _mcap_label(topic: str) -> str:
    """What an eurocslam run's topic holds; other topics are just 'estimate'."""
    return {
        DEFAULT_EST_TOPIC: "online (causal)",
        FINAL_TOPIC: "final (smoothed)",
    }.get(topic, "estimate")


POSE_TYPES = {
    "geometry_msgs/msg/PoseStamped": "pose",
    "geometry_msgs/PoseStamped": "pose",
    "geometry_msgs/msg/PoseWithCovarianceStamped": "pose_cov",
    "geometry_msgs/PoseWithCovarianceStamped": "pose_cov",
    "nav_msgs/msg/Odometry": "odom",
    "nav_msgs/Odometry": "odom",
    "nav_msgs/msg/Path": "path",
    "nav_msgs/Path": "path",
    "tf2_msgs/msg/TFMessage": "tf",
    "tf2_msgs/TFMessage": "tf",
    "geometry_msgs/msg/TransformStamped": "tfs",
    "geometry_msgs/TransformStamped": "tfs",
}


@dataclass(frozen=True)
class Loaded:
    """A trajectory with what it is: `label` says final/online/ground truth, `source` where."""

    traj: Trajectory
    label: str
    source: str
    notes: list[str] = field(default_factory=list)


def is_mcap(path: Path) -> bool:
    try:
        with open(path, "rb") as f:
            return f.read(8) == MCAP_MAGIC
    except OSError:
        return False


def _notes(traj: Trajectory) -> list[str]:
    out = []
    n = count_repeated_stamps(traj)
    if n:
        out.append(f"{traj.name}: {n} pose(s) repeat the previous timestamp (kept, as evo does)")
    if len(traj) > 1 and np.all(np.abs(traj.q_wxyz[:, 0]) == 1.0):
        out.append(
            f"{traj.name}: every orientation is identity (position-only data such as leica0?); "
            "rotation errors and RPE against it are not meaningful, ATE translation is"
        )
    return out


# ---------------------------------------------------------------------------------------------
# MCAP


def _stamp(header: Any) -> int:
    return stamp_ns(header.stamp.sec, header.stamp.nanosec)


def _pose_row(pose: Any) -> list[float]:
    p, q = pose.position, pose.orientation
    return [p.x, p.y, p.z, q.w, q.x, q.y, q.z]


def _tf_row(tf: Any) -> list[float]:
    p, q = tf.translation, tf.rotation
    return [p.x, p.y, p.z, q.w, q.x, q.y, q.z]


def _stream_records(path: Path) -> Iterator[Any]:
    """Records of an MCAP read front to back; stops quietly where a truncated file ends."""
    from mcap.stream_reader import StreamReader

    with open(path, "rb") as f:
        it = StreamReader(f).records
        while True:
            try:
                rec = next(it)
            except StopIteration:
                return
            except Exception:  # truncated / unfinished file: keep what was read
                return
            yield rec


def _scan(path: Path) -> tuple[dict[str, str], bool]:
    """({topic: schema name}, indexed). Falls back to a front-to-back scan for MCAPs without a
    summary (an interrupted run's `run.mcap.partial`)."""
    from mcap.reader import make_reader
    from mcap.records import Channel, Schema

    try:
        with open(path, "rb") as f:
            summary = make_reader(f).get_summary()
    except OSError as e:
        raise EvalError(f"{path}: cannot read: {e}") from None
    except Exception:  # mcap raises several types for corrupt or unfinished files
        summary = None
    if summary is not None:
        return {
            ch.topic: summary.schemas[ch.schema_id].name if ch.schema_id in summary.schemas else "?"
            for ch in summary.channels.values()
        }, True
    schemas: dict[int, str] = {}
    topics: dict[str, str] = {}
    for rec in _stream_records(path):
        if isinstance(rec, Schema):
            schemas[rec.id] = rec.name
        elif isinstance(rec, Channel):
            topics[rec.topic] = schemas.get(rec.schema_id, "?")
    if not topics:
        raise EvalError(f"{path}: cannot read MCAP: no channels (empty or corrupt file)")
    return topics, False


def mcap_topics(path: Path) -> dict[str, str]:
    """{topic: schema name} of an MCAP (complete or truncated)."""
    return _scan(path)[0]


def _decoded(path: Path, topic: str, indexed: bool) -> Iterator[Any]:
    """Decoded ROS 2 messages of one topic, in file order."""
    from mcap_ros2.decoder import DecoderFactory

    if indexed:
        from mcap.reader import make_reader

        with open(path, "rb") as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            for _, _, _, msg in reader.iter_decoded_messages(topics=[topic]):
                yield msg
        return
    from mcap.records import Channel, Message, Schema

    factory = DecoderFactory()
    schemas: dict[int, Schema] = {}
    decoders: dict[int, object] = {}
    for rec in _stream_records(path):
        if isinstance(rec, Schema):
            schemas[rec.id] = rec
        elif isinstance(rec, Channel) and rec.topic == topic:
            decoders[rec.id] = factory.decoder_for(rec.message_encoding, schemas.get(rec.schema_id))
        elif isinstance(rec, Message) and rec.channel_id in decoders:
            dec = decoders[rec.channel_id]
            if dec is None:
                raise EvalError(f"{path}: topic '{topic}' is not CDR-encoded ROS 2 data")
            yield dec(rec.data)  # type: ignore[operator]


def read_mcap_trajectory(
    path: Path | str,
    topic: str,
    child_frame: str | None = None,
    name: str | None = None,
    notes: list[str] | None = None,
) -> Trajectory:
    """Poses of one topic of a ROS 2 MCAP, sorted by header stamp (repeats keep the last).

    An MCAP without summary (interrupted run) is read up to where it ends; a note says so.
    """
    path = Path(path)
    topics, indexed = _scan(path)
    if not indexed and notes is not None:
        notes.append(f"{path}: no summary/index (unfinished file?); read up to where it ends")
    if topic not in topics:
        usable = [f"{t} ({s})" for t, s in sorted(topics.items()) if s in POSE_TYPES]
        raise EvalError(
            f"{path}: no topic '{topic}'; pose topics in the file: "
            + (", ".join(usable) if usable else "none")
        )
    kind = POSE_TYPES.get(topics[topic])
    if kind is None:
        raise EvalError(
            f"{path}: topic '{topic}' is {topics[topic]}; expected PoseStamped, "
            "PoseWithCovarianceStamped, Odometry, Path or TFMessage"
        )
    t: list[int] = []
    rows: list[list[float]] = []
    children: dict[str, int] = {}
    try:
        for msg in _decoded(path, topic, indexed):
            if kind == "pose":
                t.append(_stamp(msg.header))
                rows.append(_pose_row(msg.pose))
            elif kind in ("pose_cov", "odom"):
                t.append(_stamp(msg.header))
                rows.append(_pose_row(msg.pose.pose))
            elif kind == "path":
                t = [_stamp(ps.header) for ps in msg.poses]
                rows = [_pose_row(ps.pose) for ps in msg.poses]
            else:
                tfs = msg.transforms if kind == "tf" else [msg]
                for tf in tfs:
                    children[tf.child_frame_id] = children.get(tf.child_frame_id, 0) + 1
                    if child_frame is None or tf.child_frame_id == child_frame:
                        t.append(_stamp(tf.header))
                        rows.append(_tf_row(tf.transform))
    except EvalError:
        raise
    except Exception as e:
        raise EvalError(f"{path}: cannot decode topic '{topic}': {e}") from None
    if kind in ("tf", "tfs"):
        if child_frame is None and len(children) > 1:
            raise EvalError(
                f"{path}: topic '{topic}' holds transforms to several child frames "
                f"({', '.join(sorted(children))}); choose one with --child-frame"
            )
        if child_frame is not None and child_frame not in children:
            raise EvalError(
                f"{path}: topic '{topic}' has no transform with child frame '{child_frame}' "
                f"(child frames: {', '.join(sorted(children)) or 'none'})"
            )
    if not t:
        raise EvalError(f"{path}: topic '{topic}' has no messages")
    t_ns = np.asarray(t, dtype=np.int64)
    v = np.asarray(rows, dtype=np.float64)
    if not np.all(np.isfinite(v)):
        raise EvalError(f"{path}: topic '{topic}' holds non-finite poses")
    if np.all(t_ns == 0):
        raise EvalError(f"{path}: topic '{topic}' has zero header stamps")
    order = np.argsort(t_ns, kind="stable")
    t_ns, v = t_ns[order], v[order]
    keep = np.concatenate([t_ns[1:] != t_ns[:-1], [True]])  # last of equal stamps
    t_ns, v = t_ns[keep], v[keep]
    qn = np.linalg.norm(v[:, 3:7], axis=1)
    if np.any(qn < 1e-9):
        raise EvalError(f"{path}: topic '{topic}' holds a zero-norm quaternion")
    return Trajectory(
        t_ns,
        np.ascontiguousarray(v[:, :3]),
        v[:, 3:7] / qn[:, None],
        None,
        name or f"{path.name}:{topic}",
    )


# ---------------------------------------------------------------------------------------------
# inputs


def load_estimates(
    path: Path | str,
    topic: str | None = None,
    child_frame: str | None = None,
    time_unit: TimeUnit = "auto",
    which: str = "both",
) -> list[Loaded]:
    """Estimates to evaluate. A run folder yields final and/or online (`which`: final, online,
    both); a file or MCAP yields one."""
    path = Path(path)
    if not path.exists():
        raise EvalError(f"{path}: no such file or folder")
    if path.is_dir():
        out = []
        final, online = path / RUN_FINAL, path / RUN_ONLINE
        if which in ("final", "both") and final.exists():
            t = read_trajectory(final, time_unit=time_unit, name=str(final))
            out.append(Loaded(t, "final (smoothed)", str(final), _notes(t)))
        if which in ("online", "both") and online.exists():
            t = read_trajectory(online, time_unit=time_unit, name=str(online))
            out.append(Loaded(t, "online (causal)", str(online), _notes(t)))
        if not out and (path / RUN_MCAP).exists():
            mc = path / RUN_MCAP
            if topic:
                t = read_mcap_trajectory(mc, topic, child_frame, f"{mc}:{topic}")
                return [Loaded(t, _mcap_label(topic), f"{mc}:{topic}")]
            have = mcap_topics(mc)
            for tp, kind in ((FINAL_TOPIC, "final"), (DEFAULT_EST_TOPIC, "online")):
                if tp in have and which in (kind, "both"):
                    t = read_mcap_trajectory(mc, tp, None, f"{mc}:{tp}")
                    out.append(Loaded(t, _mcap_label(tp), f"{mc}:{tp}"))
        if not out:
            wanted = {"final": RUN_FINAL, "online": RUN_ONLINE}.get(
                which, f"{RUN_FINAL} or {RUN_ONLINE}"
            )
            raise EvalError(
                f"{path}: not a run output folder with an estimate (expected {wanted}"
                f"{'' if which == 'final' else ' or ' + RUN_MCAP})"
            )
        return out
    if is_mcap(path):
        tp = topic or DEFAULT_EST_TOPIC
        notes: list[str] = []
        t = read_mcap_trajectory(path, tp, child_frame, f"{path}:{tp}", notes)
        return [Loaded(t, _mcap_label(tp), f"{path}:{tp}", notes)]
    t = read_trajectory(path, time_unit=time_unit, name=str(path))
    return [Loaded(t, "estimate", str(path), _notes(t))]


def groundtruth_csv_of(folder: Path) -> Path | None:
    """The ground truth of an EuRoC sequence folder (or its mav0): `state_groundtruth_estimate0`,
    else TUM-VI's `mocap0`."""
    for cand in (
        *(
            base / gt / "data.csv"
            for gt in ("state_groundtruth_estimate0", "mocap0")
            for base in (folder / "mav0", folder)
        ),
        folder / "data.csv",
    ):
        if cand.is_file():
            return cand
    return None


def load_groundtruth(
    path: Path | str,
    topic: str | None = None,
    child_frame: str | None = None,
    time_unit: TimeUnit = "auto",
) -> Loaded:
    """The reference trajectory (see module docstring)."""
    path = Path(path)
    if not path.exists():
        raise EvalError(f"{path}: no such file or folder")
    if (path.is_dir() and is_kitti_sequence(path)) or (
        path.is_file() and looks_like_kitti_poses(path)
    ):
        traj, poses, times = kitti_groundtruth(path)
        note = f"{poses}: KITTI poses (T_world_cam0), stamped by {times}"
        return Loaded(traj, "ground truth", str(poses), [note, *_notes(traj)])
    if path.is_dir():
        csv = groundtruth_csv_of(path)
        if csv is None:
            mc = path / RUN_MCAP
            if mc.exists():
                return load_groundtruth(mc, topic, child_frame, time_unit)
            raise EvalError(
                f"{path}: no ground truth in this folder (expected "
                "mav0/state_groundtruth_estimate0/data.csv or TUM-VI's mav0/mocap0/data.csv)"
            )
        path = csv
    if is_mcap(path):
        tp = topic or DEFAULT_GT_TOPIC
        notes: list[str] = []
        t = read_mcap_trajectory(path, tp, child_frame, f"{path}:{tp}", notes)
        return Loaded(t, "ground truth", f"{path}:{tp}", notes)
    try:
        t = read_trajectory(path, time_unit=time_unit, name=str(path))
    except EurocSlamError as e:  # the reader's hint names the estimate's option
        msg = str(e)
        if "pass --time-unit " not in msg:
            raise
        raise type(e)(msg.replace("pass --time-unit ", "pass --gt-time-unit ")) from None
    return Loaded(t, "ground truth", str(path), _notes(t))


def groundtruth_from_estimate_source(path: Path | str) -> Path | None:
    """An MCAP beside/behind the estimate that carries `/groundtruth/pose` (for `eval RUN_DIR`
    without a ground-truth argument)."""
    path = Path(path)
    mc = path / RUN_MCAP if path.is_dir() else path
    if mc.is_file() and is_mcap(mc) and DEFAULT_GT_TOPIC in mcap_topics(mc):
        return mc
    return None
