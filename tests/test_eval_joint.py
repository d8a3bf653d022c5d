"""Several sessions under one alignment (`eval.joint`, `eurocslam eval ... --session EST GT`)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from eurocslam.cli import main
from eurocslam.errors import EvalError
from eurocslam.eval.evaluate import EvalConfig, evaluate
from eurocslam.eval.joint import evaluate_joint
from eurocslam.eval.report import joint_json_dict, joint_note, joint_report
from eurocslam.eval.synthetic import perturb, random_similarity, smooth_trajectory
from eurocslam.geometry import make_T
from eurocslam.trajectory import Trajectory
from eurocslam.trajectory_io import write_euroc_csv, write_tum

DAY_NS = 86_400 * 10**9


def _cat(a: Trajectory, b: Trajectory, name: str) -> Trajectory:
    """Two time-disjoint trajectories as one."""
    return Trajectory(
        np.concatenate([a.t_ns, b.t_ns]),
        np.vstack([a.p, b.p]),
        np.vstack([a.q_wxyz, b.q_wxyz]),
        None,
        name,
    )


@pytest.fixture(scope="module")
def gts() -> tuple[Trajectory, Trajectory]:
    """Two flights of one place on two days (ground truths in one frame)."""
    g1 = smooth_trajectory(1200, 200.0, seed=1, name="gt1")
    g2 = smooth_trajectory(1000, 200.0, seed=2, name="gt2")
    g2 = Trajectory(g2.t_ns + DAY_NS, g2.p + np.array([0.5, -0.3, 0.0]), g2.q_wxyz, None, "gt2")
    return g1, g2


def test_same_frame_joint_equals_the_pooled_evaluation(
    gts: tuple[Trajectory, Trajectory],
) -> None:
    """Both estimates in one (unknown) frame: the joint evaluation is the evaluation of the two
    flights as one trajectory, and about the sessions' own ATE."""
    g1, g2 = gts
    M = random_similarity(3)
    e1 = perturb(g1, M, step=10, noise_m=0.01, seed=4, name="e1")
    e2 = perturb(g2, M, step=10, noise_m=0.01, seed=5, name="e2")
    for mode in ("se3", "sim3", "none"):
        cfg = EvalConfig(align=mode)
        if mode == "none":  # already in the ground truths' frame
            e1, e2 = perturb(g1, None, 10, 0.01, seed=4), perturb(g2, None, 10, 0.01, seed=5)
        j = evaluate_joint([(g1, e1), (g2, e2)], cfg, "estimate")
        pooled = evaluate(_cat(g1, g2, "gt"), _cat(e1, e2, "est"), cfg)
        assert j.matched == pooled.matched == 220
        assert j.ate_trans.rmse == pytest.approx(pooled.ate_trans.rmse, rel=1e-9)
        assert j.ate_rot.rmse == pytest.approx(pooled.ate_rot.rmse, rel=1e-9, abs=1e-12)
        np.testing.assert_allclose(j.alignment.matrix(), pooled.segments[0].alignment.matrix())
        assert j.ate_trans.rmse == pytest.approx(0.01 * np.sqrt(3), rel=0.15)
        assert j.ratio < 1.1 and j.frames_look_shared() and joint_note(j) is None
        for s, g, e in zip(j.sessions, (g1, g2), (e1, e2), strict=True):
            own = evaluate(g, e, cfg)
            assert s.own.ate_trans.rmse == pytest.approx(own.ate_trans.rmse)


def test_two_sessions_at_rest_take_the_joint_rotation_from_the_orientations() -> None:
    """Two takes of a platform standing at one spot (millimetres of noise): the joint fit
    follows `align`'s rule like a single one, and the report gives the position-only figure
    beside the headline; that figure is the pooled position fit's."""
    rng = np.random.default_rng(3)
    M = random_similarity(5)
    pairs = []
    for k in range(2):
        n = 60
        t = 10**18 + k * DAY_NS + np.arange(n, dtype=np.int64) * 50_000_000
        q = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
        g = Trajectory(t, np.array([1.0, 2.0, 0.5]) + rng.normal(0, 5e-4, (n, 3)), q, None, "g")
        pairs.append((g, perturb(g, M, noise_m=1e-3, noise_rad=1e-3, seed=10 + k, name="e")))
    j = evaluate_joint(pairs, EvalConfig(align="se3"), "estimate")
    al = j.alignment
    assert al.from_orientations and al.position_fit is not None
    assert np.degrees(np.arccos((np.trace(al.R @ M[:3, :3]) - 1) / 2)) < 0.2
    pos = j.ate_trans_position_fit
    pooled = evaluate(_cat(*(g for g, _ in pairs), "g"), _cat(*(e for _, e in pairs), "e"))
    assert pos is not None and pooled.ate_trans_position_fit is not None
    assert pos.rmse == pytest.approx(pooled.ate_trans_position_fit.rmse, rel=1e-12)
    assert pos.rmse < j.ate_trans.rmse  # the least-squares minimum over every rotation
    md = joint_report([j])
    assert "(rotation from the orientations:" in md
    assert f"joint ATE headline {j.ate_trans.rmse:.4f} m RMSE" in md
    assert f"the position-only fit (evo's definition) gives {pos.rmse:.4f} m RMSE" in md
    d = joint_json_dict([j])["joint"][0]
    assert d["ate_trans_position_fit_m"]["rmse"] == pos.rmse
    assert d["alignment"]["basis"] == "orientations"


