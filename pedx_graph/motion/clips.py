"""The common motion type (:class:`MotionClip`) and the index of the CMU pedestrian clips.

The CMU BVH files are optional material: nothing in the package *needs* them. :func:`default_motion_dir`
returns ``../shared/mocap/cmu`` relative to the project root when that folder exists, otherwise None.
"""
from __future__ import annotations

import csv
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pedx_graph.keypoints import SMPL_JOINTS

#: Hold-out set (never used for training priors): every clip of CMU subject 08, plus clip 02_03 (the only
#: run not by subject 09). Entries are clip names without ``.bvh``; a name ending in ``_*`` is a subject.
HOLDOUT: tuple[str, ...] = ("08_*", "02_03")

#: Left/right pairs of SMPL joint indices (used for mirroring).
SMPL_MIRROR_PERMUTATION: tuple[int, ...] = tuple(
    SMPL_JOINTS.index(n.replace("left_", "@").replace("right_", "left_").replace("@", "right_"))
    for n in SMPL_JOINTS)


def is_holdout(name: str) -> bool:
    """True when clip ``name`` (e.g. ``"08_03"`` or ``"08_03.bvh"``) belongs to :data:`HOLDOUT`."""
    stem = Path(name).name.removesuffix(".bvh")
    for entry in HOLDOUT:
        if entry.endswith("_*"):
            if stem.startswith(entry[:-1]):
                return True
        elif stem == entry:
            return True
    return False


@dataclass(frozen=True)
class MotionClip:
    """A body motion on SMPL's 24-joint tree, sampled at a fixed rate.

    World frame ("clip world"): Y up, metres, the floor is the plane ``y = floor_y``; the horizontal axes
    are those of the source (BVH world turned about Y so the figure's rest frame faces +Z, or the
    procedural path's frame). The body frame is SMPL's (Y up, +Z forward, +X to the body's left).

    ``body_pose_aa[t, 0:3]`` is the axis-angle of ``world_R_pelvis`` (the SMPL "global orient");
    ``body_pose_aa[t, 3j:3j+3]`` for j = 1..23 the axis-angle of ``parent_R_joint`` in SMPL's tree.

    ``pelvis_world[t]`` is the world position of SMPL joint 0 (pelvis). A body model that adds ``trans``
    after skinning (smplx, :mod:`pedx_graph.body`) puts its pelvis at ``J_0(betas) + trans``, so use
    ``trans = pelvis_world - J_0(betas)`` (:meth:`trans_for`).
    """

    name: str
    """Clip name (e.g. ``"07_01"`` or ``"gait-walk-1.30"``)."""
    fps: float
    """Frames per second."""
    body_pose_aa: np.ndarray
    """(T, 72) axis-angle pose, radians (joint 0 = world orientation of the pelvis)."""
    pelvis_world: np.ndarray
    """(T, 3) pelvis joint position in the clip world, metres."""
    source: str = ""
    """Where the motion came from (file name, or ``"procedural"``)."""
    floor_y: float = 0.0
    """Height of the floor plane in the clip world (Y up), metres."""
    meta: dict[str, Any] = field(default_factory=dict)
    """Free-form provenance (scale, subject, category, gait parameters...)."""

    def __post_init__(self) -> None:
        pose = np.asarray(self.body_pose_aa, dtype=float)
        pel = np.asarray(self.pelvis_world, dtype=float)
        if pose.ndim != 2 or pose.shape[1] != 72:
            raise ValueError(f"MotionClip '{self.name}': body_pose_aa must be (T, 72), got {pose.shape}")
        if pel.shape != (pose.shape[0], 3):
            raise ValueError(f"MotionClip '{self.name}': pelvis_world must be ({pose.shape[0]}, 3), got {pel.shape}")
        if not (np.all(np.isfinite(pose)) and np.all(np.isfinite(pel))):
            raise ValueError(f"MotionClip '{self.name}': non-finite pose or pelvis values")
        if not self.fps > 0:
            raise ValueError(f"MotionClip '{self.name}': fps must be > 0, got {self.fps}")
        object.__setattr__(self, "body_pose_aa", pose)
        object.__setattr__(self, "pelvis_world", pel)

    @property
    def num_frames(self) -> int:
        return int(self.body_pose_aa.shape[0])

    @property
    def duration(self) -> float:
        """Seconds from the first to the last frame."""
        return (self.num_frames - 1) / self.fps

    @property
    def times(self) -> np.ndarray:
        """(T,) frame times in seconds from the first frame."""
        return np.arange(self.num_frames) / self.fps

    @property
    def world_R_pelvis(self) -> np.ndarray:
        """(T, 3, 3) world orientation of the pelvis (body) frame."""
        from scipy.spatial.transform import Rotation
        return Rotation.from_rotvec(self.body_pose_aa[:, :3]).as_matrix()

    def trans_for(self, rest_pelvis: np.ndarray) -> np.ndarray:
        """(T, 3) ``trans`` for a body model whose rest pelvis joint is ``rest_pelvis`` (= J_0(betas))."""
        return self.pelvis_world - np.asarray(rest_pelvis, dtype=float).reshape(1, 3)

    def with_updates(self, **changes: Any) -> "MotionClip":
        """A copy with some fields replaced."""
        fields = dict(name=self.name, fps=self.fps, body_pose_aa=self.body_pose_aa,
                      pelvis_world=self.pelvis_world, source=self.source, floor_y=self.floor_y,
                      meta=dict(self.meta))
        fields.update(changes)
        return MotionClip(**fields)

    def rescaled(self, factor: float) -> "MotionClip":
        """The same motion for a body ``factor`` times as large: pelvis path scaled about the floor origin.

        Scaling the trajectory by the ratio of leg lengths keeps feet on the floor and strides consistent.
        """
        pel = self.pelvis_world.copy()
        pel[:, 1] = self.floor_y + factor * (pel[:, 1] - self.floor_y)
        pel[:, [0, 2]] *= factor
        return self.with_updates(pelvis_world=pel, meta={**self.meta, "rescaled": factor})

    def mirrored(self) -> "MotionClip":
        """Left/right mirror image (reflection x -> -x of world and body).

        Joints are swapped by :data:`SMPL_MIRROR_PERMUTATION`; a rotation vector ``(rx, ry, rz)`` maps to
        ``(rx, -ry, -rz)`` under the reflection diag(-1, 1, 1); the pelvis path gets ``x -> -x``.
        """
        aa = self.body_pose_aa.reshape(-1, 24, 3)[:, list(SMPL_MIRROR_PERMUTATION)].copy()
        aa[..., 1:] *= -1.0
        pel = self.pelvis_world.copy()
        pel[:, 0] *= -1.0
        return self.with_updates(name=self.name + "-mirror", body_pose_aa=aa.reshape(-1, 72),
                                 pelvis_world=pel, meta={**self.meta, "mirrored": True})

    def slice(self, start: int, stop: int | None = None) -> "MotionClip":
        """Frames ``start:stop``."""
        return self.with_updates(body_pose_aa=self.body_pose_aa[start:stop],
                                 pelvis_world=self.pelvis_world[start:stop])


