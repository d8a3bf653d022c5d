"""Keyframe factor graph: states X/V/B, explicit landmarks L, GTSAM smoother.

Graph per keyframe k (body = IMU frame, world = gravity-aligned, z up):

* stereo-inertial: `CombinedImuFactor(X(k-1), V(k-1), X(k), V(k), B(k-1), B(k))` from IMU
  preintegration between the keyframes (bias random walk included). Across an IMU dropout the
  IMU factor is replaced by a bias random-walk `BetweenFactor` and a loose velocity
  `BetweenFactor`: vision bridges it.
* visual-only: the same loose links and a weak prior on the (unused) biases; a keyframe that sees
  too few mapped landmarks is tied to the previous one by the frontend's relative motion.
* `GenericStereoFactor3D(X(k), L(j))` per stereo observation (uL, uR, v) in the rectified cam0
  frame, `body_P_sensor = T_body_rect0`, under a Huber loss. A stereo observation fixes a point
  in 3D, so landmarks never make the system rank-deficient.
* Priors on X(0), V(0), B(0) at initialisation (GTSAM 4.3 has no initial-bias covariance).

The smoother is an `IncrementalFixedLagSmoother` (or plain `ISAM2`). Fixed-lag pitfalls handled
here: every new key is given a timestamp (landmarks included), a landmark is re-stamped each
time it is observed, keys without values are never stamped, and a landmark that has been
marginalised and is seen again gets a fresh key (`landmarks.py`). Every factor is also kept in
the segment's global graph for the final batch (`final_batch.py`), which produces the final
(smoothed) trajectory.

Each update returns a `KeyframeUpdate`; `finish` returns the `SegmentSolution`. All GTSAM
failures (indeterminant system, NaN) surface as `EstimatorFailure`; the pipeline resets and
starts a new segment.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, L, V, X

from eurocslam.backend.factors import ImuModel, StereoModel, pose
from eurocslam.backend.final_batch import (
    FinalBatchResult,
    SegmentGraph,
    final_batch,
    imu_bridge,
)
from eurocslam.backend.initializer import InitialState
from eurocslam.backend.landmarks import LandmarkKeys, landmark_indices
from eurocslam.backend.preintegration import bias, integrate
from eurocslam.backend.types import EstimatorFailure, KeyframeUpdate, NavEstimate, SegmentSolution
from eurocslam.camera import RectifiedStereo, bucket_select
from eurocslam.config import RunConfig
from eurocslam.dataset.calib import ImuCalib
from eurocslam.dataset.types import ImuData
from eurocslam.geometry import F64, inv_T


@dataclass(frozen=True)
class _StereoAdded:
    """What `_add_stereo` put into a keyframe's graph: the factors the global graph takes
    instead (by index in the graph: those of landmarks whose smoother key is not their first),
    priors for the smoother alone (re-found landmarks anchored at their last position), the
    number of stereo factors and of new landmarks."""

    subst: dict[int, gtsam.NonlinearFactor]
    anchors: list[gtsam.NonlinearFactor]
    n_factors: int
    n_new: int


class KeyframeEstimator:
    """Keyframe-based smoother, stereo-inertial or visual-only (`cfg.mode`, resolved). One
    instance per trajectory segment."""

    def __init__(
        self, imu_calib: ImuCalib | None, stereo: RectifiedStereo, imu: ImuData, cfg: RunConfig
    ) -> None:
        self.cfg = cfg
        # the IMU's data and noise model; None: visual-only (no IMU factors, no prediction)
        if cfg.inertial and imu_calib is None:
            raise ValueError("stereo-inertial needs the IMU's calibration")
        self._imu = ImuModel(imu, imu_calib, cfg.imu) if cfg.inertial and imu_calib else None
        self._stereo = StereoModel(stereo, cfg.backend)
        # bias random walk between keyframes without an IMU factor (visual-only: the biases are
        # unused, kept determined by a prior; a nominal walk where the rig has no IMU)
        rw_gyro, rw_acc = (
            (imu_calib.gyro_random_walk, imu_calib.accel_random_walk) if imu_calib else (1e-4, 1e-3)
        )
        self._rw_gyro = rw_gyro * cfg.imu.gyro_bias_walk_scale
        self._rw_acc = rw_acc * cfg.imu.accel_bias_walk_scale
        self._make_smoother()
        self._k = -1  # index of the latest keyframe
        self._t0_ns = 0
        self._state: NavEstimate | None = None
        self._lms = LandmarkKeys()
        self._seg = SegmentGraph()
        self._pim: gtsam.PreintegratedCombinedMeasurements | None = None
        self._pim_t_ns = 0
        self._pim_ok = True
        self._kf_estimates: dict[int, NavEstimate] = {}  # keyframe index -> smoothed estimate
        self._window: list[int] = []  # keyframe indices still in the smoother

    # ---- setup ----------------------------------------------------------------------------------
    def _make_smoother(self) -> None:
        b = self.cfg.backend
        p = gtsam.ISAM2Params()
        p.setRelinearizeThreshold(b.relinearize_threshold)
        p.relinearizeSkip = b.relinearize_skip
        p.findUnusedFactorSlots = True
        self._smoother: gtsam.IncrementalFixedLagSmoother | None = None
        self._isam: gtsam.ISAM2 | None = None
        if b.smoother == "fixed_lag":
            self._smoother = gtsam.IncrementalFixedLagSmoother(b.lag_s, p)
        else:
            self._isam = gtsam.ISAM2(p)

    def _t(self, t_ns: int) -> float:
        return (t_ns - self._t0_ns) * 1e-9

    # ---- initialisation -------------------------------------------------------------------------
    def initialize(
        self,
        init: InitialState,
        landmark_ids: np.ndarray,
        stereo_uv: F64,
        stereo_sigma: F64 | None = None,
    ) -> KeyframeUpdate:
        """The first keyframe, with priors on its pose, velocity and biases."""
        c = self.cfg.init
        self._t0_ns = init.t_ns
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
        if self._imu is None:
            vel_sigma = 1.0
        bias_noise = gtsam.noiseModel.Diagonal.Sigmas(
            np.array([c.prior_accel_bias_sigma] * 3 + [c.prior_gyro_bias_sigma] * 3)
        )
        self._k = 0
        graph.add(gtsam.PriorFactorPose3(X(0), pose(init.T_world_body), pose_noise))
        graph.add(
            gtsam.PriorFactorVector(
                V(0),
                np.asarray(init.v_world, float),
                gtsam.noiseModel.Isotropic.Sigma(3, vel_sigma),
            )
        )
        b0 = bias(init.bg, init.ba)
        graph.add(gtsam.PriorFactorConstantBias(B(0), b0, bias_noise))
        values.insert(X(0), pose(init.T_world_body))
        values.insert(V(0), np.asarray(init.v_world, float))
        values.insert(B(0), b0)
        for key in (X(0), V(0), B(0)):
            stamps[key] = 0.0
        self._seg = SegmentGraph(kf_index0=0)
        self._seg.kf_times.append(init.t_ns)
        self._state = NavEstimate(
            init.t_ns,
            np.asarray(init.T_world_body, float),
            np.asarray(init.v_world, float),
            np.asarray(init.bg, float),
            np.asarray(init.ba, float),
        )
        self._reset_pim(init.t_ns, self._state)
        added = self._add_stereo(
            0, init.T_world_body, landmark_ids, stereo_uv, stereo_sigma, graph, values, stamps, 0.0
        )
        self._update(graph, values, stamps, added)
        return self._read_state(0, init.t_ns)

    # ---- IMU prediction ------------------------------------------------------------------------
    def _reset_pim(self, t_ns: int, st: NavEstimate) -> None:
        if self._imu is None:
            return
        self._pim = gtsam.PreintegratedCombinedMeasurements(self._imu.params, bias(st.bg, st.ba))
        self._pim_t_ns = t_ns
        self._pim_ok = True

    def _extend_pim(self, t_ns: int) -> None:
        assert self._pim is not None and self._imu is not None
        if t_ns <= self._pim_t_ns:
            return
        info = integrate(self._pim, self._imu.data, self._pim_t_ns, t_ns)
        if not info.ok(self.cfg.imu.max_gap_s):
            self._pim_ok = False
        self._pim_t_ns = t_ns

    def imu_ok_since_keyframe(self) -> bool:
        """No IMU dropout since the latest keyframe (always True visual-only)."""
        return self._pim_ok

    def _imu_links(self) -> bool:
        """The next keyframe is linked to the latest by an IMU factor."""
        return self._imu is not None and self._pim_ok

    def predict(self, t_ns: int) -> NavEstimate:
        """State at `t_ns` predicted from the latest keyframe state: IMU preintegration, or a
        constant-velocity model when visual-only or across an IMU dropout."""
        st = self._state
        assert st is not None
        dt = (t_ns - st.t_ns) * 1e-9
        if self._imu is not None:
            self._extend_pim(t_ns)
        if self._imu_links():
            assert self._pim is not None
            nav = gtsam.NavState(
                gtsam.Rot3(st.T_world_body[:3, :3]),
                gtsam.Point3(*st.T_world_body[:3, 3]),
                st.v_world,
            )
            pred = self._pim.predict(nav, bias(st.bg, st.ba))
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
    ) -> KeyframeUpdate:
        """Add a keyframe at `t_ns` with its stereo observations; returns what the update
        changed. `stereo_sigma`: per observation, the pixel sigma in units of
        `backend.stereo_sigma_px` (the keypoint's pyramid scale); None: 1 for all."""
        st = self._state
        assert st is not None
        k = self._k + 1
        pred = self.predict(t_ns)
        T_guess = T_world_body_guess if T_world_body_guess is not None else pred.T_world_body
        v_guess = pred.v_world
        imu_link = self._imu_links()
        if T_world_body_guess is not None and not imu_link:
            dt = max((t_ns - st.t_ns) * 1e-9, 1e-3)
            v_guess = (T_world_body_guess[:3, 3] - st.T_world_body[:3, 3]) / dt
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        stamps: dict[int, float] = {}
        dt = (t_ns - st.t_ns) * 1e-9
        if imu_link:
            assert self._pim is not None
            graph.add(
                gtsam.CombinedImuFactor(X(k - 1), V(k - 1), X(k), V(k), B(k - 1), B(k), self._pim)
            )
        else:
            self._add_loose_link(k, dt, graph)
        values.insert(X(k), pose(T_guess))
        values.insert(V(k), np.asarray(v_guess, float))
        values.insert(B(k), bias(st.bg, st.ba))
        tk = self._t(t_ns)
        for key in (X(k), V(k), B(k)):
            stamps[key] = tk
        added = self._add_stereo(
            k, T_guess, landmark_ids, stereo_uv, stereo_sigma, graph, values, stamps, tk
        )
        n_known = added.n_factors - added.n_new
        if not imu_link and n_known < self.cfg.backend.min_obs_without_imu:
            if self._imu is not None or T_world_body_guess is None:
                raise EstimatorFailure(
                    f"keyframe at t={t_ns} ns sees {n_known} mapped landmarks and has no IMU "
                    "constraint"
                )
            # visual-only: the frontend tracks landmarks the smoother no longer holds (unseen by
            # it for the lag: marginalised) or a new map; link the keyframe to the previous one
            # by the frontend's relative motion instead of failing
            T_rel = inv_T(st.T_world_body) @ np.asarray(T_world_body_guess)
            b = self.cfg.backend
            sig = np.array([b.vo_bridge_rot_sigma] * 3 + [b.vo_bridge_pos_sigma] * 3)
            graph.add(
                gtsam.BetweenFactorPose3(
                    X(k - 1), X(k), pose(T_rel), gtsam.noiseModel.Diagonal.Sigmas(sig)
                )
            )
        self._k = k
        self._seg.kf_times.append(t_ns)
        self._update(graph, values, stamps, added)
        update = self._read_state(k, t_ns)
        self._reset_pim(t_ns, update.nav)
        return update

    def _add_loose_link(self, k: int, dt: float, graph: gtsam.NonlinearFactorGraph) -> None:
        """No usable IMU between k-1 and k: bias random walk and a loose velocity link (vision
        fixes the pose); visual-only, a weak prior keeps the unused biases determined."""
        sg = self._rw_gyro * math.sqrt(max(dt, 1e-3))
        sa = self._rw_acc * math.sqrt(max(dt, 1e-3))
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
        if self._imu is None:
            graph.add(
                gtsam.PriorFactorConstantBias(
                    B(k), gtsam.imuBias.ConstantBias(), gtsam.noiseModel.Isotropic.Sigma(6, 1.0)
                )
            )

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
    ) -> _StereoAdded:
        """Stereo factors into `graph`; see `_StereoAdded` for what else comes back."""
        b = self.cfg.backend
        st = self._stereo.geometry
        lms = self._lms
        ids = np.asarray(landmark_ids, dtype=np.int64)
        uv = np.asarray(stereo_uv, dtype=np.float64).reshape(-1, 3)
        scale = (
            np.ones(len(uv))
            if stereo_sigma is None or len(stereo_sigma) != len(uv)
            else np.round(np.asarray(stereo_sigma, dtype=np.float64), 3)
        )
        # a landmark the smoother let go and the tracker re-found (map reuse) is anchored at its
        # last smoothed position: the online estimate stays in the frame of the map it returns
        # to instead of drifting away from it. The smoother alone takes these priors; the final
        # batch has the landmark's observations then and now on one variable instead
        anchor = (
            gtsam.noiseModel.Isotropic.Sigma(3, b.refound_prior_sigma_m)
            if b.refound_prior_sigma_m > 0
            else None
        )
        anchors: list[gtsam.NonlinearFactor] = []
        disp = uv[:, 0] - uv[:, 1]
        ok = np.isfinite(uv).all(axis=1) & (disp >= b.min_disparity_px)
        depth = np.where(ok, st.fx * st.baseline / np.where(ok, disp, 1.0), np.inf)
        idx = np.nonzero(ok)[0]
        cap = b.max_landmarks_per_keyframe if self._imu else b.max_landmarks_per_keyframe_no_imu
        final_cap = max(cap, b.final_max_landmarks_per_keyframe) if b.final_batch else cap
        extra = idx[:0]
        if idx.size > cap:
            # spread over the image (4 x 3 cells, round-robin), in each cell landmarks already
            # in the graph first, then the nearest: the nearest alone can crowd one region
            known = np.array([lms.is_active(int(ids[i])) for i in idx], dtype=bool)
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
            key_i = lms.key_of.get(fid)
            if key_i is None or not lms.active[key_i]:
                old = key_i
                key_i = lms.new_key(fid)
                Xw = world_point(i)
                values.insert(L(key_i), gtsam.Point3(*Xw))
                lms.pos[key_i] = Xw
                n_new += 1
                if anchor is not None and old is not None and lms.smoothed[old]:
                    anchors.append(gtsam.PriorFactorPoint3(L(key_i), lms.pos[old], anchor))
            stamps[L(key_i)] = tk  # new or re-observed: (re-)stamp
            obs = (uv[i, 0], uv[i, 1], uv[i, 2], float(scale[i]))
            gkey = int(lms.gkey[key_i])
            lms.nobs[gkey] += 1
            if gkey != key_i:
                subst[graph.size()] = self._stereo.factor(k, gkey, *obs)
            graph.add(self._stereo.factor(k, key_i, *obs))
        # beyond the smoother's cap: observations for the final batch alone. A landmark not yet
        # known gets a key that the smoother never holds (it re-keys it if it picks it later)
        for i in extra.tolist():
            fid = int(ids[i])
            key_i = lms.key_of.get(fid)
            if key_i is None:
                key_i = lms.new_key(fid)
                lms.active[key_i] = False
                lms.pos[key_i] = world_point(i)
            gkey = int(lms.gkey[key_i])
            lms.nobs[gkey] += 1
            self._seg.final_only.append((k, gkey, uv[i, 0], uv[i, 1], uv[i, 2], scale[i]))
        return _StereoAdded(subst, anchors, len(idx), n_new)

    # ---- smoother -------------------------------------------------------------------------------
    def _update(
        self,
        graph: gtsam.NonlinearFactorGraph,
        values: gtsam.Values,
        stamps: dict[int, float],
        added: _StereoAdded | None = None,
    ) -> None:
        """One smoother update with `graph`; the segment's global graph takes the same factors
        (re-keyed where `added.subst` says) except the smoother-only anchors."""
        subst = added.subst if added is not None else {}
        for i in range(graph.size()):
            self._seg.graph.add(subst.get(i, graph.at(i)))
        if added is not None:
            for f in added.anchors:
                graph.add(f)
        try:
            if self._smoother is not None:
                ts = gtsam.FixedLagSmootherKeyTimestampMap()
                for key, t in stamps.items():
                    ts.insert((key, t))
                self._smoother.update(graph, values, ts)
                est = self._smoother.calculateEstimate()
            else:
                assert self._isam is not None
                self._isam.update(graph, values)
                est = self._isam.calculateEstimate()
        except RuntimeError as e:
            raise EstimatorFailure(f"smoother update failed: {e}") from None
        self._est = est
        # landmarks still in the window, read in one call (keys sort 'l' before 'v': the
        # landmarks are the first rows of extractPoint3, which also returns the velocities)
        lidx = landmark_indices(est.keys())
        pts = np.asarray(gtsam.utilities.extractPoint3(est))[: lidx.size]
        self._lms.set_window(lidx, pts)

    def _read_state(self, k: int, t_ns: int) -> KeyframeUpdate:
        est = self._est
        T = est.atPose3(X(k)).matrix()
        v = np.asarray(est.atVector(V(k)))
        b = est.atConstantBias(B(k))
        ne = NavEstimate(t_ns, T, v, np.asarray(b.gyroscope()), np.asarray(b.accelerometer()))
        if not (np.all(np.isfinite(T)) and np.all(np.isfinite(v))):
            raise EstimatorFailure("non-finite state after update")
        self._state = ne
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
            self._kf_estimates[kk] = NavEstimate(
                self._seg.kf_times[kk],
                pose_kk.matrix(),
                v_kk,
                np.asarray(b_kk.gyroscope()),
                np.asarray(b_kk.accelerometer()),
            )
            self._seg.values[X(kk)] = pose_kk
            self._seg.values[V(kk)] = v_kk
            self._seg.values[B(kk)] = b_kk
        self._window = keep
        ids, xyz = self._lms.in_window()
        window = tuple((kk, self._kf_estimates[kk].T_world_body) for kk in keep)
        return KeyframeUpdate(k, ne, window, ids, xyz)

    # ---- the end of the segment ----------------------------------------------------------------
    def final_batch(self) -> FinalBatchResult:
        """One Levenberg-Marquardt over every factor of the segment (`final_batch.py`)."""
        b = self.cfg.backend
        return final_batch(
            self._seg,
            self._lms,
            self._kf_estimates,
            self._stereo,
            self._imu,
            b.final_imu_reweight_above,
            b.final_batch_max_iterations,
        )

    def imu_bridge(
        self, states: dict[int, NavEstimate], k: int, t_ns: list[int]
    ) -> list[F64] | None:
        """Poses at `t_ns` between keyframes k and k+1 of `states` from the IMU
        (`final_batch.imu_bridge`); None visual-only."""
        if self._imu is None:
            return None
        return imu_bridge(states, len(self._seg.kf_times), k, t_ns, self._imu)

    def finish(self, frames: list[tuple[int, int]]) -> SegmentSolution:
        """The segment's final solution. `frames`: (t_ns, keyframe index it hangs from, -1 for
        none) of every frame of the segment; with the IMU and the final batch, the frames
        between keyframes get their poses from the IMU between the keyframes' final states
        (their own tracking is noisier than the preintegration over < 0.5 s)."""
        if not self.cfg.backend.final_batch:
            kf = {k: e.T_world_body for k, e in self._kf_estimates.items()}
            return SegmentSolution(kf, self._lms.in_window()[1].reshape(-1, 3), {}, None)
        res = self.final_batch()
        groups: dict[int, list[int]] = {}
        kf_t = set(self._seg.kf_times)
        for i, (t, ref) in enumerate(frames):
            if ref >= 0 and t not in kf_t:
                groups.setdefault(ref, []).append(i)
        bridged: dict[int, F64] = {}
        for k, idx in groups.items():
            Ts = self.imu_bridge(res.states, k, [frames[i][0] for i in idx])
            if Ts is not None:
                bridged.update(zip(idx, Ts, strict=True))
        lm = np.array(list(res.landmarks.values())).reshape(-1, 3)
        return SegmentSolution(res.poses, lm, bridged, res.imu_check)