def test_sessions_in_different_frames_show_in_the_joint_ate(
    gts: tuple[Trajectory, Trajectory],
) -> None:
    g1, g2 = gts
    # exact estimates in the ground truths' frame, session 2 moved by a known translation
    d = np.array([0.3, -0.4, 0.0])  # 0.5 m
    e1 = g1.take(np.arange(0, len(g1), 5)).with_name("e1")
    s2 = g2.take(np.arange(0, len(g2), 5))
    e2 = Trajectory(s2.t_ns, s2.p + d, s2.q_wxyz, None, "e2")
    j = evaluate_joint([(g1, e1), (g2, e2)], EvalConfig(align="none"))
    n1, n2 = len(e1), len(e2)
    assert j.ate_trans.rmse == pytest.approx(0.5 * np.sqrt(n2 / (n1 + n2)), rel=1e-9)
    assert j.sessions[0].ate_t.max() < 1e-12
    np.testing.assert_allclose(j.sessions[1].ate_t, 0.5, rtol=1e-9)
    # one rigid motion cannot fit both: every se3 joint error is large, each session's own tiny
    M = random_similarity(8)
    Delta = make_T(np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), d)
    e1 = perturb(g1, M, step=5, noise_m=0.002, seed=1, name="e1")
    e2 = perturb(g2, M @ Delta, step=5, noise_m=0.002, seed=2, name="e2")
    j = evaluate_joint([(g1, e1), (g2, e2)], EvalConfig(), "final (smoothed)")
    assert j.own_ate_trans.rmse < 0.005
    assert j.ate_trans.rmse > 0.5 and j.ratio > 100
    assert all(np.sqrt(np.mean(s.ate_t**2)) > 0.3 for s in j.sessions)
    note = joint_note(j)
    assert note is not None and "do the estimates share a frame?" in note
    md = joint_report([j])
    assert "### Joint: 2 sessions under one alignment, final (smoothed)" in md
    assert "### Session 2 on its own: final (smoothed)" in md and "- note:" in md
    data = joint_json_dict([j])
    assert data["joint"][0]["ratio_joint_to_own"] == pytest.approx(j.ratio)
    assert [r["session"] for r in data["results"]] == [1, 2]


def test_origin_and_align_first_count_from_the_first_session(
    gts: tuple[Trajectory, Trajectory],
) -> None:
    g1, g2 = gts
    M = random_similarity(2)
    e1, e2 = perturb(g1, M, step=4, seed=1), perturb(g2, M, step=4, seed=2)
    j = evaluate_joint([(g1, e1), (g2, e2)], EvalConfig(align="origin"))
    assert j.ate_trans.max < 1e-9  # exact estimates: the first pose gives the whole transform
    j = evaluate_joint([(g1, e1), (g2, e2)], EvalConfig(align_first=50))
    assert j.alignment.n_used == 50 and j.ate_trans.max < 1e-9


def test_joint_errors_name_the_session(gts: tuple[Trajectory, Trajectory]) -> None:
    g1, g2 = gts
    e1 = perturb(g1, None, step=4, seed=1, name="e1")
    with pytest.raises(EvalError, match=r"^session 2: no time overlap: gt2 .* e1"):
        evaluate_joint([(g1, e1), (g2, e1)])
    with pytest.raises(EvalError, match="at least one session"):
        evaluate_joint([])