@dataclass(frozen=True)
class ClipInfo:
    """One row of the CMU ``clips.csv`` index."""

    name: str
    """Clip name without extension, e.g. ``"07_01"``."""
    path: Path
    """The BVH file."""
    subject: str
    """CMU subject id, e.g. ``"07"``."""
    description: str
    """CMU description."""
    frames: int
    """Frame count including the T-pose frame 0."""
    fps: float
    """Frame rate of the file."""
    category: str
    """walk, run, turn, startstop or other."""

    @property
    def holdout(self) -> bool:
        return is_holdout(self.name)


def project_root() -> Path:
    """The folder holding the ``pedx_graph`` package (the project root in a source checkout)."""
    return Path(__file__).resolve().parents[2]


def default_motion_dir() -> Path | None:
    """``../shared/mocap/cmu`` relative to the project root if it exists (with a clips.csv), else None."""
    candidate = project_root().parent / "shared" / "mocap" / "cmu"
    return candidate if (candidate / "clips.csv").is_file() else None


def read_clip_index(motion_dir: str | os.PathLike) -> list[ClipInfo]:
    """Read ``clips.csv`` (columns ``file,subject,description,frames,fps,category``) in ``motion_dir``."""
    motion_dir = Path(motion_dir)
    index = motion_dir / "clips.csv"
    if not index.is_file():
        raise FileNotFoundError(f"{index}: clip index not found (expected clips.csv in the motion folder)")
    out = []
    with index.open(newline="") as fh:
        reader = csv.DictReader(fh)
        need = {"file", "subject", "description", "frames", "fps", "category"}
        missing = need - set(reader.fieldnames or ())
        if missing:
            raise ValueError(f"{index}: missing column(s) {sorted(missing)}")
        for n, row in enumerate(reader, start=2):
            try:
                out.append(ClipInfo(name=row["file"].removesuffix(".bvh"), path=motion_dir / row["file"],
                                    subject=row["subject"], description=row["description"],
                                    frames=int(row["frames"]), fps=float(row["fps"]),
                                    category=row["category"]))
            except ValueError as exc:
                raise ValueError(f"{index}: line {n}: bad 'frames' or 'fps' ({exc})") from None
    return out


def list_clips(motion_dir: str | os.PathLike | None = None, split: str = "train") -> list[ClipInfo]:
    """Clips of the CMU index: ``split`` = ``"train"`` (not hold-out), ``"holdout"`` or ``"all"``.

    ``motion_dir`` None uses :func:`default_motion_dir`; if that is None too, raises FileNotFoundError.
    """
    if split not in ("train", "holdout", "all"):
        raise ValueError(f"split must be 'train', 'holdout' or 'all', got {split!r}")
    if motion_dir is None:
        motion_dir = default_motion_dir()
        if motion_dir is None:
            raise FileNotFoundError("no motion folder given and ../shared/mocap/cmu not found; "
                                    "pass motion_dir (a folder with clips.csv and BVH files)")
    clips = read_clip_index(motion_dir)
    if split == "train":
        return [c for c in clips if not c.holdout]
    if split == "holdout":
        return [c for c in clips if c.holdout]
    return clips
