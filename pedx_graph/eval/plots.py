"""Figures of the evaluation report (matplotlib, Agg backend; PNG files).

* ``per_joint.png``: global and root-relative MPJPE per joint, one bar per method;
* ``error_vs_distance.png``: MPJPE per distance bin, one line per method, the error floor dashed;
* ``calibration.png``: the fraction of keypoint errors inside the ``p`` ellipsoid of their covariance
  against ``p`` (the diagonal = calibrated);
* ``overlay.png``: one frame's left image of the forward pair (a blank canvas with the LiDAR sweep projected
  as background), the fitted meshes' vertices projected with ``StereoCalibration.project`` and the 2D labels;
* ``top_view.png``: the scene from above (LiDAR sweep of that frame, true trajectories, fitted pelvis
  positions, the fitted meshes of that frame).
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from pedx_graph.eval.metrics import DISTANCE_BINS
from pedx_graph.keypoints import EVAL_JOINTS, PEDX_KEYPOINTS


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_per_joint(methods: dict[str, dict], path: str | os.PathLike) -> Path:
    """Grouped bars: per joint MPJPE (mm) of every method, global (top) and root-relative (bottom)."""
    plt = _plt()
    fig, axes = plt.subplots(2, 1, figsize=(11, 6.5), sharex=True)
    x = np.arange(len(EVAL_JOINTS))
    width = 0.8 / max(len(methods), 1)
    for ax, metric, title in zip(axes, ("global_mm", "root_relative_mm"), ("global", "root-relative")):
        for i, (name, s) in enumerate(methods.items()):
            vals = [s["per_joint"][j][metric] for j in EVAL_JOINTS]
            ax.bar(x + (i - (len(methods) - 1) / 2) * width, vals, width, label=name)
        ax.set_ylabel(f"{title} MPJPE (mm)")
        ax.grid(axis="y", alpha=0.3)
    axes[0].legend(ncol=min(len(methods), 5), fontsize=8)
    axes[1].set_xticks(x, EVAL_JOINTS)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def plot_error_vs_distance(methods: dict[str, dict], floor: dict | None, path: str | os.PathLike) -> Path:
    """MPJPE per distance bin (bin centres), global and root-relative; the floor dashed (log scale)."""
    plt = _plt()
    centres = np.array([(lo + hi) / 2 for lo, hi in DISTANCE_BINS])
    keys = [f"{lo:g}-{hi:g}" for lo, hi in DISTANCE_BINS]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, metric, title in zip(axes, ("global_mm", "root_relative_mm"), ("global", "root-relative")):
        for name, s in methods.items():
            ax.plot(centres, [s["per_distance"][k][metric] for k in keys], "o-", label=name)
        if floor:
            ax.plot(centres, [floor["per_distance"][k][metric] for k in keys], "k--", label="error floor")
        ax.set_yscale("log")
        ax.set_xlabel("distance from the LiDAR (m)")
        ax.set_ylabel(f"{title} MPJPE (mm)")
        ax.set_xticks(centres, [f"{k} m" for k in keys])
        ax.grid(alpha=0.3, which="both")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def plot_calibration(calibrations: dict[str, dict], path: str | os.PathLike) -> Path:
    """Empirical coverage of the keypoints' ``p`` ellipsoids against ``p`` (all and visible joints)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5, 5))
    ax.plot([0, 1], [0, 1], "k:", label="calibrated")
    for name, cal in calibrations.items():
        if not cal.get("frames"):
            continue
        levels = cal["curve"]["levels"]
        ax.plot(levels, cal["curve"]["all"], "o-", label=f"{name}: all keypoints")
        ax.plot(levels, cal["curve"]["visible"], "s--", label=f"{name}: visible")
    ax.set_xlabel("nominal probability p of the ellipsoid")
    ax.set_ylabel("fraction of errors inside")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def _pick_frame(results: str | os.PathLike, truth: str | os.PathLike):
    """The (sequence, frame, pair) with the most fitted people in one left image, and the data of it."""
    from collections import Counter

    from pedx_graph.data.reader import read_dataset, read_smpl_labels

    tracks = read_dataset(truth)
    pred = read_smpl_labels(results)
    count = Counter()
    for tr in tracks:
        fitted = {lab.frame for lab in pred.get((tr.sequence, tr.tracking_id), [])}
        for fr in tr.frames:
            if fr.left is not None and fr.frame in fitted:
                count[(tr.sequence, fr.frame, fr.pair)] += 1
    if not count:
        return None
    (seq, frame, pair), _ = max(count.items(), key=lambda kv: (kv[1], kv[0]))
    return seq, frame, pair, tracks, pred


