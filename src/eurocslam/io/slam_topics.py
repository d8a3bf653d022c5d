"""The SLAM side of `OUT/run.mcap`: a pipeline observer writing the estimate next to the sensor
streams, in log-time order, in the same pass.

Per frame (after `SensorStreams.write_frame` has written the IMU, ground truth and images up to
the frame's time):

| topic | type | content |
|---|---|---|
| /tf | tf2_msgs/TFMessage | world -> body (online estimate) |
| /slam/pose | geometry_msgs/PoseStamped | online pose of body in world |
| /slam/drone | visualization_msgs/MarkerArray | the Firefly model on `body` |
| /slam/features | visualization_msgs/ImageMarker | features on cam0 (green: tracked) |
| /slam/state | std_msgs/String | INIT / TRACKING / LOST |
| /slam/stats | std_msgs/Float64MultiArray | state, counts, segment (`STATS_LABELS`) |
| /slam/imu_bias | std_msgs/Float64MultiArray | gyro bias xyz [rad/s], accel bias xyz [m/s^2] (*) |
| /slam/velocity | std_msgs/Float64MultiArray | world velocity xyz [m/s], speed (*) |
| /slam/position_error | std_msgs/Float64MultiArray | estimate - aligned GT: xyz, norm [m] |
| /groundtruth/drone | visualization_msgs/MarkerArray | the Firefly on `gt_body` (green) |
| /slam/places | visualization_msgs/MarkerArray | loops, relocalizations, merges, refused loops |

(*) stereo-inertial runs only: a visual-only run estimates neither.

A frame left out by `frontend.track_every` has no /slam/features and no /slam/stats (nothing
was counted; plots join the tracked frames).

Per keyframe: /slam/path (nav_msgs/Path of the segment's smoothed keyframes) and
/slam/landmarks (sensor_msgs/PointCloud2 of the smoother's active map, in `world`).
At the end: /slam/landmarks with the final (batch-optimised) map, /slam/path_final with the
final trajectory.

Ground-truth overlay: the sensor streams write the ground truth in its own tree
(`gt_world -> gt_body`). At the first estimated pose that the ground truth covers, a
`world -> gt_world` transform is published on /tf_static that puts the ground truth's body on the
estimate there, matching position and yaw only (gravity is shared), so drift stays visible in
Foxglove as two diverging trajectories; again when the estimate moves to another world frame (a
reset, or the merge into an earlier map's frame).
"""

from __future__ import annotations

import numpy as np

from eurocslam.config import OutputConfig
from eurocslam.dataset.types import GroundTruth, StereoFrame
from eurocslam.geometry import F64, inv_T, make_T, quat_wxyz_to_rot, rot_z, wxyz_to_xyzw
from eurocslam.io import drone, ros2
from eurocslam.io.sensor_streams import FRAME_GT_BODY, FRAME_GT_WORLD, SensorStreams
from eurocslam.io.sink import Sink
from eurocslam.pipeline.outputs import RunResult
from eurocslam.pipeline.records import STATE_CODE, FrameOutput

WORLD = "world"
BODY = "body"
STATS_LABELS = (
    "state",
    "features",
    "stereo",
    "tracked",
    "landmarks",
    "segment",
    "keyframe",
    "reused",  # archived landmarks re-found at this keyframe (map reuse)
)
BIAS_LABELS = ("bg_x", "bg_y", "bg_z", "ba_x", "ba_y", "ba_z")
VEL_LABELS = ("vx", "vy", "vz", "speed")
ERROR_LABELS = ("ex", "ey", "ez", "norm")  # estimate - ground truth (aligned), world, metres
# /slam/places: one LINE_LIST marker per event (namespace = kind, id = event number), kept
# until the end of the recording
PLACE_RGBA = {
    "loop": (1.0, 0.2, 0.9, 1.0),
    "relocalization": (0.2, 0.8, 1.0, 1.0),
    "merge": (1.0, 0.9, 0.1, 1.0),
    # a loop the gate refused: recognised, its drift one the estimate cannot have (nothing moved)
    "loop_refused": (0.55, 0.55, 0.55, 1.0),
}
TRACKED_RGBA = (0.1, 1.0, 0.2, 1.0)
UNTRACKED_RGBA = (1.0, 0.55, 0.0, 1.0)

SLAM_TOPICS = (
    "/tf",
    "/slam/pose",
    "/slam/drone",
    "/slam/features",
    "/slam/state",
    "/slam/stats",
    "/slam/imu_bias",
    "/slam/velocity",
    "/slam/position_error",
    "/groundtruth/drone",
    "/slam/places",
    "/slam/path",
    "/slam/landmarks",
    "/slam/path_final",
)


