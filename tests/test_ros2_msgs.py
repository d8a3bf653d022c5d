"""Our CDR encoders against an independent one (rosbags `serialize_cdr`), byte for byte, and
decoded back by rosbags and by mcap_ros2's decoder; schema texts in the form Foxglove accepts."""

from __future__ import annotations

import re

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from eurocslam.dataset.calib import default_rig
from eurocslam.geometry import inv_T, make_T, so3_exp
from eurocslam.io import cdr, ros2, ros2_batch, ros2_calib

TS = get_typestore(Stores.ROS2_HUMBLE)
T_NS = 1_403_715_273_262_142_976
SEP = "=" * 80


def _t(t_ns: int):
    sec, nsec = divmod(t_ns, 1_000_000_000)
    return TS.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)


def _h(t_ns: int, frame: str):
    return TS.types["std_msgs/msg/Header"](stamp=_t(t_ns), frame_id=frame)


def _pose(T: np.ndarray):
    p = cdr.pose7(T)
    G = TS.types
    return G["geometry_msgs/msg/Pose"](
        position=G["geometry_msgs/msg/Point"](x=p[0], y=p[1], z=p[2]),
        orientation=G["geometry_msgs/msg/Quaternion"](x=p[3], y=p[4], z=p[5], w=p[6]),
    )


def _decode_mcap_ros2(msgtype: str, data: bytes):
    from mcap.records import Schema
    from mcap_ros2.decoder import DecoderFactory

    schema = Schema(id=1, name=msgtype, encoding="ros2msg", data=ros2.schema_text(msgtype).encode())
    return DecoderFactory().decoder_for("cdr", schema)(data)


def _check(ours: bytes, ref_msg, msgtype: str) -> None:
    ref = bytes(TS.serialize_cdr(ref_msg, msgtype))
    assert ours == ref, (
        f"{msgtype}: our CDR differs from rosbags' ({len(ours)} vs {len(ref)} bytes)"
    )
    # and it decodes with both independent decoders without complaint
    TS.deserialize_cdr(ours, msgtype)
    _decode_mcap_ros2(msgtype, ours)


ALL_TYPES = [
    ros2.IMAGE,
    ros2.COMPRESSED_IMAGE,
    ros2.CAMERA_INFO,
    ros2.IMU,
    ros2.TF_MESSAGE,
    ros2.POSE_STAMPED,
    ros2.PATH,
    ros2.POINT_STAMPED,
    ros2.POINT_CLOUD2,
    ros2.MARKER,
    ros2.MARKER_ARRAY,
    ros2.IMAGE_MARKER,
    ros2.FLOAT64_MULTI_ARRAY,
    ros2.FLOAT64,
    ros2.STRING,
]


def test_shipped_schemas_are_rosbags_own() -> None:
    """The schema texts shipped in data/ (no rosbags type store at start-up) are the ones rosbags
    generates; if this fails after a rosbags upgrade, `ros2.write_schema_file()` regenerates."""
    assert set(ros2.SHIPPED_SCHEMAS) == set(ALL_TYPES)
    for msgtype in ALL_TYPES:
        assert ros2.schema_text(msgtype) == ros2.generated_schema_text(msgtype), msgtype
    # a type not shipped comes from rosbags
    assert ros2.schema_text("std_msgs/msg/Int32") == "int32 data\n"


@pytest.mark.parametrize("msgtype", ALL_TYPES)
def test_schema_root_first_and_dependency_names_match_fields(msgtype: str) -> None:
    text = ros2.schema_text(msgtype)
    blocks = text.split(SEP + "\n")
    root = blocks[0]
    assert not root.startswith("MSG:"), "root definition must come first"
    declared = set()
    for b in blocks[1:]:
        first = b.splitlines()[0]
        assert first.startswith("MSG: ")
        name = first[5:].strip()
        assert "/msg/" not in name, f"dependency spelled {name!r}; fields spell pkg/Name"
        declared.add(name)
    # every complex field type used anywhere is declared exactly as spelled
    used = set()
    for line in text.splitlines():
        m = re.match(r"^([A-Za-z0-9_]+/[A-Za-z0-9_]+)(\[\d*\])?\s+\w+", line)
        if m:
            used.add(m.group(1))
    assert used <= declared, f"undeclared dependencies: {used - declared}"


def test_image_mono8_matches_rosbags() -> None:
    rng = np.random.default_rng(0)
    img = rng.integers(0, 255, size=(48, 75), dtype=np.uint8)
    ours = ros2.image(T_NS, "cam0", img)
    ref = TS.types[ros2.IMAGE](
        header=_h(T_NS, "cam0"),
        height=48,
        width=75,
        encoding="mono8",
        is_bigendian=0,
        step=75,
        data=img.reshape(-1),
    )
    _check(ours, ref, ros2.IMAGE)
    dec = _decode_mcap_ros2(ros2.IMAGE, ours)
    assert bytes(dec.data) == img.tobytes()
    assert dec.header.stamp.sec * 10**9 + dec.header.stamp.nanosec == T_NS


