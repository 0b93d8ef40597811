"""Figure of one simulated frame: top view of the LiDAR sweep and the labelled left image.

Left panel: the full sweep from above (grey), each instance's segment points coloured by whether they really
come from that person (green) or not (red: ground, background, other people), pedestrians' ground-truth
pelvis positions, camera fields of view.  Right panel: the left image of a pair (blank canvas) with the
labelled keypoints (filled = visible, hollow = occluded guess), the instance polygons, and the segment
points projected.  Reads only the written files (release layout + ``truth/``).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from pedx_graph.data.calib import read_calibrations
from pedx_graph.data.labels2d import iter_label2d_files, read_label2d


def render_frame(out_dir: str | Path, frame: int, path: str | Path, pair: str | None = None,
                 sequence: str | None = None, dpi: int = 110) -> Path:
    """Render frame ``frame`` of a simulated folder to ``path`` (PNG); ``pair`` defaults to the forward one."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Polygon as MplPolygon, Wedge

    out = Path(out_dir)
    meta = json.loads((out / "truth" / "meta.json").read_text())
    seq = sequence or meta["sequence"]
    calibs = read_calibrations(out / "calib")
    pair = pair or sorted(calibs, key=lambda n: not n.startswith("ylw"))[0]
    calib = calibs[pair]
    left_cam = pair.split("-")[0]
    truth = np.load(out / "truth" / seq / f"{seq}_{frame:07d}.npz")
    points = truth["scene_points"].astype(float)
    objects = {o["id"]: o for o in meta["objects"]}
    person_ids = {o["name"]: o["id"] for o in meta["objects"] if o["kind"] == "pedestrian"}

    fig, (ax_top, ax_img) = plt.subplots(1, 2, figsize=(15, 6.6), gridspec_kw={"width_ratios": [1.0, 1.15]})
    # ---- top view (x_plot = world y, y_plot = world x)
    for w in meta["walkways"]:
        a, b = np.array(w["start_xy"]), np.array(w["end_xy"])
        d = (b - a) / np.linalg.norm(b - a)
        n = np.array([-d[1], d[0]]) * w["half_width_m"]
        quad = np.array([a + n, b + n, b - n, a - n])
        ax_top.add_patch(MplPolygon(quad[:, ::-1], closed=True, lw=0,
                                    color="gold" if w["kind"] == "crosswalk" else "0.9", alpha=0.5, zorder=0))
    near = (np.abs(points[:, 0] - 15) < 40) & (np.abs(points[:, 1]) < 40)
    ax_top.scatter(points[near, 1], points[near, 0], s=0.15, c="0.7", lw=0, rasterized=True)
    for name, c in calibs.items():
        world_R_rect = c.world_T_cam[:3, :3] @ c.rect_R_cam.T
        axis = world_R_rect[:, 2]
        yaw = np.degrees(np.arctan2(axis[1], axis[0]))
        half = np.degrees(np.arctan2(c.image_size[0] / 2, c.focal_px))
        # plotted with x_plot = world y (axis inverted so left is left), y_plot = world x: angle 90 - yaw
        ax_top.add_patch(Wedge((0, 0), 45, 90 - yaw - half, 90 - yaw + half, alpha=0.06,
                               color="tab:blue" if name == pair else "tab:purple"))
    n_seg = n_bad = 0
    for key in truth.files:
        if not key.startswith("segment_index__"):
            continue
        tid = key.split("__", 1)[1]
        idx = truth[key]
        ok = truth[f"segment_is_person__{tid}"]
        n_seg += len(idx)
        n_bad += int((~ok).sum())
        ax_top.scatter(points[idx[ok], 1], points[idx[ok], 0], s=4, c="tab:green", lw=0)
        ax_top.scatter(points[idx[~ok], 1], points[idx[~ok], 0], s=6, c="tab:red", lw=0)
    for tid, oid in person_ids.items():
        k = f"joints__{tid}"
        if k in truth.files:
            pelvis = truth[k][0]
            ax_top.plot(pelvis[1], pelvis[0], "o", ms=4, mfc="none", mec="k", mew=0.8)
    ax_top.set_xlim(40, -40)
    ax_top.set_ylim(-5, 55)
    ax_top.set_aspect("equal")
    ax_top.set_xlabel("world y (m, left is left)")
    ax_top.set_ylabel("world x (m, forward)")
    ax_top.set_title(f"frame {frame}: LiDAR sweep, segment points on the person (green) / wrong (red): "
                     f"{n_bad}/{n_seg}", fontsize=9)

    # ---- left image
    width, height = calib.image_size
    ax_img.set_facecolor("0.96")
    cmap = plt.get_cmap("tab10")
    n_labels = 0
    for path_json, camera, fr, tid in iter_label2d_files(out, seq):
        if camera != left_cam or fr != frame:
            continue
        label = read_label2d(path_json, seq, camera, fr, tid)
        colour = cmap(n_labels % 10)
        n_labels += 1
        view = label.view
        if view.polygon is not None:
            ax_img.add_patch(MplPolygon(view.polygon, closed=True, fill=False, ec=colour, lw=0.8))
        kp = view.keypoints
        lab = view.labelled
        vis = view.visible & lab
        ax_img.scatter(kp[vis, 0], kp[vis, 1], s=8, color=colour, lw=0)
        ax_img.scatter(kp[lab & ~vis, 0], kp[lab & ~vis, 1], s=10, facecolors="none", edgecolors=colour, lw=0.6)
        key = f"segment_index__{tid}"
        if key in truth.files:
            uv, _ = calib.project(points[truth[key]])
            ax_img.scatter(uv[:, 0], uv[:, 1], s=1.5, color="k", lw=0)
    ax_img.set_xlim(0, width)
    ax_img.set_ylim(height, 0)
    ax_img.set_aspect("equal")
    ax_img.set_title(f"left image {left_cam} ({width}x{height}): {n_labels} labelled pedestrians; "
                     "filled = visible, hollow = occluded, black = segment points", fontsize=9)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path
