"""The doctor on an EuRoC ASL folder: files, calibration, CSVs, timestamps, time units, images,
time overlap, values, and the reader's own verdict, each check guarded so one failure never hides
the others' findings. A folder without `imu0/` is stereo-only (a note, not an error)."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from eurocslam.dataset.asl import AslSequence, resolve_mav0
from eurocslam.dataset.calib import (
    CameraCalib,
    _matrix4,
    camera_from_yaml,
    imu_from_yaml,
    load_sensor_yaml,
)
from eurocslam.dataset.calib_sources import (
    KALIBR,
    SENSOR_YAML,
    CalibrationSource,
    load_source,
    measured_rates,
    source_of,
    sources_in,
)
from eurocslam.dataset.doctor.calib_checks import (
    CalibIssue,
    check_camera,
    check_imu,
    check_stereo_pair,
    check_transform,
)
from eurocslam.dataset.doctor.csv_scan import GT, STREAMS, ScannedCsv, scan_csv
from eurocslam.dataset.doctor.image_checks import ImageState, check_images
from eurocslam.dataset.doctor.kalibr_checks import check_kalibr_source
from eurocslam.dataset.doctor.report import (
    ERROR,
    INFO,
    WARNING,
    DoctorReport,
    Findings,
    StreamStats,
)
from eurocslam.errors import EurocSlamError
from eurocslam.timebase import NS_PER_S, could_be_seconds, magnitude, unit_hint, unit_outliers

GAP_PERIODS = 1.5  # a step longer than this many sample periods is a gap


class _Doctor:
    def __init__(
        self,
        path: Path | str,
        *,
        full: bool,
        sample: int,
        progress: Callable[[int, str], Any] | None,
        calib: Path | None = None,
    ) -> None:
        self.path = Path(path)
        self.calib = calib  # --calib FILE|DIR: check that calibration instead of the folder's
        self.sources: list[CalibrationSource] = []
        self.found = Findings(self.path)
        self.add = self.found.add
        self.guard = self.found.guard
        self.streams: dict[str, StreamStats] = {}
        self.csvs: dict[str, ScannedCsv] = {}
        self.cams: dict[str, CameraCalib] = {}
        self.rates: dict[str, float] = {}
        self.images = ImageState(full, sample, progress)
        self.stereo_pairs = 0
        self.mav0: Path | None = None
        self.root = self.path

    # ---- run --------------------------------------------------------------------------------
    def run(self) -> DoctorReport:
        t0 = time.perf_counter()
        try:
            self.mav0 = resolve_mav0(self.path)
        except EurocSlamError as e:
            self.add(ERROR, "files", str(e))
        if self.mav0 is not None:
            self.root = self.mav0.parent if self.mav0.name == "mav0" else self.mav0
            self.found.root = self.root
            with self.guard("calibration", self.calib):
                self.sources = (
                    [source_of(self.calib)] if self.calib is not None else sources_in(self.mav0)
                )
            self.check_files()
            self.check_calibration()
            for name, (folder, ncols, required) in STREAMS.items():
                path = self.mav0 / folder / "data.csv"
                if path.is_file():
                    with self.guard("csv", path):
                        scanned = scan_csv(self.found, name, path, ncols, required)
                        if scanned is not None:
                            self.csvs[name] = scanned
            for name in self.csvs:
                with self.guard("timestamps", self.mav0 / STREAMS[name][0] / "data.csv"):
                    self.check_times(name)
            with self.guard("units"):
                self.check_time_units()
            for cam in ("cam0", "cam1"):
                with self.guard("images", self.mav0 / cam / "data"):
                    csv, calib = self.csvs.get(cam), self.cams.get(cam)
                    where = self.sources[0].where(cam, "resolution") if self.sources else None
                    check_images(self.found, self.images, cam, self.mav0, csv, calib, where)
            with self.guard("overlap"):
                self.check_overlap()
            with self.guard("values"):
                self.check_values()
            self.check_reader()
        order = [n for n in STREAMS if n in self.streams]
        return DoctorReport(
            sequence=str(self.path),
            mav0=str(self.mav0) if self.mav0 is not None else None,
            findings=self.found.sorted(),
            streams=tuple(self.streams[n] for n in order),
            stereo_pairs=self.stereo_pairs,
            image_headers_read=self.images.headers_read,
            images_decoded=self.images.decoded,
            elapsed_s=time.perf_counter() - t0,
        )

    # ---- files ------------------------------------------------------------------------------
    def check_files(self) -> None:
        assert self.mav0 is not None
        for _name, (folder, _ncols, required) in STREAMS.items():
            d = self.mav0 / folder
            csv, yml = d / "data.csv", d / "sensor.yaml"
            if not d.is_dir():
                if folder == "imu0":
                    self.add(INFO, "files", "no IMU: a stereo-only sequence, runs visual-only", d)
                elif required:
                    self.add(ERROR, "files", "folder missing", d)
                elif folder == GT and not (self.mav0 / "mocap0").is_dir():
                    self.add(INFO, "files", "no ground truth: evaluation needs an external file", d)
                continue
            if not csv.is_file():
                self.add(ERROR if required else WARNING, "files", "file missing", csv)
            calibrated = folder in ("cam0", "cam1", "imu0")
            # (the cameras' and the IMU's calibration may come from a camchain instead)
            kalibr = bool(self.sources) and self.sources[0].kind == KALIBR
            if not yml.is_file() and not (calibrated and kalibr) and folder != "mocap0":
                self.add(ERROR if calibrated else INFO, "files", "file missing", yml)
            if folder in ("cam0", "cam1") and not (d / "data").is_dir():
                self.add(ERROR, "files", "image folder missing", d / "data")

    # ---- calibration ------------------------------------------------------------------------
    def calib_findings(self, issues: list[CalibIssue], path: Path, prefix: str = "") -> None:
        for i in issues:
            self.add(i.severity, "calibration", prefix + i.message, path, key=i.key)

    def check_calibration(self) -> None:
        """Every calibration source found (or the one `--calib` names); the first is the one
        the reader uses (an info finding says which, when it is not the folder's sensor.yaml)."""
        assert self.mav0 is not None
        for k, src in enumerate(self.sources):
            if k == 0 and not (src.kind == SENSOR_YAML and src.path == self.mav0):
                self.add(INFO, "calibration", f"the reader uses {src.describe()}", src.path)
            elif k > 0:
                self.add(INFO, "calibration", f"also found, not used: {src.describe()}", src.path)
            if src.kind == KALIBR:
                cams = check_kalibr_source(self.found, src, measured_rates(self.mav0))
                if k == 0:
                    self.cams.update(cams)
            elif k == 0:
                self.check_sensor_yaml(src.path)
            else:
                for i in load_issues(src):
                    self.add(ERROR, "calibration", i, src.path)

        for sensor in (GT, "leica0"):
            path = self.mav0 / sensor / "sensor.yaml"
            if path.is_file():
                with self.guard("calibration", path):
                    data = load_sensor_yaml(path)
                    if "T_BS" in data:
                        self.calib_findings(check_transform(_matrix4(data, path)), path)

    def check_sensor_yaml(self, folder: Path) -> None:
        """cam0, cam1 and imu0 sensor.yaml files of `folder`."""
        for cam in ("cam0", "cam1"):
            path = folder / cam / "sensor.yaml"
            if not path.is_file():
                continue
            with self.guard("calibration", path):
                data = load_sensor_yaml(path)
                self.rates[cam] = yaml_rate(data)
                calib = camera_from_yaml(data, cam, path, validate=False)
                self.cams[cam] = calib
                self.calib_findings(check_camera(calib), path)
        if "cam0" in self.cams and "cam1" in self.cams:
            stereo = check_stereo_pair(self.cams["cam0"], self.cams["cam1"])
            self.calib_findings(stereo, folder / "cam1" / "sensor.yaml", "stereo: ")
        path = folder / "imu0" / "sensor.yaml"
        if path.is_file():
            with self.guard("calibration", path):
                data = load_sensor_yaml(path)
                self.rates["imu0"] = yaml_rate(data)
                self.calib_findings(check_imu(imu_from_yaml(data, path, validate=False)), path)

    # ---- timestamps ---------------------------------------------------------------------------
    def check_times(self, name: str) -> None:
        assert self.mav0 is not None
        c = self.csvs[name]
        path = self.mav0 / STREAMS[name][0] / "data.csv"
        t = c.t
        yaml_rate = self.rates.get(name)
        stats = StreamStats(name, c.rel, int(t.size), None, None, None, yaml_rate)
        if t.size == 0:
            self.streams[name] = stats
            return
        d = np.diff(t)
        back = np.nonzero(d < 0)[0]
        if back.size:
            i = int(back[0])
            self.add(
                WARNING,
                "timestamps",
                f"{back.size} timestamp(s) go backwards (first: {t[i + 1]} after {t[i]}); "
                "the reader sorts them",
                path,
                int(c.lines[i + 1]),
            )
        order = np.argsort(t, kind="stable")
        ts = t[order]
        dup = np.nonzero(ts[1:] == ts[:-1])[0]
        if dup.size:
            li = int(c.lines[order[dup[0] + 1]])
            self.add(
                WARNING,
                "timestamps",
                f"{dup.size} duplicate timestamp(s) (first: {ts[dup[0]]}); the reader keeps one",
                path,
                li,
            )
        u = np.unique(ts)
        measured = None
        if u.size > 1:
            du = np.diff(u)
            med = float(np.median(du))
            measured = NS_PER_S / med if med > 0 else None
            period = NS_PER_S / yaml_rate if yaml_rate else med
            if yaml_rate and med > 0:
                ratio = med / period
                if ratio < 0.01 or ratio > 100:
                    self.add(
                        ERROR,
                        "units",
                        f"median spacing {med:.0f} ns, but rate_hz {yaml_rate:g} means "
                        f"{period:.0f} ns: {unit_hint(ratio)}",
                        path,
                    )
                    period = med
                elif abs(ratio - 1) > 0.1:
                    self.add(
                        WARNING,
                        "timestamps",
                        f"measured rate {NS_PER_S / med:.2f} Hz differs from sensor.yaml rate_hz "
                        f"{yaml_rate:g}",
                        path,
                        key="rate_hz",
                    )
            gaps = np.nonzero(du > GAP_PERIODS * period)[0]
            if gaps.size:
                big = int(gaps[np.argmax(du[gaps])])
                # line of the row after the largest gap
                pos = np.searchsorted(ts, u[big + 1])
                li = int(c.lines[order[pos]])
                lost = int(np.sum(np.round(du[gaps] / period) - 1))
                self.add(
                    WARNING,
                    "timestamps",
                    f"{gaps.size} gap(s) longer than {GAP_PERIODS:g} periods "
                    f"({GAP_PERIODS * period / 1e6:.1f} ms), about {lost} sample(s) missing; "
                    f"largest {du[big] / 1e6:.1f} ms ({du[big] / period:.1f} periods) "
                    f"ends at this line",
                    path,
                    li,
                )
        self.streams[name] = StreamStats(
            name, c.rel, int(t.size), int(u[0]), int(u[-1]), measured, yaml_rate
        )

    def check_time_units(self) -> None:
        """Timestamps of different files differing by orders of magnitude: s vs ns mix-ups."""
        assert self.mav0 is not None
        mags = {n: magnitude(c.t) for n, c in self.csvs.items() if c.t.size}
        if len(mags) < 2:
            return
        ref_name, outliers = unit_outliers(mags, prefer="imu0")
        ref = mags[ref_name]
        for n in outliers:
            m = mags[n]
            self.add(
                ERROR,
                "units",
                f"timestamps are ~1e{m:.0f} while the other files' are ~1e{ref:.0f} "
                f"({unit_hint(10 ** (m - ref))}); EuRoC timestamps are integer nanoseconds",
                self.mav0 / STREAMS[n][0] / "data.csv",
            )
        if could_be_seconds(mags):
            self.add(
                INFO,
                "units",
                "timestamps are small (< 1e11): if these are seconds, the files are not in "
                "EuRoC's nanoseconds",
            )

    # ---- time overlap ---------------------------------------------------------------------------
    def check_overlap(self) -> None:
        c0, c1 = self.csvs.get("cam0"), self.csvs.get("cam1")
        if c0 is None or c1 is None or c0.t.size == 0 or c1.t.size == 0:
            return
        t0, t1 = np.unique(c0.t), np.unique(c1.t)
        both = np.intersect1d(t0, t1)
        only0, only1 = np.setdiff1d(t0, t1), np.setdiff1d(t1, t0)
        for cam, only, c in (("cam0", only0, c0), ("cam1", only1, c1)):
            if only.size and both.size:
                li = int(c.lines[np.nonzero(c.t == only[0])[0][0]])
                self.add(
                    WARNING,
                    "overlap",
                    f"{only.size} timestamp(s) in {cam} only (first: {only[0]}); the reader "
                    "skips those frames",
                    c.rel,
                    li,
                )
        # complete pairs: both listed and both images usable
        names0 = dict(zip(c0.t.tolist(), c0.names or [], strict=True))
        names1 = dict(zip(c1.t.tolist(), c1.names or [], strict=True))
        u0, u1 = self.images.usable.get("cam0"), self.images.usable.get("cam1")
        self.stereo_pairs = sum(
            1
            for t in both.tolist()
            if (u0 is None or names0[t] in u0) and (u1 is None or names1[t] in u1)
        )
        if both.size == 0:
            self.add(
                ERROR,
                "overlap",
                "cam0 and cam1 share no timestamp: no stereo pairs (the reader joins on timestamp)",
                c1.rel,
            )
            return
        if self.stereo_pairs == 0:
            self.add(ERROR, "overlap", "no stereo pair has both images usable")
        a, b = int(both[0]), int(both[-1])
        imu = self.csvs.get("imu0")
        if imu is not None and imu.t.size:
            i0, i1 = int(imu.t.min()), int(imu.t.max())
            tol = int(NS_PER_S / self.rates["imu0"]) if self.rates.get("imu0") else 0
            if i1 < a or i0 > b:
                self.add(
                    ERROR,
                    "overlap",
                    f"IMU [{i0}, {i1}] does not overlap the stereo frames [{a}, {b}]",
                    imu.rel,
                )
            elif i0 > a + tol or i1 < b - tol:
                cover = (min(i1, b) - max(i0, a)) / max(b - a, 1)
                parts = []
                if i0 > a + tol:
                    parts.append(f"starts {(i0 - a) / NS_PER_S:.3f} s after the first stereo frame")
                if i1 < b - tol:
                    parts.append(f"ends {(b - i1) / NS_PER_S:.3f} s before the last stereo frame")
                self.add(
                    WARNING,
                    "overlap",
                    f"IMU {' and '.join(parts)}: it covers {100 * cover:.0f}% of the image span; "
                    "frames outside it have no inertial data",
                    imu.rel,
                )
        for name, label in (("groundtruth", "ground truth"), ("leica0", "leica0")):
            g = self.csvs.get(name)
            if g is None or g.t.size == 0:
                continue
            g0, g1 = int(g.t.min()), int(g.t.max())
            if g1 < a or g0 > b:
                self.add(
                    WARNING if name == "groundtruth" else INFO,
                    "overlap",
                    f"{label} [{g0}, {g1}] does not overlap the stereo frames [{a}, {b}]"
                    + ("; an evaluation against it is impossible" if name == "groundtruth" else ""),
                    g.rel,
                )
            elif g0 > a or g1 < b:
                cover = (min(g1, b) - max(g0, a)) / max(b - a, 1)
                self.add(
                    INFO,
                    "overlap",
                    f"{label} covers {100 * cover:.0f}% of the stereo frames' time span",
                    g.rel,
                )

    # ---- values -------------------------------------------------------------------------------
    def check_values(self) -> None:
        imu = self.csvs.get("imu0")
        if imu is not None and imu.values is not None and imu.t.size:
            ok = np.isfinite(imu.values).all(axis=1)
            if not ok.any():
                return
            acc = np.linalg.norm(imu.values[ok, 3:6], axis=1)
            med = float(np.median(acc))
            if not 5.0 <= med <= 15.0:
                hint = " (in g instead of m/s^2?)" if 0.5 <= med <= 1.5 else ""
                self.add(
                    WARNING,
                    "values",
                    f"median accelerometer norm {med:.3f} m/s^2 is far from gravity{hint}",
                    imu.rel,
                )
            gmax = float(np.abs(imu.values[ok, 0:3]).max())
            if gmax > 35.0:
                self.add(
                    WARNING,
                    "values",
                    f"largest gyroscope value {gmax:.1f} rad/s is implausible (deg/s?)",
                    imu.rel,
                )
        gt = self.csvs.get("groundtruth")
        if gt is not None and gt.values is not None and gt.t.size:
            norms = np.linalg.norm(gt.values[:, 3:7], axis=1)
            zero = np.nonzero(norms < 1e-9)[0]
            if zero.size:
                self.add(
                    ERROR,
                    "values",
                    f"{zero.size} zero quaternion(s) (q_RS_w..z all 0)",
                    gt.rel,
                    int(gt.lines[zero[0]]),
                    "q_RS",
                )
            dev = np.abs(norms - 1.0)
            off = np.nonzero((dev > 1e-3) & (norms >= 1e-9))[0]
            if off.size:
                worst = int(off[np.argmax(dev[off])])
                self.add(
                    WARNING,
                    "values",
                    f"{off.size} quaternion(s) not unit length (worst norm {norms[worst]:.4f}); "
                    "the reader normalises them",
                    gt.rel,
                    int(gt.lines[worst]),
                    "q_RS",
                )

    # ---- the reader's verdict -------------------------------------------------------------------
    def check_reader(self) -> None:
        """Open the sequence with the reader the pipeline uses: anything it refuses is an error."""
        self.found.reader_verdict(lambda: AslSequence(self.path, calib=self.calib), self.root)


def yaml_rate(data: dict[str, Any]) -> float:
    try:
        r = float(data.get("rate_hz", 0) or 0)
    except (TypeError, ValueError):
        return 0.0
    return r if math.isfinite(r) and r > 0 else 0.0


def diagnose(
    path: Path | str,
    *,
    full: bool = False,
    sample: int = 24,
    progress: Callable[[int, str], Any] | None = None,
    calib: Path | str | None = None,
) -> DoctorReport:
    """Check a sequence folder (or its `mav0/`). Never raises on bad data: every problem is a
    `Finding`. `sample` images per camera are decoded (all of them with `full`); `progress(n,
    camera)` is called once per decoded image. `calib` (`--calib FILE|DIR`): check against that
    calibration instead of the folder's own."""
    c = Path(calib) if calib is not None else None
    return _Doctor(path, full=full, sample=sample, progress=progress, calib=c).run()


def load_issues(src: CalibrationSource) -> list[str]:
    """Why a calibration source other than the one used cannot be loaded (empty: it can)."""
    try:
        load_source(src)
    except EurocSlamError as e:
        return [str(e)]
    return []