@pytest.mark.parametrize("frame", ["", "c", "cam0", "abcdefgh"])
def test_compressed_image_and_string_alignment(frame: str) -> None:
    data = bytes(range(37))
    ref = TS.types[ros2.COMPRESSED_IMAGE](
        header=_h(T_NS, frame), format="png", data=np.frombuffer(data, np.uint8)
    )
    _check(ros2.compressed_image(T_NS, frame, "png", data), ref, ros2.COMPRESSED_IMAGE)


def test_camera_info_matches_rosbags_and_rectification_is_sane() -> None:
    rig = default_rig()
    i0, i1 = ros2_calib.stereo_camera_infos(rig)
    for info, frame in ((i0, "cam0"), (i1, "cam1")):
        ref = TS.types[ros2.CAMERA_INFO](
            header=_h(T_NS, frame),
            height=info.height,
            width=info.width,
            distortion_model="plumb_bob",
            d=info.D,
            k=info.K.reshape(-1),
            r=info.R.reshape(-1),
            p=info.P.reshape(-1),
            binning_x=0,
            binning_y=0,
            roi=TS.types["sensor_msgs/msg/RegionOfInterest"](
                x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
            ),
        )
        _check(ros2_calib.camera_info(T_NS, frame, info), ref, ros2.CAMERA_INFO)
        assert np.allclose(info.R @ info.R.T, np.eye(3), atol=1e-9)
    np.testing.assert_allclose(i0.K, rig.cam0.K)
    np.testing.assert_allclose(i0.D[:4], rig.cam0.distortion)
    # ROS convention: P_right[0, 3] = -fx' * baseline
    assert i1.P[0, 3] == pytest.approx(-i1.P[0, 0] * rig.baseline, rel=1e-6)
    assert i0.P[0, 3] == 0.0


