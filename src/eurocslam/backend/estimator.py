"""Stereo-inertial factor graph: keyframe states X/V/B, explicit landmarks L, GTSAM smoother.

Graph per keyframe k (body = IMU frame, world = gravity-aligned, z up):

* `CombinedImuFactor(X(k-1), V(k-1), X(k), V(k), B(k-1), B(k))` from IMU preintegration between
  the keyframes (bias random walk included). Across an IMU dropout the IMU factor is replaced by
  a bias random-walk `BetweenFactor` and a loose velocity `BetweenFactor`: vision bridges it.
* `GenericStereoFactor3D(X(k), L(j))` per stereo observation (uL, uR, v) in the rectified cam0
  frame, `body_P_sensor = T_body_rect0`, under a Huber loss. A stereo observation fixes a point
  in 3D, so landmarks never make the system rank-deficient.
* Priors on X(0), V(0), B(0) at initialisation (GTSAM 4.3 has no initial-bias covariance).

The smoother is an `IncrementalFixedLagSmoother` (or plain `ISAM2`). Fixed-lag pitfalls handled
here: every new key is given a timestamp (landmarks included), a landmark is re-stamped each
time it is observed, keys without values are never stamped, and a landmark that has been
marginalised and is seen again gets a fresh key. Every factor is also kept in a per-segment
global graph so a full batch optimisation can produce the final (smoothed) trajectory. There a
landmark keeps its first key however often the smoother let it go: a landmark seen again
after a while (the frontend re-finds mapped points, `frontend.reuse_map`) ties the keyframes
that saw it then to those that see it now, so the final batch closes the loop.

All GTSAM failures (indeterminant system, NaN) surface as `EstimatorFailure`; the pipeline's
health logic resets and starts a new segment.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, L, V, X

from eurocslam.backend.initializer import InitialState
from eurocslam.backend.preintegration import bias, integrate, make_params
from eurocslam.camera import RectifiedStereo, bucket_select
from eurocslam.config import RunConfig
from eurocslam.dataset.calib import ImuCalib
from eurocslam.dataset.types import ImuData
from eurocslam.geometry import F64, inv_T, make_T, so3_exp, so3_log


class EstimatorFailure(RuntimeError):
    """The smoother could not be updated (degenerate system, NaN); the caller must reset."""


@dataclass(frozen=True)
class NavEstimate:
    """State at one instant: pose, velocity and biases in the world frame."""

    t_ns: int
    T_world_body: F64
    v_world: F64
    bg: F64
    ba: F64


@dataclass(frozen=True)
class ImuCheck:
    """The final batch's variance check of the IMU factors against the stereo factors."""

    ratio: float  # (IMU chi-square / its redundancy) / (stereo chi-square / its redundancy)
    accel_scale: float = 1.0  # variance scale the final batch gave the accelerometer (1: none)
    ratio_after: float = math.nan  # the ratio with that scale (NaN: not re-weighted)


@dataclass
class UpdateStats:
    n_stereo_factors: int = 0
    n_new_landmarks: int = 0
    imu_bridged: bool = False  # IMU factor replaced by vision-only bridging
    time_ms: float = 0.0


@dataclass
class _Segment:
    graph: gtsam.NonlinearFactorGraph = field(default_factory=gtsam.NonlinearFactorGraph)
    values: dict[int, object] = field(default_factory=dict)  # key -> latest estimate
    kf_times: list[int] = field(default_factory=list)
    kf_index0: int = 0
    # stereo observations beyond the smoother's cap, for the final batch:
    # (keyframe index, global landmark key, uL, uR, v, sigma scale)
    final_only: list[tuple[int, int, float, float, float, float]] = field(default_factory=list)


REWEIGHT_ROUNDS = 3  # variance-component rounds of the final batch, at most
REWEIGHT_DONE = 1.25  # they stop once the IMU/stereo residual ratio is below this


def _landmark_indices(keys: Iterable[int]) -> np.ndarray:
    """The indices of the landmark symbols L(i) among gtsam keys, in the keys' order."""
    k = np.asarray(keys, dtype=np.uint64)
    is_l = (k >> np.uint64(56)) == np.uint64(ord("l"))
    return (k[is_l] & np.uint64((1 << 56) - 1)).astype(np.int64)


def _pose(T: F64) -> gtsam.Pose3:
    return gtsam.Pose3(np.asarray(T, dtype=np.float64))


