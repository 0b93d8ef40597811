"""Training the pose and temporal GMM priors on the CMU clips (never on the hold-out).

Data: every CMU clip of :func:`pedx_graph.motion.list_clips` split ``"train"`` (hold-out = subject 08 and
clip 02_03, :data:`pedx_graph.motion.HOLDOUT`; asking for a hold-out clip raises :class:`HoldoutError`),
retargeted with :func:`pedx_graph.motion.load_cmu_clip` onto the default body model's rest skeleton
(``TrainConfig.rest_skeleton``) and, by default, mirrored left/right as augmentation.

Pose prior (paper E_P): ``n_pose`` (8) full-covariance components on the 69-d body pose (axis-angle of
joints 1..23, radians), frames sampled at ``pose_fps`` (30 Hz).

Temporal prior (paper Eq. 10): ``n_temporal`` (10) components on the 75-d frame-to-frame difference at
``dt = 1 / fps`` (0.1 s: PedX's LiDAR rate) -- exactly the definition of ``factors.temporal_prior``::

    d(i, j) = [ world_R_pelvis_i^T (pelvis_j - pelvis_i)     (3)  step in the body frame of frame i, m
                Log(world_R_pelvis_i^T world_R_pelvis_j)      (3)  root rotation step (local), rad
                body_pose_j - body_pose_i ]                   (69) body pose difference, rad

Expressing the step and the rotation in the body frame of frame i makes d independent of the walking
direction and of the world's axes (Y-up mocap and a LiDAR frame of any orientation give the same d). Pairs (i, j = i + dt) start
at every ``1 / (fps * oversample)`` s so all phases of the motion are used.

Covariances: scikit-learn's ``reg_covar`` adds a variance floor to every dimension. The pose default
(1e-2 rad^2) was chosen by leaving subject 07 out of the training clips (never the hold-out): mean
log-likelihood per frame on subject 07 for pose reg 1e-4 / 1e-3 / 1e-2 / 3e-2 = 32.4 / 39.3 / 48.6 / 39.0.
For the temporal prior the density criterion (temporal reg 1e-6 / 1e-5 / 1e-4 / 1e-3 = 177.5 / 168.3 /
160.1 / 141.0 on subject 07) picks a floor so tight that the prior overrules the measurements of another
person's gait: on a validation scene (procedural gait, no CMU hold-out clip, ``pedx-graph simulate
--seed 100 --pedestrians 10 --frames 40``) the fit's MPJPE global / root-relative was 125 / 43 mm with
1e-5, 70 / 37 mm with 1e-3 and 58 / 34 mm with 1e-2, so the default is 1e-2 (a floor of ~0.1 rad per 0.1 s
for every joint: cross-subject variation the ten components cannot represent). Dimensions that the
mocap cannot observe are exactly zero in every frame: collars, feet (toes) and hands are never moved by
the retargeting. Their rows and columns are replaced by an explicit variance (``unobserved_std``), so the
prior keeps them near zero without locking them.
"""
from __future__ import annotations

import datetime as _dt
import logging
import os
import platform
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pedx_graph.keypoints import SMPL_JOINTS
from pedx_graph.motion import (MotionClip, generic_rest_joints, is_holdout, list_clips, load_cmu_clip,
                               resample_clip)
from pedx_graph.priors.difference import temporal_difference
from pedx_graph.priors.gmm import GaussianMixturePrior, precision_cholesky_from_covariance
from pedx_graph.utils import atomic_write_json

log = logging.getLogger(__name__)

AXES = ("x", "y", "z")
#: Names of the 69 pose-prior dimensions.
POSE_DIMS: tuple[str, ...] = tuple(f"{SMPL_JOINTS[j]}.{a} (rad, axis-angle rel. parent)"
                                   for j in range(1, 24) for a in AXES)
#: Names of the 75 temporal-prior dimensions.
TEMPORAL_DIMS: tuple[str, ...] = (
    tuple(f"step.{a} (m, body frame of frame i)" for a in AXES)
    + tuple(f"root_rotation_step.{a} (rad, Log(R_i^T R_j))" for a in AXES)
    + tuple(f"d_{SMPL_JOINTS[j]}.{a} (rad, pose_j - pose_i)" for j in range(1, 24) for a in AXES))

