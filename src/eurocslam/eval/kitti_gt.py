"""KITTI ground truth for `eval`: `poses/NN.txt` (one 3x4 `T_world_cam0` per frame, no stamps)
stamped by the sequence's `times.txt`, given as the poses file or as the sequence folder.

The poses are cam0 poses, and the KITTI reader's body frame is cam0, so a run on the sequence
and its ground truth are in the same body frame.
"""

from __future__ import annotations

from pathlib import Path

from eurocslam.dataset.kitti_files import (
    TIMES,
    poses_path_of,
    read_poses,
    read_times,
    times_paths_for_poses,
)
from eurocslam.errors import EvalError
from eurocslam.geometry import rot_to_quat_wxyz
from eurocslam.trajectory import Trajectory


def kitti_groundtruth(path: Path) -> tuple[Trajectory, Path, Path]:
    """(trajectory, poses file, times file) of a KITTI poses file or sequence folder."""
    if path.is_dir():
        times, poses = path / TIMES, poses_path_of(path)
        if not poses.is_file():
            raise EvalError(
                f"{path}: no ground truth for this KITTI sequence ({poses} not found; KITTI "
                "keeps it in poses/NN.txt beside sequences/)"
            )
        if not times.is_file():
            raise EvalError(f"{times}: file not found (the poses' timestamps)")
    else:
        poses = path
        cands = times_paths_for_poses(path)
        found = next((c for c in cands if c.is_file()), None)
        if found is None:
            raise EvalError(
                f"{path}: a KITTI poses file carries no timestamps and no times.txt was found "
                f"(tried {cands[0]} and {cands[1]})"
            )
        times = found
    t_ns, _ = read_times(times)
    T = read_poses(poses, int(t_ns.size), times)
    traj = Trajectory(t_ns, T[:, :3, 3].copy(), rot_to_quat_wxyz(T[:, :3, :3]), None, str(poses))
    return traj, poses, times
