"""``pedx-graph train-prior``: train the pose and temporal GMMs on the CMU clips (hold-out excluded)."""
from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path

log = logging.getLogger(__name__)


def register(subparsers) -> None:
    p = subparsers.add_parser("train-prior", help="train the pose and temporal GMM priors on CMU mocap",
                              description="Train the pose and temporal GMM priors on the CMU clips (hold-out excluded).")
    p.add_argument("--motion-dir", type=Path, default=None,
                   help="folder with clips.csv and the CMU BVH files (default: ../shared/mocap/cmu if present)")
    p.add_argument("--fps", type=float, default=10.0, help="temporal prior rate, dt = 1/fps (default 10)")
    p.add_argument("--out", type=Path, default=Path("priors"), help="output folder (default ./priors)")
    p.add_argument("--seed", type=int, default=0, help="EM initialisation seed (default 0)")
    p.add_argument("--no-mirror", action="store_true", help="do not add left/right mirrored clips")
    p.add_argument("--n-init", type=int, default=3, help="EM initialisations (default 3)")
    p.add_argument("--clips", nargs="*", default=(), help="train on these clip names only (hold-out refused)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pedx_graph.motion import default_motion_dir
    from pedx_graph.priors.train import TrainConfig, train_priors
    motion_dir = args.motion_dir or default_motion_dir()
    if motion_dir is None:
        log.error("no motion folder: pass --motion-dir (a folder with clips.csv and the CMU BVH files)")
        return 2
    cfg = TrainConfig(fps=args.fps, seed=args.seed, mirror=not args.no_mirror, n_init=args.n_init,
                      clips=tuple(args.clips))
    from pedx_graph.config_ranges import check_config
    check_config(cfg, "<command line>")
    result = train_priors(motion_dir, args.out, cfg)       # errors: one line from pedx_graph.cli (exit 1)
    ll = result.provenance["log_likelihood"]
    print(json.dumps({"out": str(args.out), "clips_train": len(result.provenance["clips_train"]),
                      "log_likelihood": {k: v for k, v in ll.items() if k != "holdout_per_clip"}}, indent=1))
    return 0
