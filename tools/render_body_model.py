"""Render the open body model into a 4-panel PNG: T-pose and a walking pose, front and side views.

Uses ``pedx_graph.body.BodyModel`` (numpy LBS) for the forward pass and matplotlib for drawing: an
orthographic projection, back-face culling, Lambert shading and the painter's algorithm (faces drawn from
far to near as one ``PolyCollection``). Runs with the project's own environment::

    python tools/render_body_model.py                       # committed model -> docs/body_model.png
    python tools/render_body_model.py --model my_smpl.npz --out /some/where.png

Body frame (SMPL): Y up, +Z forward, subject's left at +X, metres. Front view: camera on +Z looking
along -Z (image right = +X, the subject's left). Side view: camera on -X looking along +X (image
right = +Z, the subject faces right).
"""
from __future__ import annotations

import argparse
import io
import sys
from pathlib import Path

import numpy as np

REPO_ROOT = Path(__file__).resolve().parents[1]
if str(REPO_ROOT) not in sys.path:
    sys.path.insert(0, str(REPO_ROOT))

from pedx_graph.body import BodyModel, PEDX_KEYPOINTS, SMPL_JOINTS  # noqa: E402
from pedx_graph.utils import atomic_write_bytes  # noqa: E402

#: Walking pose: joint name -> list of (axis, degrees) rotations applied right to left (last first),
#: each about the body frame's axes at that joint (SMPL local rotations, rest frames world-aligned).
WALK_POSE: dict[str, list[tuple[str, float]]] = {
    "left_hip": [("x", -25.0)],          # left thigh forward (negative X rotation swings -Y towards +Z)
    "right_hip": [("x", 15.0)],          # right thigh back
    "left_knee": [("x", 8.0)],
    "right_knee": [("x", 35.0)],         # trailing knee bent (shin backwards)
    "right_ankle": [("x", -10.0)],
    "left_shoulder": [("x", 20.0), ("z", -72.0)],   # arm down, then swung back
    "right_shoulder": [("x", -20.0), ("z", 72.0)],  # arm down, then swung forward
    "left_elbow": [("y", -15.0)],        # slight forward bend
    "right_elbow": [("y", 30.0)],
}


def axis_angle_from_rotations(rotations: list[tuple[str, float]]) -> np.ndarray:
    """Axis-angle (3,) of ``R = R_1 @ R_2 @ ...`` for a list of (axis, degrees) elementary rotations."""
    from scipy.spatial.transform import Rotation
    body_R = np.eye(3)
    for axis, deg in rotations:
        body_R = body_R @ Rotation.from_euler(axis, deg, degrees=True).as_matrix()
    return Rotation.from_matrix(body_R).as_rotvec()


def walking_pose() -> np.ndarray:
    """(72,) SMPL pose vector (identity root) of ``WALK_POSE``."""
    pose = np.zeros(72)
    for name, rots in WALK_POSE.items():
        j = SMPL_JOINTS.index(name)
        pose[3 * j:3 * j + 3] = axis_angle_from_rotations(rots)
    return pose


def project(body_p: np.ndarray, view: str) -> tuple[np.ndarray, np.ndarray]:
    """Orthographic image coordinates (N, 2) and depth towards the camera (N,) for ``view`` front/side."""
    if view == "front":
        return body_p[:, [0, 1]], body_p[:, 2]
    if view == "side":
        return body_p[:, [2, 1]], -body_p[:, 0]
    raise ValueError(f"unknown view {view!r}")