def yaw_between(R_a: F64, R_b: F64) -> float:
    """Yaw (about world z) of the z-rotation closest to R_a @ R_b^T."""
    D = R_a @ R_b.T
    return float(np.arctan2(D[1, 0] - D[0, 1], D[0, 0] + D[1, 1]))


def groundtruth_alignment(T_world_body: F64, T_gtworld_body: F64, yaw_only: bool = True) -> F64:
    """`T_world_gtworld` putting the ground-truth body on the estimate: yaw + translation where
    both frames are gravity-aligned (stereo-inertial), the whole pose otherwise."""
    if not yaw_only:
        return T_world_body @ inv_T(T_gtworld_body)
    yaw = yaw_between(T_world_body[:3, :3], T_gtworld_body[:3, :3])
    R = rot_z(yaw)
    return make_T(R, T_world_body[:3, 3] - R @ T_gtworld_body[:3, 3])


def _gt_pose_at(gt: GroundTruth, t_ns: int, max_dt_ns: int = 20_000_000) -> F64 | None:
    if len(gt) == 0:
        return None
    i = int(np.searchsorted(gt.t_ns, t_ns))
    cands = [j for j in (i - 1, i) if 0 <= j < len(gt)]
    j = min(cands, key=lambda j: abs(int(gt.t_ns[j]) - t_ns))
    if abs(int(gt.t_ns[j]) - t_ns) > max_dt_ns:
        return None
    return make_T(quat_wxyz_to_rot(gt.q_wxyz[j]), gt.p[j])


