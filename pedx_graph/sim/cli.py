"""``pedx-graph simulate``: write a PedX-like simulated dataset (release layout + ``truth/``), default or PedX rig."""
from __future__ import annotations

import argparse
import json
import logging

log = logging.getLogger(__name__)


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "simulate", help="simulate a PedX-like intersection sequence (labels, LiDAR, ground truth)",
        description="Simulate a four-way-stop intersection seen by two stereo pairs and a 32-beam LiDAR and "
                    "write it in the PedX release layout under OUT, with exact ground truth under OUT/truth. "
                    "--rig pedx: the real PedX cameras and z-down LiDAR frame.")
    p.add_argument("out", metavar="OUT", help="output folder (created)")
    p.add_argument("--seed", type=int, default=0, help="random seed (same seed + config = same bytes)")
    p.add_argument("--pedestrians", type=int, default=None, help="number of pedestrians (config: scene.n_pedestrians)")
    p.add_argument("--frames", type=int, default=None, help="number of frames (config: scene.n_frames)")
    p.add_argument("--motion-dir", default=None,
                   help="folder of BVH clips with clips.csv (hold-out split); default: procedural gait")
    p.add_argument("--split", default=None, choices=["holdout", "train", "all"],
                   help="clip split used with --motion-dir (default from config: holdout)")
    p.add_argument("--rig", default=None, choices=["default", "pedx"],
                   help="rig preset: 'default' (LiDAR frame with +z against gravity, forward + left pairs) or "
                        "'pedx' (the real PedX rig, z-down LiDAR frame, real-label quirks); default: the YAML's "
                        "'rig:' key, else default")
    p.add_argument("--config", default=None,
                   help="YAML read on top of the rig preset (e.g. configs/sim_default.yaml, configs/sim_pedx.yaml)")
    p.add_argument("--body-model", default=None, help="SMPL-format .npz (default: the package's open model)")
    p.add_argument("--detections", default=None, metavar="FORMATS",
                   help="also write detector files on distorted raw images, comma-separated: openpose_body25, "
                        "openpose_body25b, openpose_coco18, coco (config: detections.formats)")
    p.add_argument("--workers", type=int, default=1, help="processes over frames (same files for any count)")
    p.add_argument("--overwrite", action="store_true", help="replace a simulation already in OUT")
    p.add_argument("--images", action="store_true",
                   help="also render camera images into images/<seq>/<cam>/ (config: images.enabled)")
    p.add_argument("--image-scale", type=float, default=None,
                   help="rendered image size over the calibration's (config: images.scale)")
    p.add_argument("--figure", default=None, metavar="PNG",
                   help="also render the middle frame to this PNG (needs matplotlib)")
    p.set_defaults(func=_run_simulate)


def _run_simulate(args: argparse.Namespace) -> int:
    from pedx_graph.sim.config import load_sim_config
    from pedx_graph.sim.simulate import simulate

    config = load_sim_config(args.config, rig=args.rig)
    if args.pedestrians is not None:
        config.scene.n_pedestrians = args.pedestrians
    if args.frames is not None:
        config.scene.n_frames = args.frames
    if args.motion_dir is not None:
        config.motion.motion_dir = args.motion_dir
    if args.split is not None:
        config.motion.split = args.split
    if args.body_model is not None:
        config.body_model = args.body_model
    if args.detections is not None:
        config.detections.formats = tuple(f.strip() for f in args.detections.split(",") if f.strip())
    if args.images:
        config.images.enabled = True
    if args.image_scale is not None:
        config.images.scale = args.image_scale
    config.validate(args.config or "<command line>")
    summary = simulate(args.out, config, seed=args.seed, progress=True, overwrite=args.overwrite,
                       workers=args.workers)
    if args.figure:
        from pedx_graph.sim.figure import render_frame

        frame = config.scene.first_frame + config.scene.n_frames // 2
        render_frame(args.out, frame, args.figure)
    print(json.dumps(summary, indent=1))
    return 0