def plot_overlay(results: str | os.PathLike, truth: str | os.PathLike, path: str | os.PathLike, model) -> Path | None:
    """Fitted meshes projected into one left image with the 2D labels (see the module docstring)."""
    from pedx_graph.data.reader import read_scene_points

    picked = _pick_frame(results, truth)
    if picked is None:
        return None
    seq, frame, pair, tracks, pred = picked
    plt = _plt()
    calib = next(tr.calibrations[pair] for tr in tracks if pair in tr.calibrations)
    width, height = calib.image_size
    fig, (ax, zoom) = plt.subplots(1, 2, figsize=(14, 6.5), gridspec_kw={"width_ratios": [2.2, 1]})
    for a in (ax, zoom):
        a.set_facecolor("0.93")
    try:
        scene = read_scene_points(truth, seq, frame)
        depth = calib.world_to_rect(scene)[:, 2]
        uv = calib.project(scene)[0]
        keep = (depth > 1.0) & (uv[:, 0] >= 0) & (uv[:, 0] < width) & (uv[:, 1] >= 0) & (uv[:, 1] < height)
        for a in (ax, zoom):
            a.scatter(uv[keep, 0], uv[keep, 1], s=0.3, c=np.log(depth[keep]), cmap="Greys_r", alpha=0.6)
    except Exception:
        pass
    colours = plt.get_cmap("tab10")
    boxes = []
    k = 0
    for tr in tracks:
        frames = {fr.frame: fr for fr in tr.frames}
        labels = {lab.frame: lab for lab in pred.get((tr.sequence, tr.tracking_id), [])}
        if tr.sequence != seq or frame not in frames or frame not in labels or frames[frame].pair != pair:
            continue
        fr, lab = frames[frame], labels[frame]
        if fr.left is None:
            continue
        colour = colours(k % 10)
        k += 1
        verts = np.asarray(model.forward(lab.pose, lab.betas, lab.trans).vertices)
        uv = calib.project(verts[::3])[0]
        kp = fr.left.keypoints
        ok = np.all(np.isfinite(kp), axis=1)
        for a, size in ((ax, 0.4), (zoom, 1.5)):
            a.scatter(uv[:, 0], uv[:, 1], s=size, color=colour, alpha=0.35)
            a.scatter(kp[ok & fr.left.visible, 0], kp[ok & fr.left.visible, 1], marker="+", s=40, color="k", lw=1)
            a.scatter(kp[ok & ~fr.left.visible, 0], kp[ok & ~fr.left.visible, 1], marker="x", s=25, color="r",
                      lw=1)
            if fr.left.polygon is not None:
                poly = np.vstack([fr.left.polygon, fr.left.polygon[:1]])
                a.plot(poly[:, 0], poly[:, 1], "-", color=colour, lw=0.8)
        boxes.append(np.vstack([uv.min(axis=0), uv.max(axis=0)]))
    if boxes:
        lo = np.min([b[0] for b in boxes], axis=0)
        hi = np.max([b[1] for b in boxes], axis=0)
        pad = 0.15 * (hi - lo).max() + 40
        ax.set_xlim(max(lo[0] - pad, 0), min(hi[0] + pad, width))
        ax.set_ylim(min(hi[1] + pad, height), max(lo[1] - pad, 0))
        big = max(boxes, key=lambda b: b[1, 1] - b[0, 1])
        centre, half = big.mean(axis=0), 0.65 * (big[1] - big[0]).max()
        zoom.set_xlim(centre[0] - half, centre[0] + half)
        zoom.set_ylim(centre[1] + half, centre[1] - half)
    else:
        ax.set_xlim(0, width)
        ax.set_ylim(height, 0)
    for a in (ax, zoom):
        a.set_aspect("equal")
        a.set_xlabel("u (px)")
    ax.set_ylabel("v (px)")
    ax.set_title(f"{seq} frame {frame}, left camera of {pair}: fitted meshes (colour), 2D labels "
                 f"(+ visible, x occluded), LiDAR sweep (grey)", fontsize=9)
    zoom.set_title("the largest person", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def plot_top_view(results: str | os.PathLike, truth: str | os.PathLike, path: str | os.PathLike, model) -> Path | None:
    """The scene from above: one frame's sweep, true trajectories, fitted pelvis positions and meshes."""
    from pedx_graph.data.reader import read_scene_points, read_smpl_labels

    picked = _pick_frame(results, truth)
    if picked is None:
        return None
    seq, frame, pair, tracks, pred = picked
    ground = next(tr.ground for tr in tracks if tr.sequence == seq)      # top view = the level frame's x, y
    gt = read_smpl_labels(truth)
    plt = _plt()
    fig, ax = plt.subplots(figsize=(9, 9))
    try:
        scene = ground.to_level(read_scene_points(truth, seq, frame))
        scene = scene[np.hypot(scene[:, 0], scene[:, 1]) < 55][::2]
        ax.scatter(scene[:, 0], scene[:, 1], s=0.2, color="0.6")
    except Exception:
        pass
    colours = plt.get_cmap("tab10")
    lhip, rhip = PEDX_KEYPOINTS.index("lhip"), PEDX_KEYPOINTS.index("rhip")
    people_xy = []
    k = 0
    for key, labels in sorted(gt.items()):
        if key[0] != seq:
            continue
        colour = colours(k % 10)
        k += 1
        true_kp = np.asarray(model.keypoints(np.stack([l.pose for l in labels]),
                                             np.stack([l.betas for l in labels]), np.stack([l.trans for l in labels])))
        pelvis = ground.to_level(0.5 * (true_kp[:, lhip] + true_kp[:, rhip]))
        people_xy.append(pelvis[:, :2])
        ax.plot(pelvis[:, 0], pelvis[:, 1], "-", color=colour, lw=1.5)
        fitted = pred.get(key, [])
        if fitted:
            kp = np.stack([np.asarray(l.extra["keypoints_3d"], float) for l in fitted])
            fp = ground.to_level(0.5 * (kp[:, lhip] + kp[:, rhip]))
            ax.scatter(fp[:, 0], fp[:, 1], s=8, color=colour, marker="o", edgecolors="k", linewidths=0.3)
            now = [l for l in fitted if l.frame == frame]
            if now:
                verts = ground.to_level(np.asarray(model.forward(now[0].pose, now[0].betas,
                                                                 now[0].trans).vertices)[::5])
                ax.scatter(verts[:, 0], verts[:, 1], s=0.3, color=colour, alpha=0.5)
    if people_xy:
        xy = np.concatenate(people_xy)
        lo, hi = np.minimum(xy.min(axis=0), 0.0) - 4.0, xy.max(axis=0) + 4.0
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
    ax.plot([0], [0], "k^", ms=9, label="camera rig (vehicle)")
    ax.plot([], [], "k-", label="true pelvis trajectory")
    ax.plot([], [], "ko", ms=4, label="fitted pelvis (each frame)")
    ax.set_aspect("equal")
    ax.set_xlabel("level x (m, along the reference camera)")
    ax.set_ylabel("level y (m, left of it)")
    ax.set_title(f"{seq}: top view (sweep and meshes of frame {frame})", fontsize=10)
    ax.legend(fontsize=8, loc="upper left")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def write_figures(report: dict, runs: list[dict], truth: str | os.PathLike, out_dir: str | os.PathLike,
                  model) -> list[Path]:
    """All figures of a report into ``out_dir``; returns their paths."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    methods = {r["label"]: r["eval"] for r in runs if r["group"] == "methods" and r["labels"] == "clean"}
    written = []
    if methods:
        written.append(plot_per_joint(methods, out_dir / "per_joint.png"))
        written.append(plot_error_vs_distance(methods, report.get("floor"), out_dir / "error_vs_distance.png"))
    if any(c.get("frames") for c in report.get("calibration", {}).values()):
        written.append(plot_calibration(report["calibration"], out_dir / "calibration.png"))
    ours = next((r for r in runs if r["kind"] == "fit" and r["group"] == "methods" and r["labels"] == "clean"), None)
    if ours is not None:
        for fn, name in ((plot_overlay, "overlay.png"), (plot_top_view, "top_view.png")):
            p = fn(ours["path"], truth, out_dir / name, model)
            if p is not None:
                written.append(p)
    return written
