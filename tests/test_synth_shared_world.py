"""`synth --world-from`: several sessions rendered in one shared world, with exact ground truth
in one frame (multi-session tests)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from eurocslam.errors import DatasetError
from eurocslam.geometry import make_T
from eurocslam.synth import Scene, SynthSpec
from eurocslam.synth.render import cast_and_shade
from eurocslam.synth.shared_world import MIN_OBSTACLE_M, check_flight_inside, read_flights
from eurocslam.trajectory import Trajectory
from eurocslam.trajectory_io import read_trajectory, write_tum

T0_NS = 1_403_636_580_000_000_000


def _flight(path: Path, centre: tuple[float, float], t0_ns: int, radius: float = 0.8) -> Path:
    """A 6 s circle at 1.2 m height (body x up, body z = the cameras' forward along the path),
    written as TUM: a ground truth in the shared frame."""
    t = np.arange(0.0, 6.0, 0.005)
    a = 2 * np.pi * t / 6.0
    p = np.stack([centre[0] + radius * np.cos(a), centre[1] + radius * np.sin(a), 1.2 + 0.0 * a], 1)
    fwd = np.stack([-np.sin(a), np.cos(a), 0.0 * a], 1)
    up = np.tile([0.0, 0.0, 1.0], (t.size, 1))
    R = np.stack([up, np.cross(fwd, up), fwd], axis=-1)  # columns: body axes in the world
    t_ns = t0_ns + np.round(t * 1e9).astype(np.int64)
    write_tum(path, Trajectory.from_poses(t_ns, make_T(R, p), name=path.name))
    return path


@pytest.fixture(scope="module")
def flights(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Path]:
    """Flights A and B of one place (overlapping, different days), C somewhere else."""
    d = tmp_path_factory.mktemp("flights")
    a = _flight(d / "A.tum", (0.0, 0.0), T0_NS)
    b = _flight(d / "B.tum", (1.0, 0.5), T0_NS + 86_400 * 10**9, radius=0.6)
    c = _flight(d / "C.tum", (9.0, 0.0), T0_NS)
    return a, b, c


@pytest.fixture(scope="module")
def sessions(flights: tuple[Path, Path, Path]) -> tuple[Scene, Scene]:
    a, b, _ = flights
    sa = Scene.build(SynthSpec(trajectory=a, duration_s=0.5, world_from=(a, b)).ideal())
    # another order, a file listed twice, another crop: the same world
    sb = Scene.build(SynthSpec(trajectory=b, start_s=2.0, end_s=2.5, world_from=(b, a, b)).ideal())
    return sa, sb


def test_two_sessions_share_one_world(sessions: tuple[Scene, Scene]) -> None:
    sa, sb = sessions
    assert sa.world.digest() == sb.world.digest()
    assert sa.shared is not None and sb.shared is not None
    assert [f.digest for f in sa.shared.flights] == [f.digest for f in sb.shared.flights]
    # the same pixels seen from the same pose, in both sessions' worlds
    T_world_cam = make_T(
        np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]), [0.3, 0.2, 1.2]
    )
    img_a = cast_and_shade(sa.world, sa.models[0], T_world_cam).radiance
    img_b = cast_and_shade(sb.world, sb.models[0], T_world_cam).radiance
    assert np.array_equal(img_a, img_b)
    assert float(np.std(img_a)) > 10.0  # a textured view, not an empty one
    # and every camera of both sessions keeps its distance from the obstacles
    for sc in sessions:
        st = sc.motion.spline.evaluate(sc.t_s(sc.cam_t_ns))
        inside, near = sc.world.free_space(st.p)
        assert inside.min() > 0.1 and near.min() >= MIN_OBSTACLE_M


def test_the_world_depends_on_the_flights_and_the_seed(flights: tuple[Path, Path, Path]) -> None:
    a, b, _ = flights
    shared = Scene.build(SynthSpec(trajectory=a, duration_s=0.3, world_from=(a, b)).ideal())
    alone = Scene.build(SynthSpec(trajectory=a, duration_s=0.3, world_from=(a,)).ideal())
    seed1 = Scene.build(SynthSpec(trajectory=a, duration_s=0.3, world_from=(a, b), seed=1).ideal())
    digests = {shared.world.digest(), alone.world.digest(), seed1.world.digest()}
    assert len(digests) == 3
    # the union's room encloses B too, walls 1.5 m or more from it
    pb = read_flights([b])[0].positions
    w = shared.world
    assert np.all(pb[:, :2] - w.room_lo[:2] >= 1.5) and np.all(w.room_hi[:2] - pb[:, :2] >= 1.5)
    assert w.free_space(pb)[1].min() >= 0.6


def test_a_flight_outside_the_world_is_an_error(
    flights: tuple[Path, Path, Path], sessions: tuple[Scene, Scene]
) -> None:
    a, b, c = flights
    with pytest.raises(DatasetError, match=r"C\.tum: at 0\.00 s a camera is .* beyond a wall"):
        Scene.build(SynthSpec(trajectory=c, duration_s=0.3, world_from=(a, b)))
    # inside the room but through an obstacle laid out around A and B only
    world, shared = sessions[0].world, sessions[0].shared
    assert shared is not None and world.box_lo.shape[0] > 0
    centre = (world.box_lo[0] + world.box_hi[0]) / 2
    points = np.array([[0.0, 0.0, 1.2], centre])
    with pytest.raises(DatasetError) as e:
        check_flight_inside(world, shared, points, np.array([0.0, 3.25]), "D.tum")
    msg = str(e.value)
    assert msg.startswith("--trajectory D.tum: at 3.25 s a camera is 0.00 m from an obstacle")
    assert "--world-from A.tum B.tum" in msg and "add the trajectory to --world-from" in msg
    above = np.array([[0.0, 0.0, world.room_hi[2] + 0.5]])
    with pytest.raises(DatasetError, match=r"0\.500 m above the ceiling"):
        check_flight_inside(world, shared, above, np.array([1.0]), "D.tum")


def test_bad_world_from_inputs(tmp_path: Path, flights: tuple[Path, Path, Path]) -> None:
    a, _, _ = flights
    with pytest.raises(DatasetError, match="--world-from needs --trajectory"):
        Scene.build(SynthSpec(duration_s=0.3, world_from=(a,)))
    with pytest.raises(DatasetError, match="--world-from with --imu"):
        Scene.build(SynthSpec(trajectory=a, imu=a, world_from=(a,)))
    bad = tmp_path / "bad.tum"
    rows = [f"{1.0 + 0.1 * k:.1f} {k} 0 1 0 0 0 1" for k in range(8)]
    rows[5] = "1.5 0 x 1 0 0 0 1"
    bad.write_text("# t x y z qx qy qz qw\n" + "\n".join(rows) + "\n")
    with pytest.raises(DatasetError, match=r"^--world-from .*bad\.tum:7: non-numeric"):
        Scene.build(SynthSpec(trajectory=a, world_from=(a, bad)))
    with pytest.raises(DatasetError, match=r"^--world-from .*nope\.tum: trajectory file not found"):
        Scene.build(SynthSpec(trajectory=a, world_from=(tmp_path / "nope.tum",)))


def test_cli_renders_two_sessions_in_one_world(
    tmp_path: Path, flights: tuple[Path, Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    from eurocslam.cli import main

    a, b, c = flights
    common = ["--duration", "0.3", "--ideal", "--workers", "1", "--world-from", str(a), str(b)]
    assert main(["synth", str(tmp_path / "sa"), "--trajectory", str(a), *common]) == 0
    line_a = next(ln for ln in capsys.readouterr().out.splitlines() if "world " in ln)
    assert (
        main(
            [
                "synth",
                str(tmp_path / "sb"),
                "--trajectory",
                str(b),
                "--blackout",
                "0.1:0.2",
                *common,
            ]
        )
        == 0
    )
    line_b = next(ln for ln in capsys.readouterr().out.splitlines() if "world " in ln)
    assert line_a == line_b and ", id " in line_a and "built from A.tum, B.tum; seed 0" in line_a
    ja = json.loads((tmp_path / "sa/synth.json").read_text())
    jb = json.loads((tmp_path / "sb/synth.json").read_text())
    assert ja["world_id"] == jb["world_id"] and ja["world_id"][:12] in line_a
    assert [f["file"] for f in ja["world_from"]] == [f["file"] for f in jb["world_from"]]
    assert jb["spec"]["blackout"] == [0.1, 0.2] and len(jb["spec"]["world_from"]) == 2
    # each ground truth stays in its file's frame: the written poses are the given ones
    for name, src in (("sa", a), ("sb", b)):
        gt = read_trajectory(tmp_path / name / "mav0/state_groundtruth_estimate0/data.csv")
        given = read_trajectory(src)
        k = np.searchsorted(given.t_ns, gt.t_ns)
        assert np.all(given.t_ns[k] == gt.t_ns)
        assert np.abs(gt.p - given.p[k]).max() < 0.015  # the spline's fit at the file's start
    # errors are one line, exit code 2
    assert main(["synth", str(tmp_path / "sc"), "--trajectory", str(c), *common]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "C.tum" in err and "beyond a wall" in err
    assert main(["synth", str(tmp_path / "sd"), "--world-from", str(a)]) == 2
    assert "--world-from needs --trajectory" in capsys.readouterr().err
    assert not (tmp_path / "sc").exists() and not (tmp_path / "sd").exists()


def test_spec_identity_without_world_from_is_unchanged() -> None:
    assert "world_from" not in SynthSpec(duration_s=1.0).to_json()


@pytest.mark.slow
def test_machine_hall_flights_share_a_hall(euroc_dir: Path) -> None:
    """MH_01 and MH_02 (one Leica frame) in one hall; V1_01 (another room's frame) is not in it."""
    g = euroc_dir / "groundtruth"
    mh = (g / "MH_01_easy.txt", g / "MH_02_easy.txt")
    s1 = Scene.build(SynthSpec(trajectory=mh[0], end_s=1.0, world_from=mh))
    s2 = Scene.build(SynthSpec(trajectory=mh[1], start_s=50.0, end_s=51.0, world_from=mh[::-1]))
    assert s1.world.digest() == s2.world.digest()
    assert s1.world.texels_per_m == 200.0
    assert s1.world.atlas_bytes() < 100e6  # 77 MB with every mip level
    with pytest.raises(DatasetError, match=r"V1_01_easy\.txt: at .* s a camera is"):
        Scene.build(SynthSpec(trajectory=g / "V1_01_easy.txt", world_from=mh))
