"""Draw each fitted joint's uncertainty over a camera image: the 3D keypoint covariance as a 2D ellipse.

Every fitted keypoint comes with a (3, 3) marginal covariance in the LiDAR (world) frame.  Projected into a
rectified camera to first order, ``Sigma_uv = J Sigma J^T`` with ``J = d uv / d world_p`` (2 x 3, pixels per
metre), it is an ellipse in the image; this script draws the 95 % ellipse of every keypoint of every person
fitted in one frame (OpenCV), the fitted keypoints as dots and the 2D labels as crosses, on a blank canvas of
the camera's image size (a real image can be passed with ``--image``).

    python examples/draw_uncertainty.py --out example_out/ellipses --pedestrians 3 --frames 8

Writes ``OUT/uncertainty.png`` and ``OUT/uncertainty.json`` (per person and keypoint: pixel position and the
ellipse's semi-axes in pixels).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np

from pedx_graph import SimConfig, fit_track, read_dataset, simulate

CHI2_2DOF_95 = 5.991      # 95 % quantile of the chi-square distribution with 2 degrees of freedom


def project_with_covariance(calib, world_p: np.ndarray, world_cov: np.ndarray):
    """Rectified left-image pixels (K, 2) of world points (K, 3) and their first-order covariances (K, 2, 2)."""
    rect_R_world = calib.rect_T_world[:3, :3]
    rect_p = calib.world_to_rect(world_p)                                    # (K, 3) metres
    P = calib.left_P_rect                                                    # (3, 4)
    hom = rect_p @ P[:, :3].T + P[:, 3]                                      # (K, 3)
    uv = hom[:, :2] / hom[:, 2:3]
    d_uv_d_rect = (P[None, :2, :3] - uv[:, :, None] * P[None, 2:3, :3]) / hom[:, 2, None, None]   # (K, 2, 3)
    jac = d_uv_d_rect @ rect_R_world                                         # (K, 2, 3) px / m
    return uv, jac @ world_cov @ np.swapaxes(jac, 1, 2)


def draw_ellipse(image: np.ndarray, uv: np.ndarray, cov_uv: np.ndarray, colour) -> tuple[float, float]:
    """Draw the 95 % ellipse of ``cov_uv`` (2, 2) centred at ``uv``; returns its semi-axes (major, minor), px."""
    eigval, eigvec = np.linalg.eigh(cov_uv)
    minor, major = np.sqrt(CHI2_2DOF_95 * np.clip(eigval, 0.0, None))
    angle = float(np.degrees(np.arctan2(eigvec[1, 1], eigvec[0, 1])))        # direction of the major axis
    centre = (int(round(uv[0])), int(round(uv[1])))
    axes = (max(int(round(major)), 1), max(int(round(minor)), 1))
    cv2.ellipse(image, centre, axes, angle, 0, 360, colour, 2, cv2.LINE_AA)
    return float(major), float(minor)


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--out", default="example_out/ellipses", help="output folder")
    parser.add_argument("--pedestrians", type=int, default=3, help="pedestrians in the scene")
    parser.add_argument("--frames", type=int, default=8, help="frames (10 Hz)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the scene")
    parser.add_argument("--image", default=None, help="draw on this image (the frame's rectified left image)")
    args = parser.parse_args(argv)

    out = Path(args.out)
    sim = SimConfig()
    sim.scene.n_pedestrians, sim.scene.n_frames = args.pedestrians, args.frames
    simulate(out / "scene", sim, seed=args.seed, overwrite=True)
    tracks = read_dataset(out / "scene")

    # the frame and stereo pair of the middle frame of the longest track; everyone labelled there is drawn
    first = max(tracks, key=lambda t: len(t.frames))
    shown = first.frames[len(first.frames) // 2]
    pair, frame = shown.pair, shown.frame
    calib = first.calibrations[pair]
    width, height = calib.image_size
    image = cv2.imread(args.image) if args.image else np.full((height, width, 3), 40, np.uint8)
    if image is None or image.shape[:2] != (height, width):
        raise SystemExit(f"{args.image}: not a {width} x {height} image of camera pair {pair}")

    people = []
    colours = [(80, 200, 255), (120, 255, 120), (255, 160, 80), (200, 120, 255), (255, 255, 120)]
    for track in tracks:
        index = next((i for i, fr in enumerate(track.frames) if fr.frame == frame and fr.pair == pair), None)
        if index is None or track.sequence != first.sequence:
            continue
        result = fit_track(track)
        world_p = result.world_keypoints[index]                                   # (18, 3) metres
        world_cov = np.asarray(result.extra_per_frame[index]["cov_keypoints_3d"])  # (18, 3, 3) m^2
        uv, cov_uv = project_with_covariance(calib, world_p, world_cov)
        colour = colours[len(people) % len(colours)]
        axes = [draw_ellipse(image, uv[k], cov_uv[k], colour) for k in range(len(uv))]
        for point in uv:
            cv2.circle(image, (int(round(point[0])), int(round(point[1]))), 3, colour, -1, cv2.LINE_AA)
        label = track.frames[index].left
        if label is not None:
            for point in np.asarray(label.keypoints)[:, :2]:
                if np.all(np.isfinite(point)):
                    cv2.drawMarker(image, (int(round(point[0])), int(round(point[1]))), (255, 255, 255),
                                   cv2.MARKER_CROSS, 10, 1)
        people.append({"tracking_id": track.tracking_id, "uv_px": uv.tolist(),
                       "semi_axes_px": axes})
    cv2.imwrite(str(out / "uncertainty.png"), image)
    record = {"sequence": first.sequence, "frame": int(frame), "pair": pair, "image_size": [width, height],
              "chi2": CHI2_2DOF_95, "people": people}
    (out / "uncertainty.json").write_text(json.dumps(record, indent=1))
    print(f"frame {frame} of {first.sequence}, camera pair {pair}: {len(people)} people drawn -> "
          f"{out / 'uncertainty.png'}")
    return record


if __name__ == "__main__":
    main()
