"""Configuration of the estimator: noise in physical units, which energy terms, solver settings.

Every noise value is a standard deviation in pixels, metres or radians (never a hand-tuned loss weight);
the presets in ``configs/`` mirror these defaults.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from pedx_graph.data.calib import CalibrationLimits
from pedx_graph.data.ground import GroundConfig
from pedx_graph.data.reader import ReaderConfig


@dataclass
class PlausibilityConfig:
    """Limits of a plausible fitted track (:mod:`pedx_graph.solvers.plausibility`)."""

    enabled: bool = True
    """Check every fitted track; False writes whatever the solver returns."""
    max_distance_m: float = 200.0
    """Largest distance of the body centre from the rig's viewpoint, metres."""
    min_depth_m: float = 0.5
    """Smallest depth of the body centre in front of a camera that labels it, metres."""
    shape_support_margin: float = 0.25
    """A shape coefficient may exceed the shape prior's support (``noise.shape_support_sd`` prior SDs) by this
    much, in betas units, before the body counts as outside the prior."""
    max_abs_beta: float = 5.0
    """Largest ``|beta_i|`` when the fit has no shape support term (``noise.shape_support_sd`` 0 or inf)."""
    max_outlier_fraction: float = 0.7
    """Largest fraction of the 2D keypoint rows the reprojection term's robust loss may reject (real labels
    click some points where the body model does not put them — the head, the hips —, so a few keypoints
    can be outliers in every frame of a sound fit: the limit leaves room for that)."""
    max_lidar_outlier_fraction: float = 0.9
    """Largest fraction of the LiDAR rows the chamfer term's robust loss may reject (segments cut by loose
    polygons can be mostly background: only a nearly complete rejection says the data contradict)."""
    min_rows: int = 20
    """A data term with fewer rows than this in the track is not judged by ``max_outlier_fraction``."""


