"""The allowed values of every configuration field, checked once at start-up (:func:`check_config`).

:func:`pedx_graph.config.load_config` calls :func:`check_config` on what it loaded, so a run refuses a bad
value before it creates any output, with one line naming the file and the key
(``fit.yaml: config key 'noise.keypoint_sigma_px' must be > 0, got -3.0``).  Rules are keyed by
``"<ClassName>.<field>"`` in :data:`RULES`; every number of every config (also in tuples) must be finite
unless its rule allows infinity, whether or not it has a rule.  ``None`` passes where the field's type allows
it.  :data:`CROSS_CHECKS` relate two fields of one class.  The simulator's :class:`~pedx_graph.sim.config.SimConfig`
keeps its own :meth:`~pedx_graph.sim.config.SimConfig.validate`, which :func:`check_config` also calls.
"""
from __future__ import annotations

import dataclasses
import importlib
import math
import numbers
from dataclasses import dataclass
from typing import Any, Callable

INF = math.inf


class ConfigError(ValueError):
    """A configuration file or field is malformed (bad YAML, unknown key, wrong type, value out of range).

    Defined here, below :mod:`pedx_graph.config` (which re-exports it), so that the range checks need nothing
    from the YAML loader."""


@dataclass(frozen=True)
class Range:
    """A number (or every number of a tuple, or of a mapping's values and their tuples) within ``lo``-``hi``."""

    lo: float = -INF
    hi: float = INF
    lo_open: bool = False
    hi_open: bool = False
    integer: bool = False
    """Whole numbers only."""
    allow_inf: bool = False
    """``inf`` is a value (e.g. "no limit")."""
    length: int | None = None
    """A tuple of exactly this many numbers."""

    def problem(self, value) -> str | None:
        if isinstance(value, dict):                         # e.g. keypoint set -> per-keypoint numbers
            return next((p for p in map(self.problem, value.values()) if p), None)
        values = list(value) if isinstance(value, (list, tuple)) else [value]
        if self.length is not None and (not isinstance(value, (list, tuple)) or len(values) != self.length):
            return f"must be {self.length} numbers"
        for v in values:
            if isinstance(v, bool) or not isinstance(v, numbers.Real):
                return "must be a number"
            v = float(v)
            if math.isnan(v) or (math.isinf(v) and not self.allow_inf):
                return "must be finite"
            if self.integer and v != int(v):
                return "must be a whole number"
            low_bad = v <= self.lo if self.lo_open else v < self.lo
            high_bad = v >= self.hi if self.hi_open else v > self.hi
            if low_bad or high_bad:
                return f"must be {self.describe()}"
        return None

    def describe(self) -> str:
        if self.hi == INF:
            return f"{'>' if self.lo_open else '>='} {self.lo:g}"
        if self.lo == -INF:
            return f"{'<' if self.hi_open else '<='} {self.hi:g}"
        return f"in {'(' if self.lo_open else '['}{self.lo:g}, {self.hi:g}{')' if self.hi_open else ']'}"


@dataclass(frozen=True)
class Choice:
    """A string (or every string of a tuple) among ``values``, or among ``module.attribute``'s keys (read when
    first checked, so this table imports nothing heavy)."""

    values: tuple[str, ...] = ()
    module: str = ""
    attribute: str = ""

    def allowed(self) -> list[str]:
        if self.module:
            return sorted(getattr(importlib.import_module(self.module), self.attribute))
        return list(self.values)

    def problem(self, value) -> str | None:
        values = list(value) if isinstance(value, (list, tuple)) else [value]
        allowed = self.allowed()
        for v in values:
            if not isinstance(v, str) or v not in allowed:
                return f"must be one of {allowed}"
        return None