POSE_FILE = "pose_gmm.npz"
TEMPORAL_FILE = "temporal_gmm.npz"
PROVENANCE_FILE = "provenance.json"


class HoldoutError(ValueError):
    """A hold-out clip was requested for training."""


@dataclass
class TrainConfig:
    """Settings of :func:`train_priors`."""

    fps: float = 10.0
    """Frame rate of the temporal prior (dt = 1 / fps seconds)."""
    pose_fps: float = 30.0
    """Rate at which frames are sampled for the pose prior."""
    oversample: int = 3
    """Temporal pairs start every 1 / (fps * oversample) s."""
    n_pose: int = 8
    """Components of the pose GMM."""
    n_temporal: int = 10
    """Components of the temporal GMM."""
    reg_covar_pose: float = 1e-2
    """Variance floor added to every pose dimension (rad^2)."""
    reg_covar_temporal: float = 1e-2
    """Variance floor added to every temporal dimension (m^2 or rad^2); chosen by fitting a validation
    scene, see the module docstring."""
    unobserved_std_pose: float = 0.15
    """Std (rad) given to pose dimensions that are constant in the data (collars, toes, hands)."""
    unobserved_std_temporal: float = 0.05
    """Std (rad per dt) given to temporal dimensions that are constant in the data."""
    mirror: bool = True
    """Add the left/right mirror image of every clip."""
    n_init: int = 3
    """k-means initialisations tried by scikit-learn (best likelihood kept)."""
    max_iter: int = 500
    """EM iterations per initialisation."""
    seed: int = 0
    """Random seed of the EM initialisation."""
    clips: tuple[str, ...] = ()
    """Clip names to train on (empty: every non-hold-out clip)."""
    rest_skeleton: str = "body"
    """Rest skeleton the clips are retargeted onto: "body" (the shipped default body model at betas = 0,
    so the poses are right for the model that is fitted) or "generic" (:func:`generic_rest_joints`)."""


def rest_joints_for(name: str) -> tuple[np.ndarray, str]:
    """(24, 3) rest joints of skeleton ``name`` ("body" or "generic") and a description for provenance."""
    if name == "generic":
        return generic_rest_joints(), "generic_rest_joints()"
    if name == "body":
        from pedx_graph.body.model import BodyModel, default_model_path
        path = default_model_path()
        if not path.is_file():
            raise FileNotFoundError(f"{path}: default body model not found; use rest_skeleton='generic'")
        model = BodyModel.load(path)
        return model.rest_joints(np.zeros(model.num_betas)), f"body model {path.name}, betas = 0"
    raise ValueError(f"rest_skeleton must be 'body' or 'generic', got {name!r}")


def assert_not_holdout(names) -> None:
    """Raise :class:`HoldoutError` if any clip name belongs to the hold-out set."""
    bad = sorted(n for n in names if is_holdout(n))
    if bad:
        raise HoldoutError(f"hold-out clip(s) {bad} may not be used for training (HOLDOUT = 08_*, 02_03)")


def pose_features(clip: MotionClip, pose_fps: float) -> np.ndarray:
    """(N, 69) body poses of ``clip`` resampled to ``pose_fps``."""
    return resample_clip(clip, pose_fps).body_pose_aa[:, 3:]


def temporal_features(clip: MotionClip, fps: float, oversample: int = 1) -> np.ndarray:
    """(N, 75) differences at dt = 1/fps, pairs starting every 1/(fps*oversample) s."""
    fine = resample_clip(clip, fps * oversample)
    rot = fine.world_R_pelvis
    pose = fine.body_pose_aa[:, 3:]
    k = oversample
    if fine.num_frames <= k:
        return np.zeros((0, 75))
    return temporal_difference(rot[:-k], fine.pelvis_world[:-k], pose[:-k],
                               rot[k:], fine.pelvis_world[k:], pose[k:])