@dataclass
class NoiseConfig:
    """Measurement and prior noise, physical units."""

    keypoint_sigma_px: float = 3.0
    """Per-row sigma of joints marked visible, pixels, click noise and model error in one figure: used when no
    per-keypoint click noise is known (``keypoint_sigma_px_per_keypoint`` unset and no estimate from the
    data, e.g. ``fit_track`` called directly, or too few stereo clicks)."""
    keypoint_noise_from_data: bool = True
    """Estimate each keypoint's click noise from the dataset (vertical disparity of the clicks in both images
    of a rectified pair, :mod:`pedx_graph.data.noise_estimate`) before a dataset fit, and use it unless
    ``keypoint_sigma_px_per_keypoint`` is set; recorded in ``summary.json`` under ``noise``."""
    keypoint_sigma_px_per_keypoint: tuple[float, ...] | None = None
    """Click noise of one visible label, pixels per axis, 18 values in PEDX_KEYPOINTS order (an explicit
    override; ``fit_dataset`` fills it from the data estimate when unset).  When set, the per-row sigma is
    ``sqrt(click_k^2 + keypoint_model_sigma_px^2)`` (times ``hip_sigma_factor`` for the hips)."""
    keypoint_model_sigma_px: float = 2.2
    """Model-error term added in quadrature to the per-keypoint click noise, pixels: annotators click on a
    real body and the body model's keypoints are not exactly where they click; it also carries what the fit
    leaves unmodelled (priors, local minima).  On the simulator the labels are clicks on the model's own
    keypoints (residual at the truth = the click noise), yet with 0 here and 0 for ``lidar_model_sigma_m``
    the covariances were overconfident while the reprojection kernel acted on each row: keypoint NEES/dof
    1.62 (default rig) and 3.99 (PedX rig); with the kernel on each keypoint (2026-12-05) 0.96 and 2.27.
    Default: the part of the 3 px ``keypoint_sigma_px`` that the simulator's 2 px clicks do not explain
    (``sqrt(3^2 - 2^2)``), not tuned on either rig: NEES/dof 0.48 on the default rig (conservative) and
    0.75 / 96 % coverage on the PedX rig, against 2.70 / 88 % with 3 px on every keypoint
    (benchmarks/results/bench_noise.md)."""
    keypoint_noise_min_samples: int = 30
    """A keypoint with fewer stereo clicks than this in the dataset gets the pooled all-keypoint click noise;
    the whole dataset needs ``max(100, this)`` or there is no estimate (``keypoint_sigma_px`` is used)."""
    occluded_keypoint_sigma_px: float = 12.0
    """2D label noise of joints labelled but marked not visible (guessed by the annotator), pixels."""
    reprojection_loss: str = "geman_mcclure"
    """Robust loss of the reprojection term, on each keypoint's whitened 2D offset in each image (a label is
    kept or rejected with both coordinates): ``geman_mcclure``, ``huber``, ``cauchy`` or ``none``."""
    reprojection_loss_scale: float = 3.44
    """Scale of the robust reprojection loss in whitened units (multiples of the keypoint's sigma, on the
    length of its 2D offset).  Default: the length a Gaussian keypoint's 2D offset exceeds as often (0.27 %)
    as one coordinate exceeds 3 sigma, ``sqrt(-2 ln 0.0027)``, the per-coordinate scale 3 the loss had
    while it acted on each row alone."""
    left_right_swap_prob: float = 0.0
    """Prior probability that one image's labels of one left/right keypoint pair — or of every pair, the whole
    image — have the person's left and right exchanged (a click on the wrong side).  After the second stage
    an exchange is undone where the reprojection loss favours it by more than ``log((1 - p) / p)`` nats, at
    the body the neighbouring frames predict (whole images) or at the fitted body (single pairs), and the
    second stage runs again (:mod:`pedx_graph.solvers.mirror`; ``mirrored_labels`` in the track's report).
    0 (manual labels): the annotators' left and right are kept as they are.  A detector's tracks use
    ``detector_left_right_swap_prob`` instead (``pedx_graph.detections.fit_layout``)."""
    detector_left_right_swap_prob: float = 0.05
    """``left_right_swap_prob`` of tracks imported from a detector (another keypoint set than ``pedx18``):
    heatmap detectors take a wrist, knee or ankle for the other one, or a whole person seen from behind
    for one seen from the front, often with full confidence.  0.05: the simulator's detector model's
    per-pair rate (``DetectorNoiseConfig.swap_prob``)."""
    hip_sigma_factor: float = 2.0
    """Hip keypoints get ``hip_sigma_factor`` times the sigma: the model's hip joints sit inside the pelvis.
    PedX-format labels only: a detector track's hip rows project its keypoint set's own surface hips, whose
    noise is in their imported ``sigma_px`` (``pedx_graph.detections.fit_layout``)."""
    lidar_sigma_m: float = 0.04
    """Point-to-surface noise of the LiDAR chamfer term, metres (range noise + model/clothing mismatch in one
    figure): used when the range noise is not known (``lidar_range_sigma_m`` unset, no estimate)."""
    lidar_noise_from_data: bool = True
    """Estimate the LiDAR range noise from the segments (local fits along the rays,
    :mod:`pedx_graph.data.noise_estimate`) before a dataset fit and use it unless ``lidar_range_sigma_m`` is
    set; recorded in ``summary.json`` under ``noise``."""
    lidar_range_sigma_m: float | None = None
    """LiDAR range noise, metres (an explicit override; ``fit_dataset`` fills it from the data estimate when
    unset).  When set, the chamfer sigma is ``sqrt(lidar_range_sigma_m^2 + lidar_model_sigma_m^2)``."""
    lidar_model_sigma_m: float = 0.035
    """Model-error term of the chamfer added in quadrature to the range noise, metres: clothing, a body model
    that is not the true surface, and the chamfer's nearest-vertex correspondences, whose errors are not
    independent between points.  Not a measured surface mismatch: on the simulator the segment points lie
    1.2-1.3 cm per coordinate from the true body's chamfer vertices, range noise included.  Default: the part
    of the 4 cm ``lidar_sigma_m`` that the simulator's 2 cm range noise does not explain
    (``sqrt(4^2 - 2^2)``), as ``keypoint_model_sigma_px`` (benchmarks/results/bench_noise.md)."""
    lidar_noise_min_samples: int = 100
    """Fewer usable local-fit residuals than this in the dataset: no range-noise estimate (``lidar_sigma_m``)."""
    lidar_loss: str = "geman_mcclure"
    """Robust loss of the chamfer term (mislabeled points from the 2D polygons)."""
    lidar_loss_scale: float = 2.5
    """Scale of the robust chamfer loss in whitened units."""
    lidar_max_points: int = 150
    """At most this many instance points per frame enter the chamfer term (seeded subsample)."""
    lidar_seen_side: bool = True
    """The chamfer matches each LiDAR point only to model vertices facing the rig's viewpoint
    (``Track.ground.world_p_sensor``; :mod:`factors.lidar_chamfer`, "Seen side"): a return lies on the
    surface the sensor sees, so a body slid along the ray until its points sit on its flanks or back is
    penalised.  False: any vertex (the paper's plain chamfer)."""
    lidar_viewpoint_offset_m: float = 2.5
    """How far the LiDAR's centre may lie from the rig's viewpoint the seen-side test uses
    (``Track.ground.world_p_sensor``: the cameras' mean centre unless ``GroundConfig.sensor_xyz`` sets it),
    metres.  The real PedX rig's left cameras sit 2.3 m from its LiDAR (``simulate --rig pedx``).  With the
    points' range ``d`` a vertex still counts as facing while its normal is turned up to
    ``atan(offset / d) + lidar_normal_tolerance_deg`` past perpendicular to the ray."""
    lidar_normal_tolerance_deg: float = 5.0
    """Angular error allowed for the seen-side test's vertex normals, degrees (the rest template's normals
    turned by the skinning: 4 deg median error in strongly bent random poses)."""
    translation_sigma_m: float = 0.10
    """Translation prior: pelvis vs LiDAR points' mean, metres, across the viewing ray (paper Eq. 2)."""
    translation_ray_sigma_m: float = 0.20
    """Translation prior along the viewing ray, metres (the visible surface is in front of the root)."""
    translation_vertical_sigma_m: float = 0.25
    """Translation prior vertically, metres (which body parts the LiDAR sees changes the points' mean height)."""
    translation_loss: str = "cauchy"
    """Robust loss of the translation prior: a polygon that caught mostly background moves the mean by metres."""
    translation_loss_scale: float = 3.0
    """Scale of the robust translation loss in whitened units."""
    translation_depth_offset_m: float = 0.10
    """The pelvis lies this far behind the mean of the visible surface along the viewing ray, metres."""
    heading_sigma_rad: float = 0.35
    """Heading prior: body forward vs LiDAR-trajectory heading, radians, at walking speed."""
    heading_min_speed_mps: float = 0.3
    """Below this speed (m/s) the heading sigma grows as ``sigma * min_speed / speed`` (no direction at rest)."""
    joint_limit_sigma_rad: float = 0.05
    """Joint-limit hinge (knees, elbows do not bend backwards), radians."""
    ground_contact_sigma_m: float = 0.06
    """Ground contact (``factors.ground_contact``): the lower ankle stands its height above the sequence's
    ground plane (when the plane is known), within this many metres (Cauchy kernel); 0 switches the term
    off.  0.06 rather than the slightly better 0.03 on a flat ground: it also helps with the plane 15 cm
    below the feet, a pedestrian on a kerb (benchmarks/results/bench_ground_contact.md)."""
    shape_sigma: float = 1.0
    """Shape prior: betas ~ N(0, shape_sigma^2 I)."""
    shape_support_sd: float = 3.5
    """Support of the shape prior, in its standard deviations: a one-sided hinge holds every
    ``|beta_i| <= shape_support_sd * shape_sigma`` (``factors.shape_prior``).  The shape is shared by every
    frame of a track, so without it T frames of reprojection rows outweigh the single Gaussian prior where
    the data cannot fix size against depth (one camera, stereo at range).  0 or inf: no support term."""
    shape_support_sigma: float = 0.02
    """Width of the support hinge, betas units: a coefficient this far beyond the bound costs as much as one
    standard deviation of a Gaussian term (a stiff wall, continuously differentiable energy).  A data pull
    of gradient g (whitened, per unit of beta) ends ``g * shape_support_sigma^2`` past the bound: 0.04 for
    g = 100 (tests/test_shape_support_solvers.py: four frames pulling beta_0 to -30 end 0.055 past it)."""