class SlamMcapWriter:
    """Pipeline observer: sensor streams + SLAM topics into one sink, in log-time order."""

    def __init__(
        self,
        sink: Sink,
        streams: SensorStreams,
        groundtruth: GroundTruth | None,
        cfg: OutputConfig | None = None,
        *,
        inertial: bool = True,
        drone_model: bool = True,
    ) -> None:
        """`inertial`: a stereo-inertial run: its world is levelled by gravity, so the
        ground-truth overlay is placed by position and yaw only, and it estimates the IMU's
        biases and the velocity (/slam/imu_bias, /slam/velocity; a visual-only run writes
        neither: nothing estimates them there); `drone_model`: draw the
        drone (EuRoC's body is its IMU frame; a camera-only rig's body is its left camera)."""
        self.sink = sink
        self.inertial = inertial
        self.drone_model = drone_model
        self.streams = streams
        self.gt = groundtruth
        self.cfg = cfg or OutputConfig()
        self._gt_aligned = False
        self._gt_frame = 0  # the world frame (FrameOutput.frame) the overlay is placed in
        self._n_kf = 0
        self._n_places = 0
        self._n_frames = 0
        self._t_last = streams.t0_ns
        self.T_world_gtworld: F64 | None = None

    def _w(self, topic: str, msgtype: str, t: int, msg: bytes) -> None:
        self.sink.write(topic, msgtype, t, msg)

    def on_frame(self, frame: StereoFrame, out: FrameOutput) -> None:
        t = int(frame.t_ns)
        self.streams.write_frame(self.sink, frame)
        self._t_last = max(self._t_last, t)
        fr = out.frontend
        T = out.T_world_body
        if T is not None:
            if out.frame != self._gt_frame:
                # the estimate moved to another world frame (a reset, or a merge into an earlier
                # map's frame): place the ground truth again, in the new frame
                self._gt_aligned, self._gt_frame = False, out.frame
            if self.cfg.groundtruth_overlay and not self._gt_aligned and self.gt is not None:
                T_gt = _gt_pose_at(self.gt, t)
                if T_gt is not None:
                    self.T_world_gtworld = groundtruth_alignment(T, T_gt, self.inertial)
                    self._w(
                        "/tf_static",
                        ros2.TF_MESSAGE,
                        t,
                        ros2.tf_message(
                            [ros2.Transform(t, WORLD, FRAME_GT_WORLD, self.T_world_gtworld)]
                        ),
                    )
                    self._gt_aligned = True
            self._w("/tf", ros2.TF_MESSAGE, t, ros2.tf_message([ros2.Transform(t, WORLD, BODY, T)]))
            self._w("/slam/pose", ros2.POSE_STAMPED, t, ros2.pose_stamped(t, WORLD, T))
            if self.drone_model:
                self._w("/slam/drone", drone.MSGTYPE, t, drone.drone_markers(BODY, t))
            self._write_groundtruth_overlay(t, T)
        self._w("/slam/state", ros2.STRING, t, ros2.string(out.state.value))
        if out.places or self._n_frames == 0:
            self._write_places(t, out)  # (an empty array first: the topic is in every run)
        self._n_frames += 1
        if out.is_keyframe:
            self._n_kf += 1
            path, lm = out.keyframe_path, out.landmarks
            if path is not None and len(path.t_ns):
                self._w(
                    "/slam/path", ros2.PATH, t, ros2.path(t, WORLD, path.t_ns, path.T_world_body)
                )
            every = max(1, self.cfg.landmarks_every_n_keyframes)
            if self._n_kf % every == 0 and lm is not None and len(lm):
                self._w("/slam/landmarks", ros2.POINT_CLOUD2, t, ros2.point_cloud2(t, WORLD, lm))
        if not out.left_out:  # nothing was counted: the plots join the tracked frames
            stats = [
                STATE_CODE[out.state],
                fr.n_features if fr else 0,
                fr.n_stereo if fr else 0,
                fr.n_tracked if fr else 0,
                out.n_active_landmarks,
                out.segment,
                1.0 if out.is_keyframe else 0.0,
                fr.n_reused if fr else 0,
            ]
            self._w(
                "/slam/stats",
                ros2.FLOAT64_MULTI_ARRAY,
                t,
                ros2.float64_multi_array(stats, STATS_LABELS),
            )
        if out.nav is not None and self.inertial:
            nav = out.nav
            self._w(
                "/slam/imu_bias",
                ros2.FLOAT64_MULTI_ARRAY,
                t,
                ros2.float64_multi_array(np.concatenate([nav.bg, nav.ba]), BIAS_LABELS),
            )
            v = nav.v_world
            self._w(
                "/slam/velocity",
                ros2.FLOAT64_MULTI_ARRAY,
                t,
                ros2.float64_multi_array([v[0], v[1], v[2], float(np.linalg.norm(v))], VEL_LABELS),
            )
        if (
            self.cfg.draw_features
            and fr is not None
            and len(fr.draw_uv)
            and (frame.left is not None)
        ):
            tracked = np.asarray(fr.draw_tracked, dtype=bool)
            colors = np.where(tracked[:, None], TRACKED_RGBA, UNTRACKED_RGBA)
            self._w(
                "/slam/features",
                ros2.IMAGE_MARKER,
                t,
                ros2.image_marker(
                    t,
                    "cam0",
                    fr.draw_uv,
                    ns="features",
                    type=ros2.ImageMarkerType.POINTS,
                    scale=4.0,
                    outline_colors=colors,
                ),
            )

    def _write_places(self, t: int, out: FrameOutput) -> None:
        markers = []
        for ev in out.places:
            ns = "loop_refused" if ev.refused else ev.kind.value
            markers.append(
                ros2.Marker(
                    t,
                    WORLD,
                    ns,
                    self._n_places,
                    ros2.MarkerType.LINE_LIST,
                    scale=(0.02, 0.0, 0.0),
                    color=PLACE_RGBA.get(ns, (1.0, 1.0, 1.0, 1.0)),
                    points=np.array([ev.p_query, ev.p_match]),
                )
            )
            self._n_places += 1
        self._w("/slam/places", ros2.MARKER_ARRAY, t, ros2.marker_array(markers))

    def _write_groundtruth_overlay(self, t: int, T_world_body: F64) -> None:
        """Once the ground truth is aligned: its drone (another colour, on `gt_body`) and the
        position error of the estimate against it, in `world` (plot-friendly)."""
        if self.T_world_gtworld is None or self.gt is None:
            return
        T_gt = _gt_pose_at(self.gt, t)
        if T_gt is None:
            return
        if self.drone_model:
            self._w(
                "/groundtruth/drone",
                drone.MSGTYPE,
                t,
                drone.drone_markers(FRAME_GT_BODY, t, drone.GROUNDTRUTH_COLOR, ns="drone_gt"),
            )
        e = T_world_body[:3, 3] - (self.T_world_gtworld @ T_gt)[:3, 3]
        self._w(
            "/slam/position_error",
            ros2.FLOAT64_MULTI_ARRAY,
            t,
            ros2.float64_multi_array([e[0], e[1], e[2], float(np.linalg.norm(e))], ERROR_LABELS),
        )

    def finish(self, result: RunResult) -> None:
        """The rest of the sensor streams, then the final map and trajectory."""
        self.streams.finish(self.sink)
        t = max(self._t_last, self.streams.t_last_ns)
        if len(result.landmarks):
            self._w(
                "/slam/landmarks",
                ros2.POINT_CLOUD2,
                t,
                ros2.point_cloud2(t, WORLD, result.landmarks),
            )
        final = result.final
        if len(final):
            poses = np.column_stack([final.p, wxyz_to_xyzw(final.q_wxyz)])
            self._w("/slam/path_final", ros2.PATH, t, ros2.path(t, WORLD, final.t_ns, poses))