def load_clips(motion_dir: str | os.PathLike | None, split: str, names: tuple[str, ...] = (),
               rest_joints: np.ndarray | None = None) -> list[MotionClip]:
    """Retargeted CMU clips of ``split`` ("train" or "holdout"), optionally only ``names``."""
    infos = list_clips(motion_dir, split)
    if names:
        known = {c.name for c in list_clips(motion_dir, "all")}
        missing = sorted(set(names) - known)
        if missing:
            raise ValueError(f"unknown clip name(s) {missing} (not in clips.csv)")
        infos = [c for c in infos if c.name in set(names)]
    if split == "train":
        assert_not_holdout([c.name for c in infos])
    rest = generic_rest_joints() if rest_joints is None else rest_joints
    return [load_cmu_clip(c.path, rest_joints=rest, meta={"category": c.category}) for c in infos]


def _floor_unobserved(prior_cov: np.ndarray, data: np.ndarray, std: float) -> tuple[np.ndarray, list[int]]:
    """Replace rows/columns of dimensions constant in ``data`` by ``std**2`` on the diagonal."""
    fixed = [int(d) for d in np.flatnonzero(data.std(axis=0) < 1e-9)]
    cov = prior_cov.copy()
    if fixed:
        cov[:, fixed, :] = 0.0
        cov[:, :, fixed] = 0.0
        cov[:, fixed, fixed] = std ** 2
    return cov, fixed


def fit_gmm(name: str, data: np.ndarray, n_components: int, reg_covar: float, unobserved_std: float,
            dims: tuple[str, ...], cfg: TrainConfig, dt: float | None = None) -> GaussianMixturePrior:
    """Fit a full-covariance GMM (scikit-learn EM, seeded) and floor the unobserved dimensions."""
    from sklearn.mixture import GaussianMixture
    if data.shape[0] < 10 * n_components:
        raise ValueError(f"{name} prior: only {data.shape[0]} samples for {n_components} components")
    gmm = GaussianMixture(n_components=n_components, covariance_type="full", reg_covar=reg_covar,
                          n_init=cfg.n_init, max_iter=cfg.max_iter, random_state=cfg.seed)
    gmm.fit(data)
    cov, fixed = _floor_unobserved(gmm.covariances_, data, unobserved_std)
    chol = precision_cholesky_from_covariance(cov)
    eig = np.linalg.eigvalsh(cov)
    meta = {"converged": bool(gmm.converged_), "n_iter": int(gmm.n_iter_), "n_samples": int(data.shape[0]),
            "unobserved_dims": [dims[d] for d in fixed],
            "max_condition_number": float((eig[:, -1] / eig[:, 0]).max())}
    return GaussianMixturePrior(name=name, weights=gmm.weights_, means=gmm.means_, covariances=cov,
                                precisions_cholesky=chol, dims=dims, dt=dt, meta=meta)


def build_features(clips: list[MotionClip], cfg: TrainConfig, mirror: bool) -> tuple[np.ndarray, np.ndarray]:
    """Stacked pose (N, 69) and temporal (M, 75) features of ``clips`` (plus mirrors if ``mirror``)."""
    poses, temps = [], []
    for clip in clips:
        for c in ((clip, clip.mirrored()) if mirror else (clip,)):
            poses.append(pose_features(c, cfg.pose_fps))
            temps.append(temporal_features(c, cfg.fps, cfg.oversample))
    return np.concatenate(poses), np.concatenate(temps)


@dataclass
class TrainResult:
    """What :func:`train_priors` produced."""

    pose: GaussianMixturePrior
    """The pose prior."""
    temporal: GaussianMixturePrior
    """The temporal prior."""
    provenance: dict = field(default_factory=dict)
    """Provenance written next to the priors."""