@dataclass
class TermsConfig:
    """Which energy terms enter the graph (the paper's Table IV ablation switches)."""

    left_reprojection: bool = True
    """E_J,l: 2D keypoints in the left image (of every stereo pair used)."""
    right_reprojection: bool = True
    """E_J,r: 2D keypoints in the right image (of every stereo pair used)."""
    all_views: bool = True
    """Every stereo pair that labels the pedestrian at a frame enters its reprojection term (PedX: the two
    pairs' left cameras are ~0.93 m apart, 3x the in-pair baselines); False: the frame's primary pair only
    (the one with the most labelled keypoints)."""
    translation_prior: bool = True
    """E_T: translation prior to the LiDAR points' mean (paper Eq. 2)."""
    lidar_chamfer: bool = True
    """E_3d: LiDAR point to model surface distance (paper Eq. 4)."""
    heading_prior: bool = True
    """E_D: heading from the LiDAR trajectory (paper Eq. 3)."""
    pose_prior: bool = True
    """E_P: GMM pose prior and joint limits."""
    temporal_prior: bool = True
    """E_tp: GMM prior on consecutive-frame differences (paper Eq. 10)."""


@dataclass
class SolverConfig:
    """Levenberg-Marquardt settings."""

    backend: str = "python"
    """``python``: LM driven from Python (measured faster, benchmarks/results/bench_fit.md); ``gtsam``:
    gtsam's ``LevenbergMarquardtOptimizer``."""
    linearization: str = "batched"
    """Python LM only.  ``batched``: the graph's error and Gauss-Newton system from batched evaluations of
    all frames (``pedx_graph.solvers.batched``, equal to ``graph.linearize`` to round-off; needs
    ``linear_solver: chain``); ``graph``: ``graph.linearize`` with one Python callback per factor."""
    linear_solver: str = "chain"
    """Python LM only.  ``chain``: block Cholesky sweep over the track's chain of frames + shared shape
    (``pedx_graph.solvers.chain``); ``gtsam``: ``GaussianFactorGraph.optimize`` (sparse QR)."""
    max_iterations: int = 25
    """Maximum LM iterations."""
    relative_error_tol: float = 1e-3
    """Stop when the relative decrease of the error is below this."""
    lambda_initial: float = 1e-2
    """Initial LM damping."""
    lambda_max: float = 1e8
    """Give up increasing the damping past this."""
    coarse_max_iterations: int = 8
    """Iterations of the first stage (without the LiDAR chamfer term), a warm start for the full graph."""
    view_outlier_sigmas: float = 4.0
    """An image whose keypoints' median whitened reprojection residual exceeds this after the first stage (and
    ``view_outlier_ratio`` times that of the frame's images within it) is a suspect: a detection of someone
    else attached to the track, towards which the first stage's Gaussian loss bends the body by a few
    tenths of a metre along the other images' rays (the LiDAR chamfer's robust loss then rejects the
    person's own points).  The first stage runs again without the suspects; those still beyond this limit
    at its estimate are taken out of their frames' labels (``dropped_views`` in the track's report), the
    others kept.  A 2D keypoint's whitened error norm has median 1.18 under the noise model.  ``inf``
    keeps every image."""
    view_outlier_ratio: float = 2.0
    """... times the median of the frame's images within ``view_outlier_sigmas`` (the first stage stops after
    ``coarse_max_iterations``: every image of a frame can still sit a few sigma off; only frames with two
    images within the limit are screened: with one, which of two images is someone else's is not told
    apart)."""
    coarse_relative_error_tol: float = 1e-2
    """Relative-decrease tolerance of the first stage."""
    coarse_reprojection_loss: str = "none"
    """Robust loss of the stereo reprojection term in the first stage (a step of graduated non-convexity;
    ``noise.reprojection_loss`` in the second).  ``none`` (Gaussian): every 2D label pulls while the body is
    still far from it; with a saturating loss from the start, labels more than a few sigma from the
    template pose (e.g. a swinging arm) are treated as outliers and the fit stays in that local minimum
    (measured: benchmarks/results/bench_calibration.md, docs/estimator.md).  The same name as
    ``noise.reprojection_loss``: one graph for both stages."""
    flip_segments: tuple[str, ...] = ("right_upper_arm", "left_upper_arm", "right_forearm", "left_forearm")
    """Limb depth-flip search after the staged fit (:mod:`pedx_graph.solvers.flips`): each named bone
    segment is mirrored in depth in every frame, the track re-solved for ``flip_max_iterations`` and the
    mirror kept when the objective drops.  A swing along the viewing ray (walking towards or away from
    the camera) is nearly invisible to stereo at range.  Any of ``pedx_graph.solvers.flips.SEGMENTS``
    (thighs, shins too); the upper arms and forearms by default: on the benchmark scenes the thighs were
    rarely kept, the forearms brought the 35-45 m keypoint calibration into its goal
    (docs/estimator.md), and each tried segment costs ``flip_screen_iterations`` LM iterations.  Empty:
    no search."""
    flip_max_iterations: int = 8
    """LM iterations that judge one mirrored candidate, at most."""
    flip_screen_iterations: int = 8
    """A mirrored candidate whose error is not below the best after this many LM iterations is dropped
    (a wrong mirror starts far above and stays there).  3 sufficed while the reprojection kernel acted on
    each coordinate; with the kernel on whole keypoints a mirrored limb's labels carry little weight
    until the limb is near them, so it settles more slowly: on bench_solvers' track 66e5e454 no mirror
    is kept at 3 (67.8 mm), three are at 8 (objective 1436 -> 1088, 38.2 mm).  Equal to
    ``flip_max_iterations``: every candidate is judged after the same iterations."""
    flip_min_distance_m: float = 12.0
    """Tracks nearer than this (median camera distance) skip the flip search: stereo disparity resolves
    the swing depth there."""
    flip_max_heading_angle_deg: float = 60.0
    """Only tracks walking towards or away from the camera get the flip search: the median angle between
    the trajectory heading and the horizontal viewing ray (folded to 0-90 degrees) at most this.  Walking
    across the view, the swings show in the image and a mirrored limb is far off its labels."""