# ---- CLI --------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory, gts: tuple[Trajectory, Trajectory]) -> dict:
    d = tmp_path_factory.mktemp("joint")
    g1, g2 = gts
    M = random_similarity(5)
    out: dict[str, Path] = {"dir": d}
    for k, g in ((1, g1), (2, g2)):
        write_euroc_csv(d / f"gt{k}.csv", g)
        write_tum(d / f"est{k}.tum", perturb(g, M, step=10, noise_m=0.01, seed=k))
        # a run folder: final and online
        run = d / f"run{k}"
        run.mkdir()
        write_tum(run / "trajectory_final.tum", perturb(g, M, step=10, noise_m=0.005, seed=k))
        write_tum(run / "trajectory_online.tum", perturb(g, M, step=10, noise_m=0.02, seed=k))
    far = perturb(g2, M @ random_similarity(9), step=10, noise_m=0.01, seed=2)
    write_tum(d / "est2_other_frame.tum", far)
    return out


def test_cli_two_sessions_reports_plots_json(
    files: dict, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    d = files["dir"]
    argv = ["eval", str(d / "est1.tum"), str(d / "gt1.csv")]
    argv += ["--session", str(d / "est2.tum"), str(d / "gt2.csv")]
    argv += ["--json", str(tmp_path / "j.json"), "--md", str(tmp_path / "j.md")]
    assert main([*argv, "--plot", str(tmp_path / "plots")]) == 0
    cap = capsys.readouterr()
    assert "### Joint: 2 sessions under one alignment, estimate" in cap.out
    assert "### Session 1 on its own: estimate" in cap.out
    assert "share a frame" not in cap.err
    assert (tmp_path / "j.md").read_text() + "\n" == cap.out  # the report printed, saved
    data = json.loads((tmp_path / "j.json").read_text())
    assert data["schema"] == "eurocslam.eval/1"
    assert data["joint"][0]["matched"] == 220 and len(data["joint"][0]["sessions"]) == 2
    assert data["joint"][0]["ate_trans_m"]["rmse"] < 0.03
    assert [s["groundtruth"] for s in data["sessions"]] == [
        str(d / "gt1.csv"),
        str(d / "gt2.csv"),
    ]
    plots = sorted(p.name for p in (tmp_path / "plots").iterdir())
    assert "joint_estimate_top.png" in plots and "s2_estimate_xyz.png" in plots
    assert len(plots) == 9
    # estimates in different frames: a note says so
    assert (
        main(
            [
                "eval",
                str(d / "est1.tum"),
                str(d / "gt1.csv"),
                "--session",
                str(d / "est2_other_frame.tum"),
                str(d / "gt2.csv"),
                "-q",
            ]
        )
        == 0
    )
    err = capsys.readouterr().err
    assert "do the estimates share a frame?" in err


def test_cli_run_folders_pair_final_with_final(
    files: dict, capsys: pytest.CaptureFixture[str]
) -> None:
    d = files["dir"]
    argv = ["eval", str(d / "run1"), str(d / "gt1.csv"), "--session", str(d / "run2")]
    argv += [str(d / "gt2.csv")]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "### Joint: 2 sessions under one alignment, final (smoothed)" in out
    assert "### Joint: 2 sessions under one alignment, online (causal)" in out
    assert out.index("Session 1 on its own: online") < out.index("Session 2 on its own: final")
    # a file and a run folder: which of the folder's estimates is ambiguous
    argv = ["eval", str(d / "est1.tum"), str(d / "gt1.csv"), "--session", str(d / "run2")]
    argv += [str(d / "gt2.csv")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "no estimate of one kind in common" in err and "--which" in err
    assert main([*argv, "--which", "final", "-q"]) == 0


def test_cli_joint_errors(files: dict, capsys: pytest.CaptureFixture[str]) -> None:
    d = files["dir"]
    base = ["eval", str(d / "est1.tum"), str(d / "gt1.csv")]
    three = [str(d / "est2.tum"), str(d / "gt2.csv"), str(d / "gt1.csv")]
    assert main([*base, "--session", *three]) == 2
    assert "expected EST [GT], got 3 paths" in capsys.readouterr().err
    assert main([*base, "--session", str(d / "est2.tum")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "session 2: " in err and "no ground truth given" in err
    assert main([*base, "--session", str(d / "nope.tum"), str(d / "gt2.csv")]) == 2
    assert "session 2: " in capsys.readouterr().err
    # session 2's estimate against session 1's ground truth: no time overlap, named
    assert main([*base, "--session", str(d / "est2.tum"), str(d / "gt1.csv")]) == 2
    assert "session 2: no time overlap" in capsys.readouterr().err
