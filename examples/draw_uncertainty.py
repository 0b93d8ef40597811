"""Draw each fitted joint's uncertainty over a camera image: the 3D keypoint covariance as a 2D ellipse.

Every fitted keypoint comes with a (3, 3) marginal covariance in the LiDAR (world) frame.  Projected into a
rectified camera to first order, ``Sigma_uv = J Sigma J^T`` with ``J = d uv / d world_p`` (2 x 3, pixels per
metre, ``Camera.jacobian``), it is an ellipse in the image.  This script fits every person labelled in one
frame and draws, with the export's overlay (``pedx_graph.export.overlays.draw_overlay``), their meshes, the
fitted keypoints with the 95 % ellipse of each, and the 2D labels, on a blank canvas of the camera's image size
(or on an image passed with ``--image``).

    python examples/draw_uncertainty.py --out example_out/ellipses --pedestrians 3 --frames 8

Writes ``OUT/uncertainty.png`` and ``OUT/uncertainty.json`` (per person and keypoint: pixel position, pixel
covariance and the 95 % ellipse's semi-axes).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np

from pedx_graph import BodyModel, SimConfig, fit_track, read_dataset, simulate
from pedx_graph.export.camera import dataset_cameras
from pedx_graph.export.overlays import PersonInView, blank_canvas, draw_overlay, ellipse_axes

COLOURS = ((48, 96, 230), (200, 120, 40), (60, 170, 60), (40, 160, 220), (170, 70, 170))   # BGR


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
    camera = next(c for c in dataset_cameras({pair: first.calibrations[pair]}).values() if c.side == "left")
    width, height = camera.image_size
    image = cv2.imread(args.image) if args.image else blank_canvas((width, height))
    if image is None or image.shape[:2] != (height, width):
        raise SystemExit(f"{args.image}: not a {width} x {height} image of camera {camera.name}")

    model = BodyModel.load()
    people, records = [], []
    for track in tracks:
        index = next((i for i, fr in enumerate(track.frames) if fr.frame == frame and fr.pair == pair), None)
        if index is None or track.sequence != first.sequence:
            continue
        result = fit_track(track)
        world_p = result.world_keypoints[index]                                   # (18, 3) metres
        world_cov = np.asarray(result.extra_per_frame[index]["cov_keypoints_3d"])  # (18, 3, 3) m^2
        uv, _ = camera.project(world_p)                                           # (18, 2) pixels
        cov_uv = camera.image_covariance(world_p, world_cov)                      # (18, 2, 2) px^2: J Sigma J^T
        people.append(PersonInView(
            tracking_id=track.tracking_id, colour_bgr=COLOURS[len(people) % len(COLOURS)],
            world_vertices=model.forward(result.pose[index], result.betas, result.trans[index]).vertices,
            faces=model.faces, world_keypoints=world_p, world_keypoint_cov=world_cov,
            label=track.frames[index].left))
        records.append({"tracking_id": track.tracking_id, "world_keypoints_m": world_p.tolist(),
                        "world_cov_m2": world_cov.tolist(), "uv_px": uv.tolist(), "cov_uv_px2": cov_uv.tolist(),
                        "semi_axes_px": [list(ellipse_axes(c)[0]) for c in cov_uv]})
    picture = draw_overlay(image, camera, people, title=f"{first.sequence} frame {frame} {camera.name}: 95 % ellipses")
    cv2.imwrite(str(out / "uncertainty.png"), picture)
    record = {"sequence": first.sequence, "frame": int(frame), "pair": pair, "camera": camera.name,
              "image_size": [width, height], "people": records}
    (out / "uncertainty.json").write_text(json.dumps(record, indent=1))
    print(f"frame {frame} of {first.sequence}, camera {camera.name}: {len(people)} people drawn -> "
          f"{out / 'uncertainty.png'}")
    return record


if __name__ == "__main__":
    main()