@dataclass
class MarginalsConfig:
    """How marginal covariances are computed and reported."""

    method: str = "chain"
    """``chain`` (forward-backward over the frames, fast) or ``gtsam`` (``gtsam.Marginals`` per frame)."""
    diffuse_information: float = 1e-6
    """Added to the diagonal of a frame's information block that is not positive definite (units^-2)."""
    max_trans_sigma_m: float = 5.0
    """Above this translation standard deviation (m) a frame's covariances are reported as null."""
    max_root_sigma_rad: float = 1.5
    """Above this root-orientation standard deviation (rad) a frame's covariances are reported as null."""
    body_pose_blocks: bool = True
    """Write the body pose covariance as 23 per-joint (3, 3) blocks (the full (69, 69) is in the API)."""
    chamfer_information: str = "point_to_plane"
    """Information of the LiDAR chamfer factors: ``point_to_plane`` (each point constrains only along the
    surface normal of its matched vertex, as the re-matched cost the solver minimises; see
    :mod:`pedx_graph.solvers.marginals`) or ``point_to_point`` (the factor's fixed-correspondence
    linearisation as is, overconfident along the surface).  Needs the factor kinds and the body model
    (``compute_marginals``'s ``factor_kinds`` and ``model``); without them the linearisation is used as is."""
    vertex_match_tol_m: float = 1e-6
    """A chamfer point's decoded vertex position must lie this close (m) to a posed mesh vertex."""


