"""Figure of one simulated frame: the labelled left image and top views of the LiDAR sweep.

Top row: the left image of a pair (a blank canvas, cropped to the labelled people) with the labelled keypoints
(filled = visible, hollow = occluded guess), the instance polygons and the instance's segment points projected.
Bottom row: the sweep from above (grey) with walkways, camera fields of view and each instance's segment points
coloured by whether they really come from that person (green) or not (red: ground, background, other people);
points on people that no segment caught are blue; black dots are the true joints, circles the pelvis.  Left:
the intersection; right: a zoom on the labelled people.  Top views are drawn in the sim frame (x forward, y left),
whatever the rig's output frame (``truth/meta.json``'s ``output_T_sim``).  Reads only the written files
(release + ``truth/``).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from pedx_graph.data.calib import read_calibrations
from pedx_graph.data.transform import transform_points
from pedx_graph.data.labels2d import iter_label2d_files, read_label2d


def _top_view(ax, meta, calibs, pair, points, truth, person_ids, limits, title, sim_T_output):
    """Top view in the sim frame (x forward, y left, +z against gravity): ``points`` are already there, calibrations and
    truth joints (output frame) are mapped with ``sim_T_output``."""
    from matplotlib.patches import Polygon as MplPolygon, Wedge

    # plot coordinates: x_plot = world y (axis inverted so the vehicle's left is on the left), y_plot = world x
    for w in meta["walkways"]:
        a, b = np.array(w["start_xy"]), np.array(w["end_xy"])
        d = (b - a) / np.linalg.norm(b - a)
        n = np.array([-d[1], d[0]]) * w["half_width_m"]
        quad = np.array([a + n, b + n, b - n, a - n])
        ax.add_patch(MplPolygon(quad[:, ::-1], closed=True, lw=0, alpha=0.5, zorder=0,
                                color="gold" if w["kind"] == "crosswalk" else "0.88"))
    for name, c in calibs.items():
        axis = (sim_T_output[:3, :3] @ c.world_R_rect)[:, 2]
        yaw = np.degrees(np.arctan2(axis[1], axis[0]))
        half = np.degrees(np.arctan2(c.image_size[0] / 2, c.focal_px))
        ax.add_patch(Wedge((0, 0), 60, 90 - yaw - half, 90 - yaw + half, alpha=0.07, zorder=0,
                           color="tab:blue" if name == pair else "tab:purple"))
    (ymin, ymax), (xmin, xmax) = limits
    view = (points[:, 0] > xmin) & (points[:, 0] < xmax) & (points[:, 1] > ymin) & (points[:, 1] < ymax)
    ax.scatter(points[view, 1], points[view, 0], s=0.3, c="0.55", lw=0, rasterized=True, zorder=1)
    on_person = np.isin(truth["scene_object_id"], np.array(sorted(person_ids.values())))
    assigned = np.zeros(len(points), dtype=bool)
    n_seg = n_bad = 0
    for key in truth.files:
        if not key.startswith("segment_index__"):
            continue
        tid = key.split("__", 1)[1]
        idx = truth[key]
        ok = truth[f"segment_is_person__{tid}"]
        assigned[idx] = True
        n_seg += len(idx)
        n_bad += int((~ok).sum())
        ax.scatter(points[idx[ok], 1], points[idx[ok], 0], s=7, c="tab:green", lw=0, zorder=3)
        ax.scatter(points[idx[~ok], 1], points[idx[~ok], 0], s=9, c="tab:red", lw=0, zorder=3)
    missed = on_person & ~assigned
    ax.scatter(points[missed, 1], points[missed, 0], s=5, c="tab:blue", lw=0, zorder=2)
    for tid in person_ids:
        key = f"joints__{tid}"
        if key in truth.files:
            joints = transform_points(sim_T_output, truth[key])
            ax.scatter(joints[:, 1], joints[:, 0], s=2, c="k", lw=0, zorder=4)
            ax.plot(joints[0, 1], joints[0, 0], "o", ms=6, mfc="none", mec="k", mew=0.7, zorder=4)
    ax.set_xlim(ymax, ymin)
    ax.set_ylim(xmin, xmax)
    ax.set_aspect("equal")
    ax.set_xlabel("sim y (m, left)")
    ax.set_ylabel("sim x (m, forward)")
    ax.set_title(title.format(n_bad=n_bad, n_seg=n_seg), fontsize=9)


def render_frame(out_dir: str | Path, frame: int, path: str | Path, pair: str | None = None,
                 sequence: str | None = None, dpi: int = 110) -> Path:
    """Render frame ``frame`` of a simulated folder to ``path`` (PNG); ``pair`` defaults to the forward one."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Polygon as MplPolygon, Rectangle

    out = Path(out_dir)
    meta = json.loads((out / "truth" / "meta.json").read_text())
    seq = sequence or meta["sequence"]
    calibs = read_calibrations(out / "calib")
    pair = pair or sorted(calibs, key=lambda n: not n.startswith("ylw"))[0]
    calib = calibs[pair]
    left_cam = pair.split("-")[0]
    truth = np.load(out / "truth" / seq / f"{seq}_{frame:07d}.npz")
    points = truth["scene_points"].astype(float)
    sim_T_output = np.linalg.inv(np.asarray(meta.get("output_T_sim", np.eye(4)), dtype=float))
    sim_points = transform_points(sim_T_output, points)
    person_ids = {o["name"]: o["id"] for o in meta["objects"] if o["kind"] == "pedestrian"}

    fig = plt.figure(figsize=(14, 10.5))
    grid = fig.add_gridspec(2, 2, height_ratios=[0.8, 1.0])
    ax_img = fig.add_subplot(grid[0, :])
    ax_all = fig.add_subplot(grid[1, 0])
    ax_zoom = fig.add_subplot(grid[1, 1])

    # ---- left image
    width, height = calib.image_size
    ax_img.set_facecolor("0.96")
    cmap = plt.get_cmap("tab10")
    labelled_tids, extents = [], []
    for path_json, camera, fr, tid in iter_label2d_files(out, seq):
        if camera != left_cam or fr != frame:
            continue
        label = read_label2d(path_json, seq, camera, fr, tid)
        colour = cmap(len(labelled_tids) % 10)
        labelled_tids.append(tid)
        view = label.view
        if view.polygon is not None:
            ax_img.add_patch(MplPolygon(view.polygon, closed=True, fill=False, ec=colour, lw=0.9))
            extents.append([*view.polygon.min(axis=0), *view.polygon.max(axis=0)])
        kp, lab = view.keypoints, view.labelled
        vis = view.visible & lab
        ax_img.scatter(kp[vis, 0], kp[vis, 1], s=12, color=colour, lw=0, zorder=3)
        ax_img.scatter(kp[lab & ~vis, 0], kp[lab & ~vis, 1], s=14, facecolors="none", edgecolors=colour,
                       lw=0.7, zorder=3)
        key = f"segment_index__{tid}"
        if key in truth.files and len(truth[key]):
            uv, _ = calib.project(points[truth[key]])
            ax_img.scatter(uv[:, 0], uv[:, 1], s=2, color="k", lw=0, zorder=4)
    x0, x1, y0, y1 = 0.0, float(width), 0.0, float(height)
    if extents:     # crop to the labelled people (the canvas is blank), aspect ~ 14:5.6
        ext = np.array(extents)
        x0, y0 = max(ext[:, 0].min() - 100, 0.0), max(ext[:, 1].min() - 100, 0.0)
        x1, y1 = min(ext[:, 2].max() + 100, float(width)), min(ext[:, 3].max() + 100, float(height))
        aspect = 2.6
        if (x1 - x0) / (y1 - y0) < aspect:
            pad = (aspect * (y1 - y0) - (x1 - x0)) / 2
            x0, x1 = x0 - pad, x1 + pad
        else:
            pad = ((x1 - x0) / aspect - (y1 - y0)) / 2
            y0, y1 = y0 - pad, y1 + pad
    ax_img.add_patch(Rectangle((0, 0), width, height, fill=False, ec="0.4", lw=1.0))
    ax_img.set_xlim(x0, x1)
    ax_img.set_ylim(y1, y0)
    ax_img.set_aspect("equal")
    ax_img.set_xlabel("u (px)")
    ax_img.set_ylabel("v (px)")
    ax_img.set_title(f"frame {frame}, left image {left_cam} ({width} x {height} px, cropped): "
                     f"{len(labelled_tids)} labelled pedestrians. Filled = visible keypoint, hollow = occluded "
                     "guess, line = polygon, black = its LiDAR segment", fontsize=9)

    # ---- top views
    _top_view(ax_all, meta, calibs, pair, sim_points, truth, person_ids, ((-25.0, 25.0), (-3.0, 47.0)),
              "top view: segment points on the person (green) / wrong (red: {n_bad} of {n_seg});\n"
              "person points in no segment (blue); joints (black), pelvis (circle)", sim_T_output)
    centres = [transform_points(sim_T_output, truth[f"joints__{t}"][0])[:2] for t in labelled_tids
               if f"joints__{t}" in truth.files]
    if centres:
        c = np.median(np.array(centres), axis=0)
    else:
        c = np.array([20.0, 0.0])
    _top_view(ax_zoom, meta, calibs, pair, sim_points, truth, person_ids,
              ((c[1] - 7.0, c[1] + 7.0), (c[0] - 7.0, c[0] + 7.0)), "zoom on the labelled people", sim_T_output)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path
