"""`eurocslam eval` end to end: files, run folders, MCAP topics, reports, plots, clear errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from eurocslam.cli import main
from eurocslam.eval.synthetic import perturb, random_similarity, smooth_trajectory
from eurocslam.geometry import wxyz_to_xyzw
from eurocslam.trajectory import Trajectory
from eurocslam.trajectory_io import write_euroc_csv, write_tum

PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def pair(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Trajectory, Trajectory]:
    d = tmp_path_factory.mktemp("evalcli")
    gt = smooth_trajectory(2000, 200.0, seed=1, name="gt")
    est = perturb(gt, random_similarity(4), step=10, noise_m=0.01, noise_rad=0.005, seed=2)
    write_euroc_csv(d / "gt.csv", gt)
    write_tum(d / "est.tum", est)
    return d / "gt.csv", d / "est.tum", gt, est


def _write_mcap(path: Path, topics: dict[str, Trajectory], tf_child: str | None = None) -> None:
    from mcap_ros2.writer import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    with open(path, "wb") as f:
        w = Writer(f, chunk_size=8192)  # several chunks, so a cut file keeps some
        pose_schema = w.register_msgdef(
            "geometry_msgs/msg/PoseStamped",
            ts.generate_msgdef("geometry_msgs/msg/PoseStamped", ros_version=2)[0],
        )
        tf_schema = w.register_msgdef(
            "tf2_msgs/msg/TFMessage",
            ts.generate_msgdef("tf2_msgs/msg/TFMessage", ros_version=2)[0],
        )
        path_schema = w.register_msgdef(
            "nav_msgs/msg/Path", ts.generate_msgdef("nav_msgs/msg/Path", ros_version=2)[0]
        )
        for topic, tr in topics.items():
            q = wxyz_to_xyzw(tr.q_wxyz)
            if topic == "/slam/path_final":
                poses = []
                for i in range(len(tr)):
                    t = int(tr.t_ns[i])
                    poses.append(
                        {
                            "header": {
                                "stamp": {"sec": t // 10**9, "nanosec": t % 10**9},
                                "frame_id": "world",
                            },
                            "pose": {
                                "position": dict(zip("xyz", map(float, tr.p[i]), strict=True)),
                                "orientation": dict(zip("xyzw", map(float, q[i]), strict=True)),
                            },
                        }
                    )
                end = int(tr.t_ns[-1])
                msg = {
                    "header": {
                        "stamp": {"sec": end // 10**9, "nanosec": end % 10**9},
                        "frame_id": "world",
                    },
                    "poses": poses,
                }
                w.write_message(topic, path_schema, msg, end, end)
                continue
            for i in range(len(tr)):
                t = int(tr.t_ns[i])
                stamp = {"sec": t // 10**9, "nanosec": t % 10**9}
                pose = {
                    "position": dict(zip("xyz", map(float, tr.p[i]), strict=True)),
                    "orientation": dict(zip("xyzw", map(float, q[i]), strict=True)),
                }
                if topic == "/tf":
                    tf = {
                        "header": {"stamp": stamp, "frame_id": "world"},
                        "child_frame_id": tf_child,
                        "transform": {
                            "translation": pose["position"],
                            "rotation": pose["orientation"],
                        },
                    }
                    other = {**tf, "child_frame_id": "other"}
                    w.write_message(topic, tf_schema, {"transforms": [tf, other]}, t, t)
                else:
                    msg = {"header": {"stamp": stamp, "frame_id": "world"}, "pose": pose}
                    w.write_message(topic, pose_schema, msg, t, t)
        w.finish()


def test_eval_files_writes_reports_and_plots(pair, tmp_path: Path, capsys) -> None:
    gt, est, _, _ = pair
    rc = main(
        [
            "eval",
            str(est),
            str(gt),
            "--json",
            str(tmp_path / "r.json"),
            "--md",
            str(tmp_path / "r.md"),
            "--plot",
            str(tmp_path / "plots"),
            "--align",
            "se3",
        ]
    )
    assert rc == 0
    out = capsys.readouterr().out
    assert "| ATE translation [m] |" in out
    data = json.loads((tmp_path / "r.json").read_text())
    res = data["results"][0]
    assert res["matched"] == 200 and res["possible"] == 200
    assert 0.005 < res["ate_trans_m"]["rmse"] < 0.03  # 1 cm noise per axis
    assert [L["fraction"] for L in res["rpe_lengths"]] == [0.1, 0.2, 0.3, 0.4, 0.5]
    assert (tmp_path / "r.md").read_text().startswith("## Trajectory evaluation")
    pngs = sorted((tmp_path / "plots").glob("*.png"))
    assert [p.name for p in pngs] == [
        "estimate_error.png",
        "estimate_rpe.png",
        "estimate_top.png",
        "estimate_xyz.png",
    ]
    assert all(p.read_bytes()[:8] == PNG and p.stat().st_size > 10_000 for p in pngs)


def test_eval_run_folder_reports_final_and_online(pair, tmp_path: Path, capsys) -> None:
    gt_csv, _, gt, _ = pair
    run = tmp_path / "run"
    final = perturb(gt, random_similarity(5), step=10, noise_m=0.005, seed=3)
    online = perturb(gt, random_similarity(5), step=10, noise_m=0.03, seed=4)
    write_tum(run / "trajectory_final.tum", final)
    write_tum(run / "trajectory_online.tum", online)
    assert main(["eval", str(run), str(gt_csv), "--json", str(tmp_path / "r.json")]) == 0
    out = capsys.readouterr().out
    assert "| final (smoothed) |" in out and "| online (causal) |" in out
    res = json.loads((tmp_path / "r.json").read_text())["results"]
    assert [r["label"] for r in res] == ["final (smoothed)", "online (causal)"]
    assert res[0]["ate_trans_m"]["rmse"] < res[1]["ate_trans_m"]["rmse"]
    assert (
        main(
            [
                "eval",
                str(run),
                str(gt_csv),
                "--which",
                "online",
                "-q",
                "--json",
                str(tmp_path / "o.json"),
            ]
        )
        == 0
    )
    res = json.loads((tmp_path / "o.json").read_text())["results"]
    assert [r["label"] for r in res] == ["online (causal)"]


def test_eval_mcap_pose_and_tf_topics(pair, tmp_path: Path) -> None:
    gt_csv, est_tum, gt, est = pair
    mc = tmp_path / "run.mcap"
    _write_mcap(mc, {"/slam/pose": est, "/groundtruth/pose": gt.take(slice(0, None, 4))})
    # estimate and ground truth both from the MCAP (no ground-truth argument)
    assert main(["eval", str(mc), "-q", "--json", str(tmp_path / "a.json")]) == 0
    # estimate from MCAP against the CSV: identical numbers to the TUM file
    assert main(["eval", str(mc), str(gt_csv), "-q", "--json", str(tmp_path / "b.json")]) == 0
    assert main(["eval", str(est_tum), str(gt_csv), "-q", "--json", str(tmp_path / "c.json")]) == 0
    b = json.loads((tmp_path / "b.json").read_text())["results"][0]
    c = json.loads((tmp_path / "c.json").read_text())["results"][0]
    assert b["ate_trans_m"]["rmse"] == pytest.approx(c["ate_trans_m"]["rmse"], abs=1e-9)
    assert b["rpe_delta_rot_deg"]["rmse"] == pytest.approx(c["rpe_delta_rot_deg"]["rmse"], abs=1e-6)
    # tf topic with a chosen child frame
    mtf = tmp_path / "tf.mcap"
    _write_mcap(mtf, {"/tf": est}, tf_child="body")
    args = [
        "eval",
        str(mtf),
        str(gt_csv),
        "-q",
        "--topic",
        "/tf",
        "--child-frame",
        "body",
        "--json",
        str(tmp_path / "d.json"),
    ]
    assert main(args) == 0
    d = json.loads((tmp_path / "d.json").read_text())["results"][0]
    assert d["ate_trans_m"]["rmse"] == pytest.approx(c["ate_trans_m"]["rmse"], abs=1e-9)


def test_eval_mcap_errors_list_topics_and_frames(pair, tmp_path: Path, capsys) -> None:
    gt_csv, _, _, est = pair
    mtf = tmp_path / "tf.mcap"
    _write_mcap(mtf, {"/tf": est}, tf_child="body")
    assert main(["eval", str(mtf), str(gt_csv), "--topic", "/nope"]) == 2
    err = capsys.readouterr().err
    assert "no topic '/nope'" in err and "/tf (tf2_msgs/msg/TFMessage)" in err
    assert main(["eval", str(mtf), str(gt_csv), "--topic", "/tf"]) == 2
    err = capsys.readouterr().err
    assert "--child-frame" in err and "(body, other)" in err
    assert main(["eval", str(mtf), str(gt_csv), "--topic", "/tf", "--child-frame", "x"]) == 2
    assert "no transform with child frame 'x'" in capsys.readouterr().err
    assert main(["eval", str(mtf), "--topic", "/tf", "--child-frame", "body"]) == 2  # no GT
    assert "no ground truth" in capsys.readouterr().err


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err and "internal error" not in err
    assert err.startswith("eurocslam eval: error: ")
    return err


def test_eval_clear_errors(pair, tmp_path: Path, capsys) -> None:
    gt_csv, est_tum, _, est = pair
    # no overlap: both names
    late = Trajectory(est.t_ns + 10**12, est.p, est.q_wxyz)
    write_tum(tmp_path / "late.tum", late)
    assert main(["eval", str(tmp_path / "late.tum"), str(gt_csv)]) == 2
    err = _one_line_error(capsys)
    assert "no time overlap" in err and "late.tum" in err and "gt.csv" in err
    # zero matches within a tiny max diff
    shifted = Trajectory(est.t_ns + 2_500_000, est.p, est.q_wxyz)
    write_tum(tmp_path / "shift.tum", shifted)
    assert main(["eval", str(tmp_path / "shift.tum"), str(gt_csv), "--max-diff", "0.001"]) == 2
    err = _one_line_error(capsys)
    assert "zero timestamp matches" in err and "shift.tum" in err and "gt.csv" in err
    # ... and the offset fixes it
    assert (
        main(
            [
                "eval",
                str(tmp_path / "shift.tum"),
                str(gt_csv),
                "--max-diff",
                "0.001",
                "--offset",
                "-0.0025",
                "-q",
            ]
        )
        == 0
    )
    capsys.readouterr()
    # malformed row
    bad = tmp_path / "bad.tum"
    bad.write_text(est_tum.read_text().replace("\n", "\n1.0 2.0\n", 3).split("\n", 1)[1])
    assert main(["eval", str(bad), str(gt_csv)]) == 2
    assert f"{bad}:" in _one_line_error(capsys)
    # fewer than 3 matches
    few = tmp_path / "few.tum"
    write_tum(few, est.take(slice(0, 2)))
    assert main(["eval", str(few), str(gt_csv)]) == 2
    assert "at least 3" in _one_line_error(capsys)
    # EuRoC CSV estimate written with seconds
    secs = tmp_path / "secs.csv"
    secs.write_text("#timestamp,x,y,z,qw,qx,qy,qz\n1403636580.5,0,0,0,1,0,0,0\n")
    assert main(["eval", str(secs), str(gt_csv)]) == 2
    assert "looks like seconds" in _one_line_error(capsys)
    # missing inputs
    assert main(["eval", str(tmp_path / "nope.tum"), str(gt_csv)]) == 2
    assert "no such file" in _one_line_error(capsys)
    assert main(["eval", str(tmp_path), str(gt_csv)]) == 2
    assert "not a run output folder" in _one_line_error(capsys)


def test_eval_segments_from_tum_comments(pair, tmp_path: Path, capsys) -> None:
    gt_csv, _, gt, _ = pair
    a = perturb(gt.take(slice(0, 900)), random_similarity(1), step=10, noise_m=0.01, seed=1)
    b = perturb(gt.take(slice(1000, 2000)), random_similarity(2), step=10, noise_m=0.01, seed=2)
    seg = np.concatenate([np.zeros(len(a), np.int64), np.ones(len(b), np.int64)])
    est = Trajectory(
        np.concatenate([a.t_ns, b.t_ns]),
        np.vstack([a.p, b.p]),
        np.vstack([a.q_wxyz, b.q_wxyz]),
        seg,
    )
    write_tum(tmp_path / "seg.tum", est)
    assert (
        main(["eval", str(tmp_path / "seg.tum"), str(gt_csv), "--json", str(tmp_path / "s.json")])
        == 0
    )
    out = capsys.readouterr().out
    assert "| segment | matched / possible |" in out
    res = json.loads((tmp_path / "s.json").read_text())["results"][0]
    assert [s["segment"] for s in res["segments"]] == [0, 1]
    assert res["ate_trans_m"]["rmse"] < 0.03
    assert 0.85 < res["coverage"] < 0.95


def test_eval_run_folder_with_only_the_mcap(pair, tmp_path: Path) -> None:
    gt_csv, _, gt, _ = pair
    final = perturb(gt, random_similarity(5), step=10, noise_m=0.005, seed=3)
    online = perturb(gt, random_similarity(5), step=10, noise_m=0.03, seed=4)
    run = tmp_path / "run"
    run.mkdir()
    _write_mcap(
        run / "run.mcap", {"/slam/pose": online, "/slam/path_final": final, "/groundtruth/pose": gt}
    )
    write_tum(tmp_path / "final.tum", final)
    assert main(["eval", str(run), "-q", "--json", str(tmp_path / "m.json")]) == 0
    assert (
        main(
            [
                "eval",
                str(tmp_path / "final.tum"),
                str(gt_csv),
                "-q",
                "--json",
                str(tmp_path / "f.json"),
            ]
        )
        == 0
    )
    res = json.loads((tmp_path / "m.json").read_text())["results"]
    assert [r["label"] for r in res] == ["final (smoothed)", "online (causal)"]
    f = json.loads((tmp_path / "f.json").read_text())["results"][0]
    assert res[0]["ate_trans_m"]["rmse"] == pytest.approx(f["ate_trans_m"]["rmse"], abs=1e-9)


def test_eval_reads_an_unfinished_mcap(pair, tmp_path: Path, capsys) -> None:
    gt_csv, _, gt, est = pair
    mc = tmp_path / "run.mcap"
    _write_mcap(mc, {"/slam/pose": est, "/groundtruth/pose": gt.take(slice(0, None, 4))})
    data = mc.read_bytes()
    part = tmp_path / "run.mcap.partial"
    part.write_bytes(data[: len(data) * 2 // 3])
    assert main(["eval", str(part), str(gt_csv), "-q", "--json", str(tmp_path / "p.json")]) == 0
    err = capsys.readouterr().err
    assert err.count("no summary/index") == 1
    res = json.loads((tmp_path / "p.json").read_text())["results"][0]
    assert 0 < res["matched"] <= len(est)