@dataclass
class DiagnosticsConfig:
    """Thresholds and reference scales of the diagnostics."""

    outlier_weight: float = 0.25
    """A residual row counts as an outlier when its robust weight is below this."""
    ref_root_rad: float = 0.1
    """Reference scale of the root orientation when ranking weak directions, radians."""
    ref_trans_m: float = 0.05
    """Reference scale of the translation, metres."""
    ref_body_pose_rad: float = 0.2
    """Reference scale of the body pose, radians."""
    ref_shape: float = 0.5
    """Reference scale of the shape coefficients."""
    worst_frames: int = 5
    """How many frames to list as the worst (highest chi2 per row) in the track summary."""
    consistency_quantile: float = 0.999
    """A non-robust factor with ``chi2`` above this quantile of ``chi2(rows)`` marks its frame inconsistent."""


@dataclass
class AdmmConfig:
    """ADMM settings (defaults: the paper's)."""

    rho: float = 2.0
    """Penalty of the consensus term rho/2 ||beta_k - beta + u_k||^2."""
    primal_tol: float = 0.05
    """Stop when every ||beta_k - beta|| is below this (and the dual residual too)."""
    dual_tol: float = 0.05
    """Stop when rho ||beta^t - beta^{t+1}|| is below this (and the primal residuals too)."""
    max_iterations: int = 50
    """Maximum ADMM iterations."""
    inner_iterations: int = 10
    """At most this many Levenberg-Marquardt iterations per frame subproblem and ADMM iteration (warm-started;
    stops earlier when the error decreases by less than ``inner_relative_tol``): each frame problem is
    solved to convergence, as in the paper.  Fewer iterations give an inexact, faster ADMM."""
    inner_relative_tol: float = 1e-3
    """Relative error decrease below which a frame subproblem counts as solved."""
    workers: int = 1
    """Processes solving the frames of one colour in parallel (1: in this process)."""


