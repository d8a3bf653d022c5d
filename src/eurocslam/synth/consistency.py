"""How well a sequence's IMU integrates onto its ground truth: the replica consistency measure.

For windows of a few lengths, starting every few samples: the angle between the gyro's rotation
(minus the ground truth's mean gyro bias, midpoint rule) and the ground truth's relative
rotation, and the |delta-v| error of the accelerometer (minus the mean accel bias) rotated by the
ground-truth orientation, with gravity `kinematics.GRAVITY` (9.81 m/s^2 along -z). Medians over
the windows ("-": none, the sequence is shorter than the window). Biases are
taken constant (the means of the bias columns): that is what an estimator whose bias is a slow
random walk can follow. Over 0.05/0.2/1/5 s, the full-length simulated-IMU replicas of V1_01,
MH_01 and V2_02 give 0.0033/0.0068/0.016-0.018/0.040-0.057 deg and 1.2/4/18-19/81-90 mm/s (their
white noise and bias random walk); V1_01's real-IMU replica 0.0011/0.0029/0.014/0.066 deg and
2.8/7.8/36/145 mm/s (a spline through the ground truth alone gave 0.061/0.081/0.146/0.329 deg
and 7.2/13.4/50/198 mm/s).

The measure needs the ground truth at the IMU's own stamps (it rotates every accelerometer
sample by it), as a synthetic sequence writes it; a real sequence's (V1_01: 20 Hz) is refused.

    .venv/bin/python -m eurocslam.synth.consistency SEQUENCE [SEQUENCE ...]
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from eurocslam.errors import DatasetError, EurocSlamError
from eurocslam.geometry import F64, quat_wxyz_to_rot
from eurocslam.synth.kinematics import GRAVITY, integrate_gyro
from eurocslam.synth.spline import so3_log_batch
from eurocslam.timebase import ns_to_s

WINDOWS_S = (0.05, 0.2, 1.0, 5.0)
MIN_COVERAGE = 0.95  # share of the IMU stamps the ground truth must have a row at


@dataclass(frozen=True)
class Mismatch:
    windows_s: tuple[float, ...]
    gyro_deg: tuple[float, ...]  # median angle per window length (nan: no such window)
    dv_mps: tuple[float, ...]  # median |delta-v| error per window length (nan: no such window)


def imu_mismatch(
    t_ns: np.ndarray,
    gyro: F64,
    accel: F64,
    bg: F64,
    ba: F64,
    R: F64,
    v: F64,
    *,
    windows_s: tuple[float, ...] = WINDOWS_S,
    stride: int = 7,
) -> Mismatch:
    """The measure on samples: IMU (t_ns, gyro, accel), constant biases bg, ba (3,), ground
    truth R_world_body (N, 3, 3) and world velocity v (N, 3) at the same stamps. A window
    longer than the samples gives nan."""
    dt = ns_to_s(np.diff(t_ns).astype(np.float64))
    P = integrate_gyro(t_ns, gyro, bg)
    f = np.einsum("nij,nj->ni", R, accel - ba) + GRAVITY
    dv = np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (f[1:] + f[:-1]) * dt[:, None], 0)])
    period = float(np.median(dt))
    gy, av = [], []
    for win in windows_s:
        n = max(1, round(win / period))
        i = np.arange(0, t_ns.size - n, stride)
        if i.size == 0:
            gy.append(float("nan"))
            av.append(float("nan"))
            continue
        j = i + n
        imu_rel = np.swapaxes(P[i], 1, 2) @ P[j]
        ref_rel = np.swapaxes(R[i], 1, 2) @ R[j]
        err = so3_log_batch(np.swapaxes(ref_rel, 1, 2) @ imu_rel)
        gy.append(float(np.degrees(np.median(np.linalg.norm(err, axis=1)))))
        dverr = (dv[j] - dv[i]) - (v[j] - v[i])
        av.append(float(np.median(np.linalg.norm(dverr, axis=1))))
    return Mismatch(tuple(windows_s), tuple(gy), tuple(av))


def sequence_mismatch(seq_dir: Path, windows_s: tuple[float, ...] = WINDOWS_S) -> Mismatch:
    """The measure on an ASL folder with a 17-column ground truth at the IMU's stamps (a
    synthetic sequence): the IMU rows within the ground truth's span, which must have a ground
    truth row at `MIN_COVERAGE` of them or more (those it misses are dropped)."""
    from eurocslam.dataset.asl import read_numeric_csv

    mav0 = Path(seq_dir) / "mav0"
    if not mav0.is_dir():
        raise DatasetError(f"{seq_dir}: not a sequence folder (no mav0/)")
    imu = read_numeric_csv(mav0 / "imu0" / "data.csv", 7)
    gt = read_numeric_csv(mav0 / "state_groundtruth_estimate0" / "data.csv", 17)
    for tab in (imu, gt):
        step = np.diff(tab.t_ns)
        if np.any(step <= 0):
            k = int(np.flatnonzero(step <= 0)[0]) + 1
            raise DatasetError(f"{tab.path}:{tab.line_numbers[k]}: timestamps must increase")
    span = imu.t_ns[(imu.t_ns >= gt.t_ns[0]) & (imu.t_ns <= gt.t_ns[-1])] if gt.t_ns.size else []
    t = np.intersect1d(span, gt.t_ns)
    if t.size < 2 or t.size < MIN_COVERAGE * len(span):
        raise DatasetError(
            f"{gt.path}: ground truth at {t.size} of the {len(span)} IMU stamps within its span "
            f"({imu.t_ns.size} IMU rows in all); the measure needs it at the IMU's own stamps "
            f"({100 * MIN_COVERAGE:g} % or more), as a synthetic sequence writes it"
        )
    a = imu.values[np.searchsorted(imu.t_ns, t)]
    g = gt.values[np.searchsorted(gt.t_ns, t)]
    return imu_mismatch(
        t,
        a[:, 0:3],
        a[:, 3:6],
        g[:, 10:13].mean(axis=0),
        g[:, 13:16].mean(axis=0),
        quat_wxyz_to_rot(g[:, 3:7]),
        g[:, 7:10],
        windows_s=windows_s,
    )


def main(argv: list[str] | None = None) -> int:
    paths = sys.argv[1:] if argv is None else argv
    if not paths:
        print(__doc__.strip().splitlines()[-1].strip(), file=sys.stderr)
        return 2
    head = " ".join(f"{w:g}s" for w in WINDOWS_S)
    print(f"{'sequence':<40} gyro mismatch deg ({head}) | delta-v error mm/s ({head})")
    for p in paths:
        try:
            m = sequence_mismatch(Path(p))
        except EurocSlamError as e:
            one_line = " ".join(str(e).split()) or type(e).__name__
            print(f"consistency: error: {one_line}", file=sys.stderr)
            return e.exit_code
        gy = " ".join("-" if np.isnan(x) else f"{x:.4f}" for x in m.gyro_deg)
        dv = " ".join("-" if np.isnan(x) else f"{1000 * x:.1f}" for x in m.dv_mps)
        print(f"{Path(p).name:<40} {gy} | {dv}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