POSITIVE = Range(0.0, lo_open=True)
NON_NEGATIVE = Range(0.0)
ANY = Range()
FRACTION = Range(0.0, 1.0)
OPEN_FRACTION = Range(0.0, 1.0, lo_open=True, hi_open=True)
COUNT = Range(1.0, integer=True)
NON_NEGATIVE_INT = Range(0.0, integer=True)
VECTOR3 = Range(length=3)
LOSSES = Choice(("geman_mcclure", "gemanmcclure", "huber", "cauchy", "none"))

#: ``"<ClassName>.<field>"`` -> the rule its value must meet (fields of bool or free text have none).
RULES: dict[str, Range | Choice] = {
    # pedx_graph.graph.config.FitConfig
    "FitConfig.prior_covariance_scale": POSITIVE,
    "FitConfig.fps": POSITIVE,
    "FitConfig.chamfer_vertices": COUNT,
    "FitConfig.seed": NON_NEGATIVE_INT,
    "FitConfig.keypoint_margin": Range(0.0, 10.0),
    # NoiseConfig
    "NoiseConfig.keypoint_sigma_px": POSITIVE,
    "NoiseConfig.keypoint_sigma_px_per_keypoint": Range(0.0, length=18),
    "NoiseConfig.keypoint_model_sigma_px": NON_NEGATIVE,
    "NoiseConfig.keypoint_noise_min_samples": COUNT,
    "NoiseConfig.occluded_keypoint_sigma_px": POSITIVE,
    "NoiseConfig.reprojection_loss": LOSSES,
    "NoiseConfig.reprojection_loss_scale": POSITIVE,
    "NoiseConfig.left_right_swap_prob": Range(0.0, 0.5, hi_open=True),
    "NoiseConfig.detector_left_right_swap_prob": Range(0.0, 0.5, hi_open=True),
    "NoiseConfig.hip_sigma_factor": POSITIVE,
    "NoiseConfig.lidar_sigma_m": POSITIVE,
    "NoiseConfig.lidar_range_sigma_m": NON_NEGATIVE,
    "NoiseConfig.lidar_model_sigma_m": NON_NEGATIVE,
    "NoiseConfig.lidar_noise_min_samples": COUNT,
    "NoiseConfig.lidar_loss": LOSSES,
    "NoiseConfig.lidar_loss_scale": POSITIVE,
    "NoiseConfig.lidar_max_points": COUNT,
    "NoiseConfig.lidar_viewpoint_offset_m": NON_NEGATIVE,
    "NoiseConfig.lidar_normal_tolerance_deg": Range(0.0, 90.0),
    "NoiseConfig.translation_sigma_m": POSITIVE,
    "NoiseConfig.translation_ray_sigma_m": POSITIVE,
    "NoiseConfig.translation_vertical_sigma_m": POSITIVE,
    "NoiseConfig.translation_loss": LOSSES,
    "NoiseConfig.translation_loss_scale": POSITIVE,
    "NoiseConfig.translation_depth_offset_m": ANY,
    "NoiseConfig.heading_sigma_rad": POSITIVE,
    "NoiseConfig.heading_min_speed_mps": NON_NEGATIVE,
    "NoiseConfig.joint_limit_sigma_rad": POSITIVE,
    "NoiseConfig.ground_contact_sigma_m": NON_NEGATIVE,
    "NoiseConfig.shape_sigma": POSITIVE,
    "NoiseConfig.shape_support_sd": Range(0.0, allow_inf=True),
    "NoiseConfig.shape_support_sigma": POSITIVE,
    # SolverConfig
    "SolverConfig.backend": Choice(("python", "gtsam")),
    "SolverConfig.linearization": Choice(("batched", "graph")),
    "SolverConfig.linear_solver": Choice(("chain", "gtsam")),
    "SolverConfig.max_iterations": NON_NEGATIVE_INT,
    "SolverConfig.relative_error_tol": NON_NEGATIVE,
    "SolverConfig.lambda_initial": POSITIVE,
    "SolverConfig.lambda_max": POSITIVE,
    "SolverConfig.coarse_max_iterations": NON_NEGATIVE_INT,
    "SolverConfig.coarse_relative_error_tol": NON_NEGATIVE,
    "SolverConfig.view_outlier_sigmas": Range(0.0, lo_open=True, allow_inf=True),
    "SolverConfig.view_outlier_ratio": POSITIVE,
    "SolverConfig.coarse_reprojection_loss": LOSSES,
    "SolverConfig.flip_segments": Choice(module="pedx_graph.solvers.flips", attribute="SEGMENTS"),
    "SolverConfig.flip_max_iterations": NON_NEGATIVE_INT,
    "SolverConfig.flip_screen_iterations": NON_NEGATIVE_INT,
    "SolverConfig.flip_min_distance_m": NON_NEGATIVE,
    "SolverConfig.flip_max_heading_angle_deg": Range(0.0, 90.0),
    # pedx_graph.data.ground.GroundConfig
    "GroundConfig.world_up": VECTOR3,
    "GroundConfig.ground_offset_m": ANY,
    "GroundConfig.sensor_xyz": VECTOR3,
    "GroundConfig.source": Choice(("auto", "pointclouds", "segments", "calibration")),
    "GroundConfig.max_camera_disagreement_deg": Range(0.0, 180.0, lo_open=True),
    "GroundConfig.max_ground_tilt_deg": Range(0.0, 90.0, lo_open=True),
    "GroundConfig.inlier_threshold_m": POSITIVE,
    "GroundConfig.min_ground_points": Range(3.0, integer=True),
    "GroundConfig.min_segment_feet": Range(3.0, integer=True),
    "GroundConfig.max_pointcloud_frames": NON_NEGATIVE_INT,
    "GroundConfig.max_fit_points": Range(3.0, integer=True),
    "GroundConfig.ransac_iterations": COUNT,
    # pedx_graph.data.calib.CalibrationLimits
    "CalibrationLimits.min_fov_deg": Range(0.0, 180.0, lo_open=True, hi_open=True),
    "CalibrationLimits.max_fov_deg": Range(0.0, 180.0, lo_open=True, hi_open=True),
    "CalibrationLimits.principal_point_margin": NON_NEGATIVE,
    "CalibrationLimits.rectified_focal_rel_tol": NON_NEGATIVE,
    "CalibrationLimits.rectified_row_tol_px": NON_NEGATIVE,
    "CalibrationLimits.min_baseline_m": NON_NEGATIVE,
    "CalibrationLimits.max_baseline_m": POSITIVE,
    "CalibrationLimits.max_camera_distance_m": POSITIVE,
    "CalibrationLimits.rotation_tol": POSITIVE,
    # pedx_graph.solvers.plausibility.PlausibilityConfig
    "PlausibilityConfig.max_distance_m": POSITIVE,
    "PlausibilityConfig.min_depth_m": NON_NEGATIVE,
    "PlausibilityConfig.shape_support_margin": NON_NEGATIVE,
    "PlausibilityConfig.max_abs_beta": POSITIVE,
    "PlausibilityConfig.max_outlier_fraction": Range(0.0, 1.0, lo_open=True),
    "PlausibilityConfig.max_lidar_outlier_fraction": Range(0.0, 1.0, lo_open=True),
    "PlausibilityConfig.min_rows": NON_NEGATIVE_INT,
    # pedx_graph.data.reader.ReaderConfig
    "ReaderConfig.fps": POSITIVE,
    "ReaderConfig.timestamps_kind": Choice(("pointclouds", "images")),
    "ReaderConfig.keypoint_margin": Range(0.0, 10.0),
    # pedx_graph.data.noise_estimate.NoiseEstimateConfig
    "NoiseEstimateConfig.min_keypoint_samples": COUNT,
    "NoiseEstimateConfig.min_total_samples": COUNT,
    "NoiseEstimateConfig.lidar_neighbours": Range(3.0, integer=True),
    "NoiseEstimateConfig.lidar_max_span_m": POSITIVE,
    "NoiseEstimateConfig.lidar_max_depth_step_m": POSITIVE,
    "NoiseEstimateConfig.lidar_max_slope": POSITIVE,
    "NoiseEstimateConfig.lidar_min_residuals": COUNT,
    "NoiseEstimateConfig.lidar_max_points": COUNT,
    # pedx_graph.solvers.stream.StreamConfig / isam.IsamConfig
    "StreamConfig.track_timeout_s": POSITIVE,
    "StreamConfig.heading_half_window_s": POSITIVE,
    "IsamConfig.relinearize_threshold_rad": POSITIVE,
    "IsamConfig.relinearize_threshold_m": POSITIVE,
    "IsamConfig.shape_relinearize_threshold": POSITIVE,
    "IsamConfig.shape_relinearize_every": NON_NEGATIVE_INT,
    "IsamConfig.relinearize_skip": COUNT,
    "IsamConfig.wildfire_threshold": NON_NEGATIVE,
    "IsamConfig.relinearize_window": NON_NEGATIVE_INT,
    "IsamConfig.presolve_iterations": NON_NEGATIVE_INT,
    "IsamConfig.presolve_method": Choice(("gn", "lm")),
    "IsamConfig.finalize": Choice(("lm", "isam")),
    "IsamConfig.finalize_max_updates": NON_NEGATIVE_INT,
    "IsamConfig.finalize_relative_tol": NON_NEGATIVE,
    "IsamConfig.num_betas": COUNT,
    # pedx_graph.graph.config.AdmmConfig
    "AdmmConfig.rho": POSITIVE,
    "AdmmConfig.primal_tol": POSITIVE,
    "AdmmConfig.dual_tol": POSITIVE,
    "AdmmConfig.max_iterations": COUNT,
    "AdmmConfig.inner_iterations": COUNT,
    "AdmmConfig.inner_relative_tol": NON_NEGATIVE,
    "AdmmConfig.workers": COUNT,
    # pedx_graph.solvers.marginals.MarginalsConfig
    "MarginalsConfig.method": Choice(("chain", "gtsam")),
    "MarginalsConfig.diffuse_information": NON_NEGATIVE,
    "MarginalsConfig.max_trans_sigma_m": POSITIVE,
    "MarginalsConfig.max_root_sigma_rad": POSITIVE,
    "MarginalsConfig.chamfer_information": Choice(("point_to_plane", "point_to_point")),
    "MarginalsConfig.vertex_match_tol_m": POSITIVE,
    # pedx_graph.solvers.diagnostics.DiagnosticsConfig
    "DiagnosticsConfig.outlier_weight": OPEN_FRACTION,
    "DiagnosticsConfig.ref_root_rad": POSITIVE,
    "DiagnosticsConfig.ref_trans_m": POSITIVE,
    "DiagnosticsConfig.ref_body_pose_rad": POSITIVE,
    "DiagnosticsConfig.ref_shape": POSITIVE,
    "DiagnosticsConfig.worst_frames": NON_NEGATIVE_INT,
    "DiagnosticsConfig.consistency_quantile": OPEN_FRACTION,
    # pedx_graph.baselines.smplify_disparity.SmplifyDispConfig
    "SmplifyDispConfig.keypoint_sigma_px": POSITIVE,
    "SmplifyDispConfig.occluded_keypoint_sigma_px": POSITIVE,
    "SmplifyDispConfig.reprojection_loss": LOSSES,
    "SmplifyDispConfig.reprojection_loss_scale": POSITIVE,
    "SmplifyDispConfig.hip_sigma_factor": POSITIVE,
    "SmplifyDispConfig.joint_limit_sigma_rad": POSITIVE,
    "SmplifyDispConfig.shape_sigma": POSITIVE,
    "SmplifyDispConfig.pose_prior_covariance_scale": POSITIVE,
    "SmplifyDispConfig.yaw_candidates_deg": ANY,
    "SmplifyDispConfig.min_keypoints": COUNT,
    "SmplifyDispConfig.default_depth_m": POSITIVE,
    "SmplifyDispConfig.rigid_stage_sigma": POSITIVE,
    # pedx_graph.eval: experiments, report, detector noise
    "ExperimentConfig.pedestrians": COUNT,
    "ExperimentConfig.frames": COUNT,
    "ExperimentConfig.baselines": Choice(module="pedx_graph.baselines.run", attribute="BASELINES"),
    "ExperimentConfig.floor_samples": COUNT,
    "SceneVariant.intersection_x_m": ANY,
    "SceneVariant.distance_mean_m": POSITIVE,
    "SceneVariant.distance_std_m": NON_NEGATIVE,
    "ReportConfig.floor_samples": COUNT,
    "ReportConfig.seed": NON_NEGATIVE_INT,
    # pedx_graph.export and the simulator's rendered images
    "ExportConfig.overlay_every": COUNT,
    "ExportConfig.overlay_scale": POSITIVE,
    "ExportConfig.fps": POSITIVE,
    "ImageConfig.scale": POSITIVE,
    "ImageConfig.jpeg_quality": Range(1.0, 100.0, integer=True),
    "DetectorNoiseConfig.sigma_px": NON_NEGATIVE,
    "DetectorNoiseConfig.sigma_height_frac": NON_NEGATIVE,
    "DetectorNoiseConfig.occluded_sigma_factor": POSITIVE,
    "DetectorNoiseConfig.miss_prob_visible": FRACTION,
    "DetectorNoiseConfig.miss_prob_occluded": FRACTION,
    "DetectorNoiseConfig.swap_prob": FRACTION,
    "DetectorNoiseConfig.outlier_prob": FRACTION,
    "DetectorNoiseConfig.polygon_scale_sigma": NON_NEGATIVE,
    "DetectorNoiseConfig.polygon_shift_frac": NON_NEGATIVE,
    "DetectorNoiseConfig.polygon_vertex_noise_px": NON_NEGATIVE,
    "DetectorNoiseConfig.segment_depth_gate_m": NON_NEGATIVE,
    # pedx_graph.detections.association.AssociationConfig, tracker.TrackerConfig, lidar_cut.LidarCutConfig
    "AssociationConfig.min_confidence": FRACTION,
    "AssociationConfig.min_shared_keypoints": Range(2.0, integer=True),
    "AssociationConfig.duplicate_frac": NON_NEGATIVE,
    "AssociationConfig.join_row_sigma": POSITIVE,
    # pedx_graph.detections.image_frame.ImageFrameConfig, frame_interval.WalkingCheckConfig
    "ImageFrameConfig.images": Choice(("auto", "raw", "rectified")),
    "ImageFrameConfig.min_matches": COUNT,
    "ImageFrameConfig.min_log_evidence": POSITIVE,
    "ImageFrameConfig.row_offset_sd_px": POSITIVE,
    "ImageFrameConfig.row_tilt_sd_px": POSITIVE,
    "ImageFrameConfig.max_frames": COUNT,
    "ImageFrameConfig.min_keypoints": Range(2.0, integer=True),
    "WalkingCheckConfig.walking_speed_mps": POSITIVE,
    "WalkingCheckConfig.min_walk_m": NON_NEGATIVE,
    "WalkingCheckConfig.min_frames": Range(2.0, integer=True),
    "WalkingCheckConfig.min_tracks": COUNT,
    "WalkingCheckConfig.max_ratio": Range(1.0, lo_open=True),
    # pedx_graph.detections.pixel_scale.PixelScaleConfig
    "PixelScaleConfig.scale": Range(0.0, 4.0),
    "PixelScaleConfig.units": Choice(("auto", "pixels", "unit", "signed_unit")),
    "PixelScaleConfig.min_keypoints": COUNT,
    "PixelScaleConfig.signed_fraction": FRACTION,
    "PixelScaleConfig.max_outside_fraction": FRACTION,
    "PixelScaleConfig.min_hit_points": COUNT,
    "PixelScaleConfig.depth_gate_m": POSITIVE,
    "PixelScaleConfig.disparity_sigma_px": NON_NEGATIVE,
    "PixelScaleConfig.ground_cell_m": POSITIVE,
    "PixelScaleConfig.ground_band_m": NON_NEGATIVE,
    "PixelScaleConfig.min_people": COUNT,
    "PixelScaleConfig.min_ratio": Range(1.0, lo_open=True),
    "PixelScaleConfig.tolerance": Range(0.0, 1.0, lo_open=True, hi_open=True),
    "PixelScaleConfig.max_frames": COUNT,
    "PixelScaleConfig.min_confidence": FRACTION,
    "FlipConfig.min_speed_mps": NON_NEGATIVE,
    "FlipConfig.velocity_window_frames": COUNT,
    "FlipConfig.body_sigma_m": NON_NEGATIVE,
    "FlipConfig.min_log_odds": NON_NEGATIVE,
    "FlipConfig.min_confidence": FRACTION,
    "FlipConfig.lateral_sigma_m": POSITIVE,
    "FlipConfig.max_direction_deg": Range(0.0, 180.0),
    "AssociationConfig.join_column_sigma": POSITIVE,
    "AssociationConfig.border_centre_steps": Range(0.0, integer=True),
    "AssociationConfig.pair_min_run_frames": COUNT,
    "AssociationConfig.feet_tolerance_m": POSITIVE,
    "AssociationConfig.keypoint_sigma_px": POSITIVE,
    "AssociationConfig.keypoint_sigma_frac": NON_NEGATIVE,
    "AssociationConfig.size_sigma": POSITIVE,
    "AssociationConfig.gate_sigmas": POSITIVE,
    "AssociationConfig.min_depth_m": POSITIVE,
    "AssociationConfig.max_depth_m": POSITIVE,
    "AssociationConfig.merge_distance_m": NON_NEGATIVE,
    "AssociationConfig.centre_lateral_sigma_m": POSITIVE,
    "AssociationConfig.merge_min_shared_frames": COUNT,
    "AssociationConfig.min_distance_m": NON_NEGATIVE,
    "AssociationConfig.max_distance_m": Range(0.0, allow_inf=True),
    "AssociationConfig.lidar_min_points": COUNT,
    "AssociationConfig.lidar_agreement_m": NON_NEGATIVE,
    "AssociationConfig.lidar_sigma_m": POSITIVE,
    "AssociationConfig.person_height_m": POSITIVE,
    "AssociationConfig.person_height_sigma": POSITIVE,
    "AssociationConfig.disparity_smooth_px": NON_NEGATIVE,
    "AssociationConfig.tracklet_switch_cost": NON_NEGATIVE,
    "AssociationConfig.swap_motion_m": NON_NEGATIVE,
    "AssociationConfig.swap_size_frac": NON_NEGATIVE,
    "AssociationConfig.min_height_frames": COUNT,
    "AssociationConfig.lone_height_gate_sigmas": Range(0.0, lo_open=True, allow_inf=True),
    "AssociationConfig.end_gap_frames": COUNT,
    "AssociationConfig.backward_birth_frames": NON_NEGATIVE_INT,
    "AssociationConfig.stitch_max_gap_frames": NON_NEGATIVE_INT,
    "AssociationConfig.min_separation_m": NON_NEGATIVE,
    "AssociationConfig.separate_max_rounds": NON_NEGATIVE_INT,
    "AssociationConfig.move_max_runs": NON_NEGATIVE_INT,
    "AssociationConfig.smooth_window_frames": NON_NEGATIVE_INT,
    "AssociationConfig.smooth_min_centres": COUNT,
    "AssociationConfig.smooth_motion_m": POSITIVE,
    "AssociationConfig.walking_speed_mps": NON_NEGATIVE,
    "AssociationConfig.lidar_cluster_gap_m": POSITIVE,
    "AssociationConfig.lidar_support_margin": FRACTION,
    "AssociationConfig.lidar_body_width_frac": NON_NEGATIVE,
    "AssociationConfig.lidar_context_frac": NON_NEGATIVE,
    "AssociationConfig.lidar_min_support": FRACTION,
    "AssociationConfig.lidar_identity_min_points": COUNT,
    "AssociationConfig.lidar_range_sigma_m": POSITIVE,
    "TrackerConfig.frame_interval_s": POSITIVE,
    "TrackerConfig.keypoint_sigma_px": POSITIVE,
    "TrackerConfig.motion_frac": NON_NEGATIVE,
    "TrackerConfig.lateral_sigma_m": POSITIVE,
    "TrackerConfig.accel_sigma_mps": NON_NEGATIVE,
    "TrackerConfig.max_speed_mps": POSITIVE,
    "TrackerConfig.gate_sigmas": POSITIVE,
    "TrackerConfig.min_box_iou": FRACTION,
    "TrackerConfig.size_sigma": NON_NEGATIVE,
    "TrackerConfig.range_sigma_m": NON_NEGATIVE,
    "TrackerConfig.velocity_smoothing": Range(0.0, 1.0, lo_open=True),
    "TrackerConfig.birth_min_score": FRACTION,
    "TrackerConfig.confirm_hits": COUNT,
    "TrackerConfig.tentative_max_misses": COUNT,
    "TrackerConfig.max_misses": COUNT,
    "TrackerConfig.min_track_frames": COUNT,
    "TrackerConfig.min_mean_score": FRACTION,
    "LidarCutConfig.dilate_frac": NON_NEGATIVE,
    "LidarCutConfig.dilate_px": NON_NEGATIVE,
    "LidarCutConfig.min_keypoints": Range(3.0, integer=True),
    "LidarCutConfig.gate_front_m": POSITIVE,
    "LidarCutConfig.gate_back_m": POSITIVE,
    "LidarCutConfig.depth_gate_sigmas": NON_NEGATIVE,
    "LidarCutConfig.cluster_gap_m": POSITIVE,
    "LidarCutConfig.min_cluster_points": COUNT,
    "LidarCutConfig.ground_clearance_m": ANY,
    "LidarCutConfig.beyond_border_m": NON_NEGATIVE,
    "LidarCutConfig.beyond_border_gap_m": POSITIVE,
    "LidarCutConfig.min_depth_m": NON_NEGATIVE,
    "LidarCutConfig.body_radius_m": NON_NEGATIVE,
    "LidarCutConfig.claim_sigma_m": NON_NEGATIVE,
    # pedx_graph.detections.importer.ImportConfig, noise.DetectionNoiseConfig (SigmaCurve checks itself)
    "ImportConfig.min_keypoints": COUNT,
    "ImportConfig.min_stereo_samples": COUNT,
    "ImportConfig.cloud_cache_mb": NON_NEGATIVE,
    "ReviewConfig.column_frac": NON_NEGATIVE,
    "ReviewConfig.max_height_ratio": Range(1.0),
    "ReviewConfig.ground_m": NON_NEGATIVE,
    "ReviewConfig.pad_frames": NON_NEGATIVE_INT,
    "ReviewConfig.frame_step": NON_NEGATIVE_INT,
    "ReviewConfig.min_confidence": FRACTION,
    "DetectionNoiseConfig.min_confidence": FRACTION,
    "DetectionNoiseConfig.annotation_sigma_px": POSITIVE,
    "DetectionNoiseConfig.occluded_sigma_factor": POSITIVE,
    "DetectionNoiseConfig.reference_height_px": POSITIVE,
    "DetectionNoiseConfig.floor_px": NON_NEGATIVE,
    "DetectionNoiseConfig.definition_sigma_m": NON_NEGATIVE,
    "DetectionNoiseConfig.keypoint_scale": POSITIVE,
    # pedx_graph.priors.train.TrainConfig
    "TrainConfig.fps": POSITIVE,
    "TrainConfig.pose_fps": POSITIVE,
    "TrainConfig.oversample": COUNT,
    "TrainConfig.n_pose": COUNT,
    "TrainConfig.n_temporal": COUNT,
    "TrainConfig.reg_covar_pose": NON_NEGATIVE,
    "TrainConfig.reg_covar_temporal": NON_NEGATIVE,
    "TrainConfig.unobserved_std_pose": POSITIVE,
    "TrainConfig.unobserved_std_temporal": POSITIVE,
    "TrainConfig.n_init": COUNT,
    "TrainConfig.max_iter": COUNT,
    "TrainConfig.seed": NON_NEGATIVE_INT,
    "TrainConfig.rest_skeleton": Choice(("body", "generic")),
}