@dataclass
class FitConfig:
    """Everything the batch fit needs besides the data."""

    body_model: str = ""
    """Path of an SMPL-format model file; empty: the shipped open model."""
    pose_prior: str = ""
    """Path of a pose GMM ``.npz`` (``pedx-graph train-prior``); empty: the shipped prior."""
    temporal_prior: str = ""
    """Path of a temporal GMM ``.npz``; empty: the shipped prior."""
    keypoint_sets: str = ""
    """Folder of keypoint-set files (``<set>.json``, as ``pedx-graph calibrate-keypoints`` writes them: a
    detector's own points on the body model) whose definitions replace the shipped set of that name in the
    fit; empty: the shipped sets."""
    prior_covariance_scale: float = 3.0
    """Multiplies every covariance of the pose and the temporal GMM (1: the trained priors as they are).
    Inside a track the per-frame pose priors and the frame-to-frame temporal priors multiply, and that
    product holds a single frame's pose 2.5-11.5x (median 3.8) tighter in variance than the pose prior,
    which is the spread of real poses (``benchmarks/bench_calibration.py``, ``chain_prior_overcount``):
    the same prior knowledge is counted several times.  3 widens the product back to about the pose
    prior's spread (a little below the median, so that no dimension ends up much wider).  Measured against
    1 (docs/solvers.md): keypoint NEES/dof 1.33 -> 0.83, translation 1.59 -> 0.95, and MPJPE 50.5 -> 46.2 mm
    on the fit benchmark."""
    fps: float = 10.0
    """Frame rate of the synchronised samples (Hz): ``timestamp = frame / fps`` for a sequence without a
    timestamps file (the reader's; the temporal prior's frame gap follows from the timestamps)."""
    ground: GroundConfig = field(default_factory=GroundConfig)
    """How each sequence's up axis, ground plane and viewpoint are derived (overrides, robust-fit settings)."""
    chamfer_vertices: int = 1500
    """Number of model vertices (farthest-point subsample, fixed per model) the chamfer term matches against."""
    noise: NoiseConfig = field(default_factory=NoiseConfig)
    """Noise in physical units."""
    terms: TermsConfig = field(default_factory=TermsConfig)
    """Energy terms switched on."""
    solver: SolverConfig = field(default_factory=SolverConfig)
    """Solver settings."""
    seed: int = 0
    """Seed of every random choice (point subsampling)."""
    covariances: bool = True
    """Write marginal covariances (translation, root, body pose, 18 keypoints per frame; shape per track)."""
    diagnostics: bool = True
    """Write per-track diagnostics (residuals per factor type and frame, outliers, weakest directions)."""
    calibration_limits: CalibrationLimits = field(default_factory=CalibrationLimits)
    """Sanity limits of the calibration files (field of view, baseline, rotations, camera distance from the
    LiDAR origin); a pair outside them is refused with an error naming the file and key."""
    keypoint_margin: float = 0.05
    """2D keypoints more than this fraction of the image size outside the image are dropped with a warning; a
    label with more than half of its keypoints outside is skipped (``ReaderConfig.keypoint_margin``)."""
    plausibility: PlausibilityConfig = field(default_factory=PlausibilityConfig)
    """Limits of a plausible fitted track; a track outside them is recorded as failed with the reason and not
    written (:mod:`pedx_graph.solvers.plausibility`)."""
    marginals: MarginalsConfig = field(default_factory=MarginalsConfig)
    """How the marginal covariances are computed and when they are reported as null (with ``covariances``;
    also the stream's, :mod:`pedx_graph.solvers.marginals`)."""
    diagnostics_thresholds: DiagnosticsConfig = field(default_factory=DiagnosticsConfig)
    """Outlier threshold and reference scales of the per-track diagnostics (with ``diagnostics``;
    :mod:`pedx_graph.solvers.diagnostics`)."""
    admm: AdmmConfig = field(default_factory=AdmmConfig)
    """Settings of the ADMM reference solver (``pedx-graph fit --solver admm``, :mod:`pedx_graph.solvers.admm`)."""

    def reader_config(self) -> ReaderConfig:
        """The :class:`~pedx_graph.data.reader.ReaderConfig` this fit reads its dataset with (fps, ground,
        calibration limits, keypoint margin)."""
        return ReaderConfig(fps=self.fps, ground=self.ground, calibration_limits=self.calibration_limits,
                            keypoint_margin=self.keypoint_margin)
