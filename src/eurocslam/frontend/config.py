"""Frontend / visual-odometry configuration (the `frontend:` section of `configs/euroc.yaml`).

Loaded with the other sections by `eurocslam.config` (unknown keys and wrong types are errors
there). Each field's range stands beside it (`limited`); `validate` checks them all
(`eurocslam.limits.check_limits`) and names the file and key.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from eurocslam.errors import ConfigError
from eurocslam.limits import check_limits, limited


@dataclass(frozen=True)
class FrontendConfig:
    # ---- ORB features (features.py) ------------------------------------------------------
    n_features: int = limited(1000, ge=50)  # keypoints kept per image after grid bucketing
    grid_cols: int = limited(8, ge=1)  # bucketing grid over the image
    grid_rows: int = limited(6, ge=1)
    orb_scale_factor: float = limited(1.2, gt=1.0, le=2.0)  # pyramid scale between levels
    orb_levels: int = limited(8, ge=1, le=12)  # as ORB-SLAM (scale range 3.6x)
    # FAST threshold (20 as in ORB-SLAM), and a second detection at `min_fast_threshold` when
    # an image (dark, low texture) gives < n_features
    fast_threshold: int = limited(20, ge=1, le=255)
    min_fast_threshold: int = limited(7, ge=1, le="fast_threshold")
    orb_harris_score: bool = False  # rank corners by Harris (slower) instead of FAST score
    # ORB detects factor * n_features before bucketing
    orb_candidates_factor: float = 2.5

    # ---- stereo rectification and matching (stereo.py, matching.py) ----------------------
    # cv2.stereoRectify alpha: 0 = only valid pixels
    rectify_alpha: float = limited(0.0, ge=0, le=1)
    # a rig whose cameras are not pinholes (a fisheye) is rectified through its camera models to
    # a pinhole of this horizontal field of view [deg], capped at the widest whose every pixel
    # both cameras see (camera.rectify_by_model); 0: the field of view at which the rectified
    # image keeps cam0's focal length (camera.centre_keeping_fov_deg: TUM-VI 106.6 deg); pinhole
    # rigs take `rectify_alpha` instead
    rectify_fov_deg: float = limited(120.0, ge=0, lt=180)  # 0, or >= 10
    # the rectified images' size for such a rig: "image", the raw image's (the focal length
    # follows from the field of view); "focal", the size that keeps cam0's own focal length
    # (the centre's resolution), growing with the field of view (camera.rectified_size)
    rectify_size: str = "image"
    # the disparity window, from the rig: from `stereo_min_disparity_px` (the farthest points a
    # stereo match can measure; 1 px: 48 m on EuRoC, 386 m on KITTI) up to the disparity of a
    # point `stereo_min_depth_baselines` baselines away (fx / that: 218 px on EuRoC)
    stereo_min_disparity_px: float = limited(1.0, gt=0)
    stereo_min_depth_baselines: float = limited(2.0, gt=0)
    stereo_row_tolerance_px: float = 2.0  # |vL - vR| allowed, times the octave scale
    stereo_max_hamming: int = 80  # descriptor distance accepted for a stereo match
    # best / second-best descriptor distance (distinct candidates)
    stereo_ratio: float = limited(0.9, gt=0, le=1)
    subpixel_half_window: int = limited(5, ge=1)  # SAD patch half size for sub-pixel disparity
    subpixel_search_px: int = limited(5, ge=1)  # +- search range of the SAD refinement

    # ---- temporal tracking (tracker.py) ---------------------------------------------------
    # projection search radius, as an angle (the prediction's error is angular): x fx gives
    # pixels (1.3 deg: 9.9 px on EuRoC's 436 px focal length, 16 px on KITTI's 719), times the
    # keypoint's octave scale
    track_radius_deg: float = limited(1.3, gt=0, lt=30)
    track_max_hamming: int = 80
    track_ratio: float = limited(0.9, gt=0, le=1)
    min_tracked: int = limited(20, ge=6)  # fewer pose inliers than this: LOST
    pnp_reprojection_px: float = 3.0  # solvePnPRansac inlier threshold
    pnp_iterations: int = 200
    pose_chi2_stereo: float = 7.815  # chi-square 95 % (3 dof) for stereo outliers, 1 px sigma
    pose_chi2_mono: float = 5.991  # 2 dof
    # sanity bounds on the constant-velocity model (a car on a road: 10-40 m/s)
    max_velocity_m_s: float = 50.0
    max_angular_velocity_rad_s: float = 10.0
    # the predicted pose (the caller's or the constant-velocity model's) seeds the projection
    # search; false: every frame is tracked from the last pose alone (a test that tracking does
    # not need a motion prior: the descriptor path then finds the pose)
    motion_prior: bool = True

    # ---- map management --------------------------------------------------------------------
    max_new_landmarks_per_keyframe: int = 400
    # close and far stereo points (ORB-SLAM's rule, 40 baselines: 4.4 m on EuRoC, 22 m on
    # KITTI, a disparity of fx / 40: 10.9 px and 18 px, a parallax angle of 1/40 rad on any rig;
    # no cut from the disparity noise did better on both, RESULTS.md "The far-point rule at two
    # baselines"): beyond, a depth rests on a disparity of a few pixels, and the tenths of a pixel
    # of bias a real rig's rectification leaves (a render does not) make it tens of percent
    # wrong at 1 px; such far points start landmarks only to make up `min_new_landmarks`
    # (closest first). 0: every stereo point alike. Visual-only runs take it (scale comes from
    # the stereo depths alone); stereo-inertial runs take `far_depth_baselines_inertial` (the
    # IMU measures scale, and the far landmarks' re-finding closes loops)
    far_depth_baselines: float = 40.0
    far_depth_baselines_inertial: float = 0.0
    min_new_landmarks: int = 200
    max_landmarks: int = 4000  # local map size cap (oldest culled first)
    landmark_max_unseen_s: float = 2.0  # culled when not matched for this long
    landmark_min_found_ratio: float = 0.25  # found / visible below this: culled
    landmark_min_visible_for_ratio: int = 8  # ... once predicted visible this many times
    # map reuse: landmarks culled for going unseen (found at least `archive_min_found` times)
    # are archived; at each keyframe the archive is projected and re-found landmarks come back
    # under their old ids, so the final batch ties the keyframes then and now (loop closure)
    reuse_map: bool = True
    archive_min_found: int = 3
    archive_max_landmarks: int = 100_000  # beyond: the least found are dropped
    # projection search radius (times the octave scale): the larger of an angle (x fx: the
    # pose's rotation error, which scales with the focal) and pixels (the keypoint's error and
    # the archived point's depth error seen from elsewhere, (z / b) sigma_d sin(parallax) px,
    # which do not shrink with the focal: a short-focal fisheye needs them); 0 px: the angle
    reuse_radius_deg: float = limited(0.8, gt=0, lt=30)
    reuse_radius_min_px: float = limited(0.0, lt=100)
    reuse_max_hamming: int = 50  # stricter than tracking: a wrong match is a wrong loop
    reuse_ratio: float = 0.8

    # ---- keyframe decision -----------------------------------------------------------------
    kf_max_interval_s: float = 0.5
    kf_min_tracked_ratio: float = 0.75  # tracked / tracked in the reference keyframe
    kf_min_tracked: int = 120  # fewer tracked landmarks than this: new keyframe
    # median shift of tracked features since the last keyframe, as an angle (x fx: pixels;
    # 3.3 deg: 25 px on EuRoC)
    kf_parallax_deg: float = 3.3

    # ---- degraded input --------------------------------------------------------------------
    image_min_std: float = 3.0  # below: blank image
    image_saturated_mean: float = 250.0  # above: saturated image
    image_dark_mean: float = 3.0  # below: black image
    # consecutive LOST tracked frames before re-creating the map (a frame left out by
    # `track_every` is no tracking attempt: not counted)
    reinit_after_lost_frames: int = 2

    # ---- execution -------------------------------------------------------------------------
    # extraction of the next frames (rectify, ORB, stereo matching) in worker processes while
    # the current one is tracked, decoding in a reader thread (frontend/workers.py)
    prefetch: bool = True
    prefetch_workers: int = limited(2, ge=1)  # worker processes
    # track one frame in N; the IMU gives the frames between their pose (stereo-inertial only).
    # 2 halves extraction and tracking (benchmarks/RESULTS.md, "Tracking every second frame")
    track_every: int = limited(1, ge=1)

    def for_mode(self, inertial: bool) -> FrontendConfig:
        """The tracker's configuration for a stereo-inertial or a visual-only run."""
        if not inertial:
            return self
        return dataclasses.replace(self, far_depth_baselines=self.far_depth_baselines_inertial)

    def validate(self, origin: str = "<config>") -> None:
        """Every value within its limits (`eurocslam.limits`)."""
        check_limits(self, "frontend", origin)
        if 0 < self.rectify_fov_deg < 10:
            raise ConfigError(
                f"{origin}: key 'frontend.rectify_fov_deg' value {self.rectify_fov_deg!r} out of "
                "range (must be 0 or >= 10)"
            )