class StereoInertialEstimator:
    """Keyframe-based stereo-inertial smoother. One instance per trajectory segment."""

    def __init__(
        self,
        imu_calib: ImuCalib,
        stereo: RectifiedStereo,
        imu: ImuData,
        cfg: RunConfig | None = None,
        *,
        use_imu: bool = True,
    ) -> None:
        self.cfg = cfg or RunConfig()
        self.imu = imu
        self.use_imu = use_imu
        self.imu_calib = imu_calib
        self.params = make_params(imu_calib, self.cfg.imu)
        self.stereo = stereo
        self.K = gtsam.Cal3_S2Stereo(
            stereo.fx, stereo.fy, 0.0, stereo.cx, stereo.cy, stereo.baseline
        )
        self.body_P_rect0 = _pose(stereo.T_body_rect0)
        self._stereo_noises: dict[float, gtsam.noiseModel.Base] = {}
        self._imu_rw_gyro = imu_calib.gyro_random_walk * self.cfg.imu.gyro_bias_walk_scale
        self._imu_rw_acc = imu_calib.accel_random_walk * self.cfg.imu.accel_bias_walk_scale
        self._make_smoother()
        self.k = -1  # index of the latest keyframe
        self.t0_ns = 0
        self.t_last_ns = 0
        self.state: NavEstimate | None = None
        self.lm_key: dict[int, int] = {}  # frontend landmark id -> current key index
        self._next_lm = 0
        # per landmark key index: latest position, frontend id, still in the smoother window
        self._lm_pos = np.zeros((1024, 3))
        self._lm_fid = np.zeros(1024, np.int64)
        self._lm_active = np.zeros(1024, bool)
        self._lm_gkey = np.zeros(1024, np.int64)  # the landmark's key in the global graph
        self._lm_nobs = np.zeros(1024, np.int64)  # per global key: observations in the segment
        self.segment = _Segment()
        self.pim: gtsam.PreintegratedCombinedMeasurements | None = None
        self._pim_t_ns = 0
        self._pim_ok = True
        self.stats = UpdateStats()
        self.kf_estimates: dict[int, NavEstimate] = {}  # keyframe index -> smoothed estimate
        self.final_states: dict[int, NavEstimate] = {}  # keyframe index -> final batch estimate
        self.imu_check: ImuCheck | None = None  # set by the final batch (stereo-inertial)
        self._window: list[int] = []  # keyframe indices still in the smoother

    # ---- setup ----------------------------------------------------------------------------------
    def _make_smoother(self) -> None:
        b = self.cfg.backend
        p = gtsam.ISAM2Params()
        p.setRelinearizeThreshold(b.relinearize_threshold)
        p.relinearizeSkip = b.relinearize_skip
        p.findUnusedFactorSlots = True
        if b.smoother == "fixed_lag":
            self.smoother = gtsam.IncrementalFixedLagSmoother(b.lag_s, p)
            self.isam = None
        else:
            self.smoother = None
            self.isam = gtsam.ISAM2(p)

    def _t(self, t_ns: int) -> float:
        return (t_ns - self.t0_ns) * 1e-9

    # ---- initialisation -------------------------------------------------------------------------
    def initialize(
        self,
        init: InitialState,
        landmark_ids: np.ndarray,
        stereo_uv: F64,
        stereo_sigma: F64 | None = None,
    ) -> NavEstimate:
        """First keyframe with priors; for a dynamic start, the window's keyframes with IMU
        factors between them are added too (their stereo observations are not kept)."""
        c = self.cfg.init
        self.t0_ns = init.t_ns
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        stamps: dict[int, float] = {}
        dynamic = init.mode == "dynamic"
        # first pose: yaw and position are the gauge; roll and pitch come from gravity. Pose3's
        # rotation tangent is in the body frame: the world-frame sigmas are rotated into it
        tilt = c.prior_tilt_sigma_dynamic if dynamic else c.prior_tilt_sigma_static
        R = np.asarray(init.T_world_body, float)[:3, :3]
        cov = np.zeros((6, 6))
        cov[:3, :3] = R.T @ np.diag([tilt**2, tilt**2, c.prior_yaw_sigma**2]) @ R
        cov[3:, 3:] = np.eye(3) * c.prior_pos_sigma**2
        pose_noise = gtsam.noiseModel.Gaussian.Covariance(cov)
        vel_sigma = c.prior_vel_sigma_dynamic if dynamic else c.prior_vel_sigma_static
        if not self.use_imu:
            vel_sigma = 1.0
        bias_noise = gtsam.noiseModel.Diagonal.Sigmas(
            np.array([c.prior_accel_bias_sigma] * 3 + [c.prior_gyro_bias_sigma] * 3)
        )
        self.k = 0
        graph.add(gtsam.PriorFactorPose3(X(0), _pose(init.T_world_body), pose_noise))
        graph.add(
            gtsam.PriorFactorVector(
                V(0),
                np.asarray(init.v_world, float),
                gtsam.noiseModel.Isotropic.Sigma(3, vel_sigma),
            )
        )
        b0 = bias(init.bg, init.ba)
        graph.add(gtsam.PriorFactorConstantBias(B(0), b0, bias_noise))
        values.insert(X(0), _pose(init.T_world_body))
        values.insert(V(0), np.asarray(init.v_world, float))
        values.insert(B(0), b0)
        for key in (X(0), V(0), B(0)):
            stamps[key] = 0.0
        self.segment = _Segment(kf_index0=0)
        self.segment.kf_times.append(init.t_ns)
        self.t_last_ns = init.t_ns
        self.state = NavEstimate(
            init.t_ns,
            np.asarray(init.T_world_body, float),
            np.asarray(init.v_world, float),
            np.asarray(init.bg, float),
            np.asarray(init.ba, float),
        )
        self._reset_pim(init.t_ns, self.state)
        subst = self._add_stereo(
            0, init.T_world_body, landmark_ids, stereo_uv, stereo_sigma, graph, values, stamps, 0.0
        )
        self._update(graph, values, stamps, subst)
        return self._read_state(0, init.t_ns)

    # ---- IMU prediction ------------------------------------------------------------------------
    def _reset_pim(self, t_ns: int, st: NavEstimate) -> None:
        self.pim = gtsam.PreintegratedCombinedMeasurements(self.params, bias(st.bg, st.ba))
        self._pim_t_ns = t_ns
        self._pim_ok = True

    def _extend_pim(self, t_ns: int) -> None:
        assert self.pim is not None
        if t_ns <= self._pim_t_ns:
            return
        info = integrate(self.pim, self.imu, self._pim_t_ns, t_ns)
        if not info.ok(self.cfg.imu.max_gap_s):
            self._pim_ok = False
        self._pim_t_ns = t_ns

    def imu_ok_since_keyframe(self) -> bool:
        return self._pim_ok

    def predict(self, t_ns: int) -> NavEstimate:
        """Pose at `t_ns` predicted from the latest keyframe state: IMU preintegration, or a
        constant-velocity model when the IMU is off or has a dropout."""
        st = self.state
        assert st is not None
        dt = (t_ns - st.t_ns) * 1e-9
        if self.use_imu:
            self._extend_pim(t_ns)
        if self.use_imu and self._pim_ok:
            assert self.pim is not None
            nav = gtsam.NavState(
                gtsam.Rot3(st.T_world_body[:3, :3]),
                gtsam.Point3(*st.T_world_body[:3, 3]),
                st.v_world,
            )
            pred = self.pim.predict(nav, bias(st.bg, st.ba))
            T = pred.pose().matrix()
            v = np.asarray(pred.velocity())
        else:
            T = st.T_world_body.copy()
            T[:3, 3] = T[:3, 3] + st.v_world * dt
            v = st.v_world
        return NavEstimate(t_ns, T, v, st.bg, st.ba)

    # ---- keyframes ------------------------------------------------------------------------------
    def add_keyframe(
        self,
        t_ns: int,
        landmark_ids: np.ndarray,
        stereo_uv: F64,
        T_world_body_guess: F64 | None = None,
        stereo_sigma: F64 | None = None,
    ) -> NavEstimate:
        """Add a keyframe at `t_ns` with its stereo observations; returns its smoothed state.
        `stereo_sigma`: per observation, the pixel sigma in units of `backend.stereo_sigma_px`
        (the keypoint's pyramid scale); None: 1 for all."""
        assert self.state is not None
        k = self.k + 1
        pred = self.predict(t_ns)
        T_guess = T_world_body_guess if T_world_body_guess is not None else pred.T_world_body
        v_guess = pred.v_world
        if T_world_body_guess is not None and not (self.use_imu and self._pim_ok):
            dt = max((t_ns - self.state.t_ns) * 1e-9, 1e-3)
            v_guess = (T_world_body_guess[:3, 3] - self.state.T_world_body[:3, 3]) / dt
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        stamps: dict[int, float] = {}
        bridged = False
        dt = (t_ns - self.state.t_ns) * 1e-9
        if self.use_imu and self._pim_ok:
            assert self.pim is not None
            graph.add(
                gtsam.CombinedImuFactor(X(k - 1), V(k - 1), X(k), V(k), B(k - 1), B(k), self.pim)
            )
        else:
            bridged = self.use_imu
            # no usable IMU: bias random walk and a loose velocity link; vision fixes the pose
            sg = self._imu_rw_gyro * math.sqrt(max(dt, 1e-3))
            sa = self._imu_rw_acc * math.sqrt(max(dt, 1e-3))
            graph.add(
                gtsam.BetweenFactorConstantBias(
                    B(k - 1),
                    B(k),
                    gtsam.imuBias.ConstantBias(),
                    gtsam.noiseModel.Diagonal.Sigmas(np.array([sa] * 3 + [sg] * 3)),
                )
            )
            graph.add(
                gtsam.BetweenFactorVector(
                    V(k - 1),
                    V(k),
                    np.zeros(3),
                    gtsam.noiseModel.Isotropic.Sigma(3, 2.0 * max(dt, 0.05)),
                )
            )
            if not self.use_imu:
                # visual-only: a weak constant-velocity motion prior keeps V and B determined
                graph.add(
                    gtsam.PriorFactorConstantBias(
                        B(k), gtsam.imuBias.ConstantBias(), gtsam.noiseModel.Isotropic.Sigma(6, 1.0)
                    )
                )
        values.insert(X(k), _pose(T_guess))
        values.insert(V(k), np.asarray(v_guess, float))
        values.insert(B(k), bias(self.state.bg, self.state.ba))
        tk = self._t(t_ns)
        for key in (X(k), V(k), B(k)):
            stamps[key] = tk
        subst = self._add_stereo(
            k, T_guess, landmark_ids, stereo_uv, stereo_sigma, graph, values, stamps, tk
        )
        n_known = self.stats.n_stereo_factors - self.stats.n_new_landmarks
        if not (self.use_imu and self._pim_ok) and n_known < self.cfg.backend.min_obs_without_imu:
            if self.use_imu or T_world_body_guess is None:
                raise EstimatorFailure(
                    f"keyframe at t={t_ns} ns sees {n_known} mapped landmarks and has no IMU "
                    "constraint"
                )
            # visual-only: the frontend tracks landmarks the smoother no longer holds (unseen by
            # it for the lag: marginalised) or a new map; link the keyframe to the previous one
            # by the frontend's relative motion instead of failing
            T_rel = inv_T(self.state.T_world_body) @ np.asarray(T_world_body_guess)
            b = self.cfg.backend
            sig = np.array([b.vo_bridge_rot_sigma] * 3 + [b.vo_bridge_pos_sigma] * 3)
            graph.add(
                gtsam.BetweenFactorPose3(
                    X(k - 1), X(k), _pose(T_rel), gtsam.noiseModel.Diagonal.Sigmas(sig)
                )
            )
        self.stats.imu_bridged = bridged
        self.k = k
        self.segment.kf_times.append(t_ns)
        self._update(graph, values, stamps, subst)
        est = self._read_state(k, t_ns)
        self._reset_pim(t_ns, est)
        return est

    def _stereo_noise(self, scale: float) -> gtsam.noiseModel.Base:
        """Huber-robust isotropic (uL, uR, v) noise of `stereo_sigma_px` x scale (cached)."""
        m = self._stereo_noises.get(scale)
        if m is None:
            b = self.cfg.backend
            base = gtsam.noiseModel.Isotropic.Sigma(3, b.stereo_sigma_px * max(scale, 1e-3))
            m = gtsam.noiseModel.Robust.Create(
                gtsam.noiseModel.mEstimator.Huber.Create(b.huber_k), base
            )
            self._stereo_noises[scale] = m
        return m

    def _add_stereo(
        self,
        k: int,
        T_world_body: F64,
        landmark_ids: np.ndarray,
        stereo_uv: F64,
        stereo_sigma: F64 | None,
        graph: gtsam.NonlinearFactorGraph,
        values: gtsam.Values,
        stamps: dict[int, float],
        tk: float,
    ) -> dict[int, gtsam.NonlinearFactor]:
        """Stereo factors into `graph`. Returns the factors the global graph takes instead
        (by index in `graph`): those of landmarks whose smoother key is not their first."""
        b = self.cfg.backend
        st = self.stereo
        ids = np.asarray(landmark_ids, dtype=np.int64)
        uv = np.asarray(stereo_uv, dtype=np.float64).reshape(-1, 3)
        scale = (
            np.ones(len(uv))
            if stereo_sigma is None or len(stereo_sigma) != len(uv)
            else np.round(np.asarray(stereo_sigma, dtype=np.float64), 3)
        )
        disp = uv[:, 0] - uv[:, 1]
        ok = np.isfinite(uv).all(axis=1) & (disp >= b.min_disparity_px)
        depth = np.where(ok, st.fx * st.baseline / np.where(ok, disp, 1.0), np.inf)
        ok &= depth <= b.max_depth_m
        idx = np.nonzero(ok)[0]
        cap = b.max_landmarks_per_keyframe if self.use_imu else b.max_landmarks_per_keyframe_no_imu
        final_cap = max(cap, b.final_max_landmarks_per_keyframe) if b.final_batch else cap
        extra = idx[:0]
        if idx.size > cap:
            # spread over the image (4 x 3 cells, round-robin), in each cell landmarks already
            # in the graph first, then the nearest: the nearest alone can crowd one region
            known = np.array([self._is_active(int(ids[i])) for i in idx], dtype=bool)
            priority = np.where(known, 1e6, 0.0) - depth[idx]
            pick = bucket_select(uv[idx][:, [0, 2]], priority, cap, st.width, st.height, 4, 3)
            rest = np.setdiff1d(np.arange(idx.size), pick)
            if final_cap > cap:  # the final batch's share, picked the same way from the rest
                more = bucket_select(
                    uv[idx[rest]][:, [0, 2]],
                    priority[rest],
                    final_cap - cap,
                    st.width,
                    st.height,
                    4,
                    3,
                )
                extra = idx[rest[more]]
            idx = idx[pick]
        T_world_rect0 = np.asarray(T_world_body) @ st.T_body_rect0

        def world_point(i: int) -> F64:
            z = depth[i]
            Xc = np.array([(uv[i, 0] - st.cx) * z / st.fx, (uv[i, 2] - st.cy) * z / st.fy, z])
            return T_world_rect0[:3, :3] @ Xc + T_world_rect0[:3, 3]

        n_new = 0
        subst: dict[int, gtsam.NonlinearFactor] = {}
        for i in idx.tolist():
            fid = int(ids[i])
            key_i = self.lm_key.get(fid)
            if key_i is None or not self._lm_active[key_i]:
                key_i = self._new_landmark_key(fid)
                Xw = world_point(i)
                values.insert(L(key_i), gtsam.Point3(*Xw))
                self._lm_pos[key_i] = Xw
                n_new += 1
            stamps[L(key_i)] = tk  # new or re-observed: (re-)stamp
            meas = gtsam.StereoPoint2(uv[i, 0], uv[i, 1], uv[i, 2])
            noise = self._stereo_noise(float(scale[i]))
            gkey = int(self._lm_gkey[key_i])
            self._lm_nobs[gkey] += 1
            if gkey != key_i:
                subst[graph.size()] = gtsam.GenericStereoFactor3D(
                    meas, noise, X(k), L(gkey), self.K, self.body_P_rect0
                )
            graph.add(
                gtsam.GenericStereoFactor3D(meas, noise, X(k), L(key_i), self.K, self.body_P_rect0)
            )
        # beyond the smoother's cap: observations for the final batch alone. A landmark not yet
        # known gets a key that the smoother never holds (it re-keys it if it picks it later)
        for i in extra.tolist():
            fid = int(ids[i])
            key_i = self.lm_key.get(fid)
            if key_i is None:
                key_i = self._new_landmark_key(fid)
                self._lm_active[key_i] = False
                self._lm_pos[key_i] = world_point(i)
            gkey = int(self._lm_gkey[key_i])
            self._lm_nobs[gkey] += 1
            self.segment.final_only.append((k, gkey, uv[i, 0], uv[i, 1], uv[i, 2], scale[i]))
        self.stats.n_stereo_factors = len(idx)
        self.stats.n_new_landmarks = n_new
        return subst

    # ---- smoother -------------------------------------------------------------------------------
    def _update(
        self,
        graph: gtsam.NonlinearFactorGraph,
        values: gtsam.Values,
        stamps: dict[int, float],
        subst: dict[int, gtsam.NonlinearFactor] | None = None,
    ) -> None:
        subst = subst or {}
        for i in range(graph.size()):
            self.segment.graph.add(subst.get(i, graph.at(i)))
        try:
            if self.smoother is not None:
                ts = gtsam.FixedLagSmootherKeyTimestampMap()
                for key, t in stamps.items():
                    ts.insert((key, t))
                self.smoother.update(graph, values, ts)
                est = self.smoother.calculateEstimate()
            else:
                assert self.isam is not None
                self.isam.update(graph, values)
                est = self.isam.calculateEstimate()
        except RuntimeError as e:
            raise EstimatorFailure(f"smoother update failed: {e}") from None
        self._est = est
        # landmarks still in the window, read in one call (keys sort 'l' before 'v': the
        # landmarks are the first rows of extractPoint3, which also returns the velocities)
        lidx = _landmark_indices(est.keys())
        self._lm_active[: self._next_lm] = False
        if lidx.size:
            pts = np.asarray(gtsam.utilities.extractPoint3(est))[: lidx.size]
            self._lm_pos[lidx] = pts
            self._lm_active[lidx] = True

    def _read_state(self, k: int, t_ns: int) -> NavEstimate:
        est = self._est
        pose = est.atPose3(X(k))
        v = np.asarray(est.atVector(V(k)))
        b = est.atConstantBias(B(k))
        T = pose.matrix()
        ne = NavEstimate(t_ns, T, v, np.asarray(b.gyroscope()), np.asarray(b.accelerometer()))
        if not (np.all(np.isfinite(T)) and np.all(np.isfinite(v))):
            raise EstimatorFailure("non-finite state after update")
        self.state = ne
        self.t_last_ns = t_ns
        # refresh the window's keyframe estimates (smoothing)
        if not self._window or self._window[-1] != k:
            self._window.append(k)
        keep = []
        for kk in self._window:
            if not est.exists(X(kk)):
                continue  # marginalised: its last estimate stays
            keep.append(kk)
            pose_kk = est.atPose3(X(kk))
            v_kk = np.asarray(est.atVector(V(kk)))
            b_kk = est.atConstantBias(B(kk))
            self.kf_estimates[kk] = NavEstimate(
                self.segment.kf_times[kk],
                pose_kk.matrix(),
                v_kk,
                np.asarray(b_kk.gyroscope()),
                np.asarray(b_kk.accelerometer()),
            )
            self.segment.values[X(kk)] = pose_kk
            self.segment.values[V(kk)] = v_kk
            self.segment.values[B(kk)] = b_kk
        self._window = keep
        return ne

    def active_landmarks(self) -> tuple[np.ndarray, F64]:
        """Frontend ids and world positions of the landmarks in the smoother window."""
        act = np.nonzero(self._lm_active[: self._next_lm])[0]
        return self._lm_fid[act].copy(), self._lm_pos[act].copy()

    @property
    def n_active_landmarks(self) -> int:
        return int(self._lm_active[: self._next_lm].sum())

    def _is_active(self, fid: int) -> bool:
        k = self.lm_key.get(fid)
        return k is not None and bool(self._lm_active[k])

    def _new_landmark_key(self, fid: int) -> int:
        key_i = self._next_lm
        self._next_lm += 1
        if key_i >= self._lm_pos.shape[0]:
            n = 2 * self._lm_pos.shape[0]
            self._lm_pos = np.resize(self._lm_pos, (n, 3))
            self._lm_fid = np.resize(self._lm_fid, n)
            self._lm_gkey = np.resize(self._lm_gkey, n)
            self._lm_nobs = np.pad(self._lm_nobs, (0, n - self._lm_nobs.size))  # zeros
            self._lm_active = np.pad(self._lm_active, (0, n - self._lm_active.size))  # False
        old = self.lm_key.get(fid)
        self._lm_gkey[key_i] = key_i if old is None else self._lm_gkey[old]
        self.lm_key[fid] = key_i
        self._lm_fid[key_i] = fid
        self._lm_active[key_i] = True
        return key_i

    # ---- final batch ---------------------------------------------------------------------------
    def final_batch(self, max_iterations: int = 5) -> tuple[dict[int, F64], dict[int, F64]]:
        """Full Levenberg-Marquardt over every factor of the segment and the stereo observations
        kept for it alone (`_final_graph`).

        With the IMU, a variance-component estimate follows: the IMU factors' chi-square per
        redundancy against the stereo factors' (`imu_check`). When the IMU disagrees with the
        vision by more than `backend.final_imu_reweight_above` times what its noise model
        allows (a real accelerometer whose bias wanders faster than its datasheet says), the
        accelerometer's noise and bias-walk covariances are scaled by the ratio and the batch
        runs again from the last result, until the ratio is near 1 (at most
        `REWEIGHT_ROUNDS` rounds). On V1_01 the accelerometer carries the disagreement (its
        residual components 15x a simulated IMU's, the gyro's 5x): scaling the gyro's too left
        the keyframes 0.2-0.35 mm worse.

        Returns (keyframe index -> T_world_body, landmark key -> position). Falls back to the
        smoother's estimates if the batch fails to converge."""
        vals = gtsam.Values()
        for key, v in self.segment.values.items():
            if chr(gtsam.Symbol(key).chr()) == "v":
                vals.insert(key, np.asarray(v, dtype=float))
            else:
                vals.insert(key, v)
        graph = self._final_graph()
        # one variable per landmark: its first key (its later keys' factors were re-keyed)
        gkeys = _landmark_indices(graph.keyVector())
        lms = {int(i): self._lm_pos[i].copy() for i in gkeys}
        for i, p in lms.items():
            vals.insert(L(i), gtsam.Point3(*p))
        poses = {kk: e.T_world_body for kk, e in self.kf_estimates.items()}
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(max_iterations)
        params.setRelativeErrorTol(1e-4)
        result = self._optimize(graph, vals, params)
        if result is None:
            return poses, lms
        if self.use_imu:
            result = self._reweight_imu(graph, result, params)
        out = {}
        states = {}
        for kk, e in self.kf_estimates.items():
            if result.exists(X(kk)):
                T = result.atPose3(X(kk)).matrix()
                out[kk] = T
                v, b = np.asarray(result.atVector(V(kk))), result.atConstantBias(B(kk))
                bg, ba = np.asarray(b.gyroscope()), np.asarray(b.accelerometer())
                states[kk] = NavEstimate(e.t_ns, T, v, bg, ba)
        self.final_states = states
        lm_out = {}
        for key_i in lms:
            if result.exists(L(key_i)):
                lm_out[key_i] = np.asarray(result.atPoint3(L(key_i)))
        return out, lm_out

    def _final_graph(self) -> gtsam.NonlinearFactorGraph:
        """The segment's factors plus its final-only stereo observations of landmarks seen
        at least twice (one observation only adds a landmark, no constraint)."""
        extra = [o for o in self.segment.final_only if self._lm_nobs[o[1]] >= 2]
        if not extra:
            return self.segment.graph
        graph = gtsam.NonlinearFactorGraph(self.segment.graph)
        for k, gkey, ul, ur, v, scale in extra:
            graph.add(
                gtsam.GenericStereoFactor3D(
                    gtsam.StereoPoint2(ul, ur, v),
                    self._stereo_noise(float(scale)),
                    X(k),
                    L(gkey),
                    self.K,
                    self.body_P_rect0,
                )
            )
        return graph

    def _optimize(
        self,
        graph: gtsam.NonlinearFactorGraph,
        vals: gtsam.Values,
        params: gtsam.LevenbergMarquardtParams,
    ) -> gtsam.Values | None:
        """Levenberg-Marquardt; None if it fails or any keyframe pose comes out non-finite."""
        try:
            result = gtsam.LevenbergMarquardtOptimizer(graph, vals, params).optimize()
        except RuntimeError:
            return None
        for kk in self.kf_estimates:
            if result.exists(X(kk)) and not np.all(np.isfinite(result.atPose3(X(kk)).matrix())):
                return None
        return result

    def _reweight_imu(
        self,
        graph: gtsam.NonlinearFactorGraph,
        result: gtsam.Values,
        params: gtsam.LevenbergMarquardtParams,
    ) -> gtsam.Values:
        """Variance-component rounds on the accelerometer (see `final_batch`); sets `imu_check`
        and returns the result of the last round that converged."""
        ratio = first = self._imu_ratio(graph, result)
        above = self.cfg.backend.final_imu_reweight_above
        scale, after = 1.0, math.nan
        if 0.0 < above < ratio:
            for _ in range(REWEIGHT_ROUNDS):
                trial = scale * ratio
                g = self._imu_rescaled(graph, trial)
                again = self._optimize(g, result, params)
                if again is None:
                    break
                scale, result = trial, again
                ratio = after = self._imu_ratio(g, result)
                if ratio < REWEIGHT_DONE:
                    break
        self.imu_check = ImuCheck(first, scale, after)
        return result

    def _imu_ratio(self, graph: gtsam.NonlinearFactorGraph, result: gtsam.Values) -> float:
        """Chi-square per redundancy of the IMU factors over that of the stereo factors.

        Redundancy per group, each parameter counted in the group that determines it: an IMU
        factor has 15 residuals, 9 of which fix its keyframe's velocity and biases (6 left); the
        stereo observations have 3 residuals each, less 3 per landmark and 6 per keyframe pose."""
        chi_imu = chi_st = 0.0
        n_imu = n_st = 0
        landmarks: set[int] = set()
        poses: set[int] = set()
        for i in range(graph.size()):
            f = graph.at(i)
            if isinstance(f, gtsam.CombinedImuFactor):
                chi_imu += 2.0 * f.error(result)
                n_imu += 1
            elif isinstance(f, gtsam.GenericStereoFactor3D):
                chi_st += 2.0 * f.error(result)  # Huber: outliers count linearly
                n_st += 1
                pose_key, lm_key = f.keys()
                poses.add(pose_key)
                landmarks.add(lm_key)
        r_imu = 6 * n_imu
        r_st = 3 * n_st - 3 * len(landmarks) - 6 * len(poses)
        if r_imu <= 0 or r_st <= 0 or chi_st <= 0.0:
            return math.nan
        return (chi_imu / r_imu) / (chi_st / r_st)

    def _imu_rescaled(
        self, graph: gtsam.NonlinearFactorGraph, accel_scale: float
    ) -> gtsam.NonlinearFactorGraph:
        """The graph with every IMU factor preintegrated again, the accelerometer's covariances
        scaled."""
        params = make_params(self.imu_calib, self.cfg.imu, accel_scale)
        t = self.segment.kf_times
        out = gtsam.NonlinearFactorGraph()
        for i in range(graph.size()):
            f = graph.at(i)
            if isinstance(f, gtsam.CombinedImuFactor):
                x0, v0, x1, v1, b0, b1 = f.keys()
                k = gtsam.Symbol(x1).index() - self.segment.kf_index0
                pim = gtsam.PreintegratedCombinedMeasurements(
                    params, f.preintegratedMeasurements().biasHat()
                )
                integrate(pim, self.imu, t[k - 1], t[k])
                f = gtsam.CombinedImuFactor(x0, v0, x1, v1, b0, b1, pim)
            out.add(f)
        return out

    def imu_bridge(self, k: int, t_ns: list[int]) -> list[F64] | None:
        """Poses at `t_ns` (sorted, after final keyframe k and not after k+1) from the IMU:
        preintegrated from keyframe k's final state, with the residual at k+1 (its final pose
        against the prediction) spread linearly in time; after the last keyframe, the
        prediction alone. None without IMU, with a dropout, or outside that span."""
        a, b = self.final_states.get(k), self.final_states.get(k + 1)
        if not self.use_imu or a is None or not t_ns or t_ns[0] < a.t_ns:
            return None
        if b is None and k + 1 < len(self.segment.kf_times):
            return None  # k + 1 exists but has no final state
        if b is not None and t_ns[-1] > b.t_ns:
            return None
        ab = bias(a.bg, a.ba)
        pim = gtsam.PreintegratedCombinedMeasurements(self.params, ab)
        nav = gtsam.NavState(
            gtsam.Rot3(a.T_world_body[:3, :3]), gtsam.Point3(*a.T_world_body[:3, 3]), a.v_world
        )
        pred, t_prev = [], a.t_ns
        for t in [*t_ns] + ([b.t_ns] if b is not None else []):
            if not integrate(pim, self.imu, t_prev, t).ok(self.cfg.imu.max_gap_s):
                return None
            t_prev = t
            pred.append(pim.predict(nav, ab).pose().matrix())
        if b is None:
            return pred
        end = pred.pop()
        dp = b.T_world_body[:3, 3] - end[:3, 3]
        dw = so3_log(b.T_world_body[:3, :3] @ end[:3, :3].T)
        span = float(b.t_ns - a.t_ns)
        out = []
        for t, T in zip(t_ns, pred, strict=True):
            s = (t - a.t_ns) / span
            out.append(make_T(so3_exp(s * dw) @ T[:3, :3], T[:3, 3] + s * dp))
        return out