def draw_mesh(ax, vertices: np.ndarray, faces: np.ndarray, view: str, keypoints: np.ndarray | None = None,
              color=(0.80, 0.68, 0.58)) -> None:
    """Shade and draw a triangle mesh on a matplotlib axis with the painter's algorithm."""
    from matplotlib.collections import PolyCollection
    uv, depth = project(vertices, view)
    tri_uv = uv[faces]                                             # (F, 3, 2)
    # Normal's component towards the camera from the projected winding (orthographic camera).
    e1, e2 = tri_uv[:, 1] - tri_uv[:, 0], tri_uv[:, 2] - tri_uv[:, 0]
    facing = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    # Full 3D normals in camera coordinates (u, v, towards camera) for shading.
    cam = np.concatenate([uv, depth[:, None]], axis=1)[faces]
    n = np.cross(cam[:, 1] - cam[:, 0], cam[:, 2] - cam[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True) + 1e-12
    light = np.array([0.35, 0.45, 0.82])
    light /= np.linalg.norm(light)
    keep = facing > 0
    shade = 0.35 + 0.65 * np.clip(n[keep] @ light, 0.0, 1.0)
    order = np.argsort(depth[faces[keep]].mean(axis=1))           # far first
    colors = np.clip(np.asarray(color)[None] * shade[order, None], 0, 1)
    coll = PolyCollection(tri_uv[keep][order], facecolors=colors, edgecolors=colors, linewidths=0.15)
    ax.add_collection(coll)
    if keypoints is not None:
        kp_uv, _ = project(keypoints, view)
        ax.scatter(kp_uv[:, 0], kp_uv[:, 1], s=6, c="tab:blue", zorder=3)
    ax.set_xlim(uv[:, 0].min() - 0.05, uv[:, 0].max() + 0.05)
    ax.set_ylim(uv[:, 1].min() - 0.05, uv[:, 1].max() + 0.05)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    for spine in ax.spines.values():
        spine.set_visible(False)


def render(model: BodyModel, out_path: Path, dpi: int = 110) -> Path:
    """Render the 4 panels (T-pose / walking x front / side) of ``model`` at betas = 0 to ``out_path``."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    betas = np.zeros(model.num_betas)
    poses = {"T-pose": np.zeros(72), "walking": walking_pose()}
    panels = []
    for pose_name, pose in poses.items():
        out = model.forward(pose, betas)
        for view in ("front", "side"):
            panels.append((f"{pose_name}, {view}", out, view))
    # One metric scale for all panels: widths proportional to each panel's horizontal extent.
    margin = 0.05
    uvs = [project(out.vertices, view)[0] for _, out, view in panels]
    widths = [np.ptp(uv[:, 0]) + 2 * margin for uv in uvs]
    y_lo = min(uv[:, 1].min() for uv in uvs) - margin
    y_hi = max(uv[:, 1].max() for uv in uvs) + margin
    fig, axes = plt.subplots(1, len(panels), figsize=(15, 6.2), gridspec_kw={"width_ratios": widths})
    for ax, (title, out, view), uv in zip(axes, panels, uvs):
        draw_mesh(ax, out.vertices, model.faces, view, keypoints=out.keypoints)
        ax.set_xlim(uv[:, 0].min() - margin, uv[:, 0].max() + margin)
        ax.set_ylim(y_lo, y_hi)
        ax.set_title(title, fontsize=11)
    prov = model.provenance or {}
    height = float(np.ptp(model.v_template[:, 1]))
    fig.suptitle(f"{Path(model.source).name}: V={model.num_vertices}, F={len(model.faces)}, "
                 f"betas=0, height {height:.2f} m, dots = the 18 PedX keypoints"
                 + (f" (anny {prov['anny_version']})" if "anny_version" in prov else ""), fontsize=11)
    fig.tight_layout(rect=(0.0, 0.0, 1.0, 0.95))
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    plt.close(fig)
    return atomic_write_bytes(out_path, buf.getvalue())


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--model", default=None, help="SMPL-format .npz/.pkl (default: the shipped open model)")
    p.add_argument("--out", default=str(REPO_ROOT / "docs" / "body_model.png"), help="output PNG")
    p.add_argument("--dpi", type=int, default=110)
    args = p.parse_args(argv)
    model = BodyModel.load(args.model)
    path = render(model, Path(args.out), dpi=args.dpi)
    print(f"wrote {path} ({len(PEDX_KEYPOINTS)} keypoints drawn)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
