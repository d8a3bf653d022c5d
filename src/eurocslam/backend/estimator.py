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

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, V, X
from numpy.typing import NDArray

from eurocslam.backend.factors import ImuModel, StereoModel, pose
from eurocslam.backend.final_batch import (
    FinalBatchResult,
    SegmentGraph,
    final_batch,
    imu_bridge,
)
from eurocslam.backend.initializer import InitialState
from eurocslam.backend.landmarks import LandmarkKeys, landmark_indices
from eurocslam.backend.observations import StereoAdded, StereoObservations
from eurocslam.backend.pose_graph import LoopEdge, spread_loops
from eurocslam.backend.preintegration import bias, integrate
from eurocslam.backend.types import EstimatorFailure, KeyframeUpdate, NavEstimate, SegmentSolution
from eurocslam.camera import RectifiedStereo
from eurocslam.config import RunConfig
from eurocslam.dataset.calib import ImuCalib
from eurocslam.dataset.types import ImuData
from eurocslam.geometry import F64, inv_T, se3_adjoint


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
        self._obs = StereoObservations(cfg.backend, self._imu is not None, self._stereo, self._lms)
        self._seg = SegmentGraph()
        self._pim: gtsam.PreintegratedCombinedMeasurements | None = None
        self._pim_t_ns = 0
        self._pim_ok = True
        self._kf_estimates: dict[int, NavEstimate] = {}  # keyframe index -> smoothed estimate
        self._window: list[int] = []  # keyframe indices still in the smoother
        # loop closures: the edges found by place recognition, and for each keyframe where the
        # estimate was moved (`reanchor`), its pose before (for the final batch's start)
        self._loops: list[LoopEdge] = []
        self._before: dict[int, F64] = {}
        # added to the smoother's covariance after a loop moved the estimate: the new smoother
        # starts from a prior, the moved pose is as uncertain as the loop made it
        self._cov_offset = np.zeros((6, 6))

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
        added = self._obs.add(
            0,
            init.T_world_body,
            landmark_ids,
            stereo_uv,
            stereo_sigma,
            graph,
            values,
            stamps,
            0.0,
            self._seg.final_only,
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
        pose_prior: F64 | None = None,
    ) -> KeyframeUpdate:
        """Add a keyframe at `t_ns` with its stereo observations; returns what the update
        changed. `stereo_sigma`: per observation, the pixel sigma in units of
        `backend.stereo_sigma_px` (the keypoint's pyramid scale); None: 1 for all.
        `pose_prior`: the keyframe's pose as place recognition found it in this map
        (relocalization after a loss): it ties the keyframe to the map when nothing else does
        (an IMU dropout, a new local map)."""
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
        added = self._obs.add(
            k,
            T_guess,
            landmark_ids,
            stereo_uv,
            stereo_sigma,
            graph,
            values,
            stamps,
            tk,
            self._seg.final_only,
            after_loss=pose_prior is not None,
        )
        n_known = added.n_factors - added.n_new
        if pose_prior is not None:
            # the smoother holds the keyframe where the map puts it; the final batch only
            # loosely (the online map has drifted; the landmarks seen again tie it precisely)
            T_prior = pose(pose_prior)
            added.anchors.append(gtsam.PriorFactorPose3(X(k), T_prior, self._place_noise()))
            graph.add(gtsam.PriorFactorPose3(X(k), T_prior, self._place_noise(25.0)))
        elif not imu_link and n_known < self.cfg.backend.min_obs_without_imu:
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

    def _place_noise(self, scale: float = 1.0) -> gtsam.noiseModel.Base:
        b = self.cfg.backend
        return gtsam.noiseModel.Diagonal.Sigmas(
            scale * np.array([b.place_rot_sigma] * 3 + [b.place_pos_sigma] * 3)
        )

    # ---- uncertainty ----------------------------------------------------------------------------
    def pose_covariance(self) -> F64 | None:
        """The latest keyframe's pose covariance (6, 6) in the world frame: a left perturbation,
        [rotation, translation], from the smoother's marginal (which holds what the keyframes
        it marginalised knew). It grows where nothing observes the pose: with an IMU yaw and
        position, visual-only every direction. None where GTSAM cannot give it."""
        st = self._state
        assert st is not None
        try:
            if self._smoother is not None:
                cov = self._smoother.marginalCovariance(X(self._k))
            else:
                assert self._isam is not None
                cov = self._isam.marginalCovariance(X(self._k))
        except RuntimeError:
            return None
        A = se3_adjoint(st.T_world_body)
        return np.asarray(A @ cov @ A.T + self._cov_offset, dtype=np.float64)

    # ---- loop closure ---------------------------------------------------------------------------
    def reanchor(
        self, D: F64, loop: LoopEdge | None = None, cov_after: F64 | None = None
    ) -> KeyframeUpdate:
        """Move the estimate at the latest keyframe by `D` (corrected world <- drifted world),
        as a loop closure found it: a new smoother starts at the moved state (its pose, velocity
        and biases held by priors), the landmarks it held are moved with it, and the segment's
        graph keeps everything before plus the loop edge (`loop`, when its keyframe is in this
        segment) for the final batch, which starts from the keyframes spread over the loop
        (`pose_graph.spread_loops`). `cov_after`: the moved pose's covariance (world frame,
        as `pose_covariance`), from which later covariances grow."""
        st = self._state
        assert st is not None
        k = self._k
        self._before.setdefault(k, st.T_world_body)
        T = D @ st.T_world_body
        v = D[:3, :3] @ st.v_world
        moved = NavEstimate(st.t_ns, T, v, st.bg, st.ba)
        c = self.cfg.init
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        graph.add(gtsam.PriorFactorPose3(X(k), pose(T), self._place_noise()))
        graph.add(
            gtsam.PriorFactorVector(
                V(k), v, gtsam.noiseModel.Isotropic.Sigma(3, c.prior_vel_sigma_dynamic)
            )
        )
        b = bias(st.bg, st.ba)
        graph.add(
            gtsam.PriorFactorConstantBias(
                B(k),
                b,
                gtsam.noiseModel.Diagonal.Sigmas(
                    np.array([c.prior_accel_bias_sigma] * 3 + [c.prior_gyro_bias_sigma] * 3)
                ),
            )
        )
        values.insert(X(k), pose(T))
        values.insert(V(k), v)
        values.insert(B(k), b)
        tk = self._t(st.t_ns)
        stamps = {X(k): tk, V(k): tk, B(k): tk}
        # the old smoother's landmarks come back under new keys, anchored where they are now
        lms = self._lms
        act = np.nonzero(lms.active[: lms.n])[0]
        lms.pos[act] = lms.pos[act] @ D[:3, :3].T + D[:3, 3]
        lms.active[:] = False
        if loop is not None:
            self._loops.append(loop)
            self._seg.graph.add(
                gtsam.BetweenFactorPose3(
                    X(loop.k_cand), X(loop.k_query), pose(loop.T_cand_query), self._place_noise()
                )
            )
        self._make_smoother()
        self._window = []
        self._update_smoother(graph, values, stamps)
        self._state = moved
        update = self._read_state(k, st.t_ns)
        if cov_after is not None:
            self._cov_offset = np.zeros((6, 6))
            cov_prior = self.pose_covariance()
            if cov_prior is not None:
                self._cov_offset = cov_after - cov_prior
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

    # ---- smoother -------------------------------------------------------------------------------
    def _update(
        self,
        graph: gtsam.NonlinearFactorGraph,
        values: gtsam.Values,
        stamps: dict[int, float],
        added: StereoAdded | None = None,
    ) -> None:
        """One smoother update with `graph`; the segment's global graph takes the same factors
        (re-keyed where `added.subst` says) except the smoother-only anchors."""
        subst = added.subst if added is not None else {}
        for i in range(graph.size()):
            self._seg.graph.add(subst.get(i, graph.at(i)))
        if added is not None:
            for f in added.anchors:
                graph.add(f)
        self._update_smoother(graph, values, stamps)

    def _update_smoother(
        self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, stamps: dict[int, float]
    ) -> None:
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
        """One Levenberg-Marquardt over every factor of the segment (`final_batch.py`), started
        from the keyframes spread over the loops closed online, if any."""
        if self._loops or self._before:
            self._spread_loops()
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

    def _spread_loops(self) -> None:
        """Move every keyframe's pose and velocity, and every landmark with the keyframe that
        first saw it, by the pose graph's correction of that keyframe."""
        b = self.cfg.backend
        old = {k: e.T_world_body for k, e in self._kf_estimates.items()}
        new = spread_loops(old, self._before, self._loops, b.place_rot_sigma, b.place_pos_sigma)
        corr = {k: new[k] @ inv_T(old[k]) for k in old}
        for k, e in self._kf_estimates.items():
            R = corr[k][:3, :3]
            self._kf_estimates[k] = NavEstimate(e.t_ns, new[k], R @ e.v_world, e.bg, e.ba)
            self._seg.values[X(k)] = pose(new[k])
            if V(k) in self._seg.values:
                self._seg.values[V(k)] = R @ np.asarray(self._seg.values[V(k)])
        lms = self._lms
        for key in range(lms.n):
            C = corr.get(int(lms.first_kf[key]))
            if C is not None:
                lms.pos[key] = C[:3, :3] @ lms.pos[key] + C[:3, 3]
        self._loops, self._before = [], {}

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
            ids, xyz = self._lms.in_window()
            return SegmentSolution(kf, xyz.reshape(-1, 3), ids, {}, None)
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
        ids = self._lms.fid[np.array(list(res.landmarks), dtype=np.int64)]
        return SegmentSolution(res.poses, lm, ids, bridged, res.imu_check)

    def landmark_positions(self, ids: NDArray[np.int64]) -> F64:
        """The latest estimates (N, 3) of landmarks by frontend id (NaN: unknown here)."""
        lms = self._lms
        keys = np.array([lms.key_of.get(int(i), -1) for i in ids], dtype=np.int64)
        out = np.full((len(keys), 3), np.nan)
        ok = keys >= 0
        out[ok] = lms.pos[keys[ok]]
        return out