def train_priors(motion_dir: str | os.PathLike | None = None, out_dir: str | os.PathLike | None = None,
                 cfg: TrainConfig | None = None, evaluate_holdout: bool = True) -> TrainResult:
    """Train both priors on the non-hold-out CMU clips; write them to ``out_dir`` if given.

    Files: ``pose_gmm.npz``, ``temporal_gmm.npz`` (:meth:`GaussianMixturePrior.save_npz`) and
    ``provenance.json`` (clips, settings, versions, mean log-likelihood per frame on the training data and
    on the hold-out clips, which are read for that evaluation only).
    """
    cfg = cfg or TrainConfig()
    assert_not_holdout(cfg.clips)
    import sklearn
    rest, rest_desc = rest_joints_for(cfg.rest_skeleton)
    train = load_clips(motion_dir, "train", tuple(cfg.clips), rest)
    if not train:
        raise ValueError("no training clips selected")
    log.info("training on %d clips (mirror=%s)", len(train), cfg.mirror)
    pose_x, temp_x = build_features(train, cfg, cfg.mirror)
    dt = 1.0 / cfg.fps
    pose = fit_gmm("pose", pose_x, cfg.n_pose, cfg.reg_covar_pose, cfg.unobserved_std_pose, POSE_DIMS, cfg)
    temporal = fit_gmm("temporal", temp_x, cfg.n_temporal, cfg.reg_covar_temporal, cfg.unobserved_std_temporal,
                       TEMPORAL_DIMS, cfg, dt=dt)
    evaluation = {"train": {"pose_ll_per_frame": float(pose.log_density(pose_x).mean()),
                            "temporal_ll_per_frame": float(temporal.log_density(temp_x).mean()),
                            "frames_pose": int(len(pose_x)), "frames_temporal": int(len(temp_x))}}
    holdout_names: list[str] = []
    if evaluate_holdout:
        hold = load_clips(motion_dir, "holdout", rest_joints=rest)
        holdout_names = [c.name for c in hold]
        if hold:
            hp, ht = build_features(hold, cfg, mirror=False)
            evaluation["holdout"] = {"pose_ll_per_frame": float(pose.log_density(hp).mean()),
                                     "temporal_ll_per_frame": float(temporal.log_density(ht).mean()),
                                     "frames_pose": int(len(hp)), "frames_temporal": int(len(ht))}
            evaluation["holdout_per_clip"] = {
                c.name: {"pose_ll_per_frame": float(pose.log_density(pose_features(c, cfg.pose_fps)).mean()),
                         "temporal_ll_per_frame": float(temporal.log_density(
                             temporal_features(c, cfg.fps, cfg.oversample)).mean())}
                for c in hold}
    provenance = {
        "created_utc": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "data": "CMU Graphics Lab Motion Capture Database (mocap.cmu.edu; NSF EIA-0196217), "
                "cgspeed Daz-friendly BVH release",
        "clips_train": [c.name for c in train], "clips_holdout_evaluated": holdout_names,
        "holdout_rule": "subject 08 (all clips) and clip 02_03 are never used for training",
        "retargeting": f"pedx_graph.motion.load_cmu_clip onto {rest_desc}, bones aligned",
        "config": {k: (list(v) if isinstance(v, tuple) else v) for k, v in cfg.__dict__.items()},
        "dt": dt, "temporal_definition": "d = [R_i^T (p_j - p_i), Log(R_i^T R_j), pose_j - pose_i]",
        "pose": {"components": cfg.n_pose, "dim": 69, **pose.meta},
        "temporal": {"components": cfg.n_temporal, "dim": 75, **temporal.meta},
        "log_likelihood": evaluation,
        "versions": {"scikit-learn": sklearn.__version__, "numpy": np.__version__,
                     "python": platform.python_version()},
    }
    pose = GaussianMixturePrior(**{**pose.__dict__, "meta": {"provenance": PROVENANCE_FILE, **pose.meta}})
    temporal = GaussianMixturePrior(**{**temporal.__dict__,
                                       "meta": {"provenance": PROVENANCE_FILE, **temporal.meta}})
    if out_dir is not None:
        out = Path(out_dir)
        pose.save_npz(out / POSE_FILE)
        temporal.save_npz(out / TEMPORAL_FILE)
        atomic_write_json(out / PROVENANCE_FILE, provenance)
    return TrainResult(pose, temporal, provenance)