def test_imu_covariance_is_density_squared_over_dt_and_matches_rosbags() -> None:
    rig = default_rig()
    gcov, acov = ros2_calib.imu_covariances(rig.imu)
    assert gcov[0, 0] == pytest.approx(rig.imu.gyro_noise_density**2 * rig.imu.rate_hz)
    assert acov[2, 2] == pytest.approx(rig.imu.accel_noise_density**2 * rig.imu.rate_hz)
    G = TS.types
    for frame in ("imu0", "i", "imu12"):
        ours = ros2.imu(T_NS, frame, [0.1, -0.2, 0.3], [9.8, 0.1, -0.4], gcov, acov)
        oc = np.zeros(9)
        oc[0] = -1
        ref = G[ros2.IMU](
            header=_h(T_NS, frame),
            orientation=G["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=oc,
            angular_velocity=G["geometry_msgs/msg/Vector3"](x=0.1, y=-0.2, z=0.3),
            angular_velocity_covariance=gcov.reshape(-1),
            linear_acceleration=G["geometry_msgs/msg/Vector3"](x=9.8, y=0.1, z=-0.4),
            linear_acceleration_covariance=acov.reshape(-1),
        )
        _check(ours, ref, ros2.IMU)


def _T(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return make_T(so3_exp(rng.normal(size=3)), rng.normal(size=3))


def test_tf_pose_path_point_match_rosbags() -> None:
    G = TS.types
    Ts = [_T(i) for i in range(3)]
    trs = [ros2.Transform(T_NS + i, "body", f"cam{i}", Ts[i]) for i in range(3)]

    def tr_ref(tr: ros2.Transform):
        p = cdr.pose7(tr.T_parent_child)
        return G["geometry_msgs/msg/TransformStamped"](
            header=_h(tr.t_ns, tr.parent),
            child_frame_id=tr.child,
            transform=G["geometry_msgs/msg/Transform"](
                translation=G["geometry_msgs/msg/Vector3"](x=p[0], y=p[1], z=p[2]),
                rotation=G["geometry_msgs/msg/Quaternion"](x=p[3], y=p[4], z=p[5], w=p[6]),
            ),
        )

    _check(
        ros2.tf_message(trs),
        G[ros2.TF_MESSAGE](transforms=[tr_ref(t) for t in trs]),
        ros2.TF_MESSAGE,
    )
    _check(
        ros2.pose_stamped(T_NS, "gt_world", Ts[0]),
        G[ros2.POSE_STAMPED](header=_h(T_NS, "gt_world"), pose=_pose(Ts[0])),
        ros2.POSE_STAMPED,
    )
    stamps = [T_NS, T_NS + 5, T_NS + 9]
    ref = G[ros2.PATH](
        header=_h(T_NS, "w"),
        poses=[
            G[ros2.POSE_STAMPED](header=_h(s, "w"), pose=_pose(T))
            for s, T in zip(stamps, Ts, strict=True)
        ],
    )
    _check(ros2.path(T_NS, "w", stamps, np.stack(Ts)), ref, ros2.PATH)
    _check(
        ros2.path(T_NS, "w", [], np.zeros((0, 4, 4))),
        G[ros2.PATH](header=_h(T_NS, "w"), poses=[]),
        ros2.PATH,
    )
    ref = G[ros2.POINT_STAMPED](
        header=_h(T_NS, "gt_world"), point=G["geometry_msgs/msg/Point"](x=1.0, y=2.0, z=3.0)
    )
    _check(ros2.point_stamped(T_NS, "gt_world", [1, 2, 3]), ref, ros2.POINT_STAMPED)
    # quaternion round trip
    T = _T(7)
    q = cdr.pose7(T)[3:]
    from eurocslam.geometry import quat_wxyz_to_rot, xyzw_to_wxyz

    np.testing.assert_allclose(quat_wxyz_to_rot(xyzw_to_wxyz(q)), T[:3, :3], atol=1e-12)
    np.testing.assert_allclose(cdr.poses7(np.stack([T, inv_T(T)]))[0], cdr.pose7(T))


@pytest.mark.parametrize("with_rgb,with_int", [(False, False), (True, False), (True, True)])
def test_point_cloud2_matches_rosbags(with_rgb: bool, with_int: bool) -> None:
    G = TS.types
    rng = np.random.default_rng(1)
    xyz = rng.normal(size=(10, 3)).astype(np.float32)
    rgb = rng.integers(0, 255, size=(10, 3), dtype=np.uint8) if with_rgb else None
    inten = rng.random(10).astype(np.float32) if with_int else None
    ours = ros2.point_cloud2(T_NS, "world", xyz, rgb, inten)
    dec = TS.deserialize_cdr(ours, ros2.POINT_CLOUD2)
    names = [f.name for f in dec.fields]
    step = dec.point_step
    assert step == 4 * len(names)
    ref = G[ros2.POINT_CLOUD2](
        header=_h(T_NS, "world"),
        height=1,
        width=10,
        fields=[
            G["sensor_msgs/msg/PointField"](name=n, offset=4 * i, datatype=7, count=1)
            for i, n in enumerate(names)
        ],
        is_bigendian=False,
        point_step=step,
        row_step=step * 10,
        data=np.frombuffer(bytes(dec.data), np.uint8),
        is_dense=True,
    )
    _check(ours, ref, ros2.POINT_CLOUD2)
    arr = np.frombuffer(bytes(dec.data), dtype=np.float32).reshape(10, len(names))
    np.testing.assert_array_equal(arr[:, :3], xyz)
    if with_rgb:
        packed = arr[:, 3].view(np.uint32)
        assert rgb is not None
        np.testing.assert_array_equal(packed >> 16, rgb[:, 0])
        np.testing.assert_array_equal(packed & 0xFF, rgb[:, 2])


def test_marker_array_matches_rosbags() -> None:
    G = TS.types
    pts = np.arange(12, dtype=float).reshape(4, 3)
    cols = np.full((4, 4), 0.5)
    ms = [
        ros2.Marker(
            T_NS,
            "world",
            "drone",
            0,
            10,
            pose=_T(2),
            scale=(1, 2, 3),
            color=(1, 0, 0, 1),
            mesh_resource="package://x.dae",
            text="hi",
        ),
        ros2.Marker(T_NS, "world", "pts", 1, 8, points=pts, colors=cols, lifetime_ns=10**9 + 5),
    ]

    def ref(m: ros2.Marker):
        c = m.color
        return G[ros2.MARKER](
            header=_h(m.t_ns, m.frame_id),
            ns=m.ns,
            id=m.id,
            type=m.type,
            action=m.action,
            pose=_pose(m.pose),
            scale=G["geometry_msgs/msg/Vector3"](x=m.scale[0], y=m.scale[1], z=m.scale[2]),
            color=G["std_msgs/msg/ColorRGBA"](r=c[0], g=c[1], b=c[2], a=c[3]),
            lifetime=G["builtin_interfaces/msg/Duration"](
                sec=m.lifetime_ns // 10**9, nanosec=m.lifetime_ns % 10**9
            ),
            frame_locked=False,
            points=[
                G["geometry_msgs/msg/Point"](x=p[0], y=p[1], z=p[2])
                for p in (m.points if m.points is not None else [])
            ],
            colors=[
                G["std_msgs/msg/ColorRGBA"](r=q[0], g=q[1], b=q[2], a=q[3])
                for q in (m.colors if m.colors is not None else [])
            ],
            texture_resource="",
            texture=G[ros2.COMPRESSED_IMAGE](
                header=_h(0, ""), format="", data=np.zeros(0, np.uint8)
            ),
            uv_coordinates=[],
            text=m.text,
            mesh_resource=m.mesh_resource,
            mesh_file=G["visualization_msgs/msg/MeshFile"](filename="", data=np.zeros(0, np.uint8)),
            mesh_use_embedded_materials=False,
        )

    _check(ros2.marker(ms[0]), ref(ms[0]), ros2.MARKER)
    _check(
        ros2.marker_array(ms), G[ros2.MARKER_ARRAY](markers=[ref(m) for m in ms]), ros2.MARKER_ARRAY
    )


def test_image_marker_matches_rosbags() -> None:
    G = TS.types
    uv = np.array([[10.5, 20.0], [30.0, 40.25]])
    cols = np.array([[0, 1, 0, 1], [1, 0, 0, 1]], dtype=float)
    ours = ros2.image_marker(T_NS, "cam0", uv, ns="feat", id=3, outline_colors=cols)
    ref = G[ros2.IMAGE_MARKER](
        header=_h(T_NS, "cam0"),
        ns="feat",
        id=3,
        type=4,
        action=0,
        position=G["geometry_msgs/msg/Point"](x=0.0, y=0.0, z=0.0),
        scale=3.0,
        outline_color=G["std_msgs/msg/ColorRGBA"](r=0.0, g=1.0, b=0.0, a=1.0),
        filled=0,
        fill_color=G["std_msgs/msg/ColorRGBA"](r=0.0, g=0.0, b=0.0, a=0.0),
        lifetime=G["builtin_interfaces/msg/Duration"](sec=0, nanosec=0),
        points=[G["geometry_msgs/msg/Point"](x=u, y=v, z=0.0) for u, v in uv],
        outline_colors=[G["std_msgs/msg/ColorRGBA"](r=c[0], g=c[1], b=c[2], a=c[3]) for c in cols],
    )
    _check(ours, ref, ros2.IMAGE_MARKER)


def test_std_msgs_match_rosbags() -> None:
    G = TS.types
    vals = [1.5, -2.0, 3.25]
    ref = G[ros2.FLOAT64_MULTI_ARRAY](
        layout=G["std_msgs/msg/MultiArrayLayout"](
            dim=[G["std_msgs/msg/MultiArrayDimension"](label="bgx,bgy,bgz", size=3, stride=3)],
            data_offset=0,
        ),
        data=np.array(vals),
    )
    _check(ros2.float64_multi_array(vals, ["bgx", "bgy", "bgz"]), ref, ros2.FLOAT64_MULTI_ARRAY)
    _check(ros2.float64(2.5), G[ros2.FLOAT64](data=2.5), ros2.FLOAT64)
    _check(ros2.string("TRACKING"), G[ros2.STRING](data="TRACKING"), ros2.STRING)


def test_negative_and_pre_epoch_times_split_consistently() -> None:
    assert cdr.split_ns(1_500_000_001) == (1, 500_000_001)
    assert cdr.split_ns(0) == (0, 0)


@pytest.mark.parametrize("frame", ["", "i", "imu0", "abcdefgh", "abcdefghi"])
def test_batch_encoders_equal_single_messages(frame: str) -> None:
    rng = np.random.default_rng(3)
    t = T_NS + np.arange(20) * 5_000_000
    g, a = rng.normal(size=(20, 3)), rng.normal(size=(20, 3))
    gc, ac = np.eye(3) * 2.0, np.eye(3) * 3.0
    imus = ros2_batch.imu_batch(t, frame, g, a, gc, ac)
    assert imus == [ros2.imu(int(t[i]), frame, g[i], a[i], gc, ac) for i in range(20)]
    Ts = [_T(i) for i in range(20)]
    p7 = cdr.poses7(np.stack(Ts))
    poses = ros2_batch.pose_stamped_batch(t, frame, p7)
    assert poses == [ros2.pose_stamped(int(t[i]), frame, Ts[i]) for i in range(20)]
    for child in ("", "gt_body", "abcdefg"):
        tfs = ros2_batch.tf_batch(t, frame, child, p7)
        assert tfs == [
            ros2.tf_message([ros2.Transform(int(t[i]), frame, child, Ts[i])]) for i in range(20)
        ]
        TS.deserialize_cdr(tfs[0], ros2.TF_MESSAGE)