#: ``(ClassName, check(config) -> bool, what must hold)`` relating fields of one config.
CROSS_CHECKS: list[tuple[str, Callable[[Any], bool], str]] = [
    ("CalibrationLimits", lambda c: c.min_fov_deg < c.max_fov_deg, "'min_fov_deg' < 'max_fov_deg'"),
    ("CalibrationLimits", lambda c: c.min_baseline_m < c.max_baseline_m, "'min_baseline_m' < 'max_baseline_m'"),
    ("AssociationConfig", lambda c: c.min_depth_m < c.max_depth_m, "'min_depth_m' < 'max_depth_m'"),
    ("AssociationConfig", lambda c: c.min_distance_m < c.max_distance_m, "'min_distance_m' < 'max_distance_m'"),
]

#: Config classes whose fields are not in :data:`RULES` because the class checks itself (``validate``).
SELF_CHECKED = ("SimConfig", "SceneConfig", "StereoPairConfig", "CamerasConfig", "LidarConfig", "LabelConfig",
                "MotionConfig", "OutputFrameConfig", "DetectorOutputConfig")


class _Problem(Exception):
    pass


def _check_value(value, rule, where: str) -> None:
    if value is None:
        return
    if rule is None:                                        # no rule: numbers must still be finite
        values = list(value) if isinstance(value, (list, tuple)) else [value]
        for v in values:
            if isinstance(v, numbers.Real) and not isinstance(v, bool) and not math.isfinite(float(v)):
                raise _Problem(f"config key '{where}' must be finite, got {value!r}")
        return
    problem = rule.problem(value)
    if problem:
        raise _Problem(f"config key '{where}' {problem}, got {value!r}")


def _walk(cfg, prefix: str) -> None:
    name = type(cfg).__name__
    for f in dataclasses.fields(cfg):
        value = getattr(cfg, f.name)
        where = f"{prefix}{f.name}"
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            _walk(value, where + ".")
        elif isinstance(value, list) and value and all(dataclasses.is_dataclass(v) for v in value):
            for i, item in enumerate(value):
                _walk(item, f"{where}[{i}].")
        elif not isinstance(value, bool):
            _check_value(value, RULES.get(f"{name}.{f.name}"), where)
    for cls_name, check, text in CROSS_CHECKS:
        if cls_name == name and not check(cfg):
            raise _Problem(f"config '{prefix.rstrip('.') or name}' needs {text}")


def check_config(cfg, source: str = "<config>"):
    """``cfg`` (any config dataclass, nested ones included) when every value is allowed (module docstring);
    :class:`ConfigError` naming ``source`` and the key otherwise."""
    try:
        _walk(cfg, "")
    except _Problem as exc:
        raise ConfigError(f"{source}: {exc}") from None
    validate = getattr(cfg, "validate", None)
    if callable(validate):
        validate(source)
    return cfg
