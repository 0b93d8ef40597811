"""``pedx-graph train-prior``: train the pose and temporal GMMs on the CMU clips (hold-out excluded)."""
from __future__ import annotations

import argparse
import dataclasses
import json
import logging
from pathlib import Path

log = logging.getLogger(__name__)


def register(subparsers) -> None:
    p = subparsers.add_parser("train-prior", help="train the pose and temporal GMM priors on CMU mocap",
                              description="Train the pose and temporal GMM priors on the CMU clips "
                                          "(hold-out excluded).")
    p.add_argument("--motion-dir", type=Path, default=None,
                   help="folder with clips.csv and the CMU BVH files (default: ../shared/mocap/cmu if present)")
    p.add_argument("--config", default=None, help="YAML with TrainConfig fields (pedx-graph config train-prior); "
                                                  "the flags below override it (default: the defaults)")
    p.add_argument("--fps", type=float, default=None, help="temporal prior rate, dt = 1/fps (default 10)")
    p.add_argument("--out", type=Path, default=Path("priors"), help="output folder (default ./priors)")
    p.add_argument("--seed", type=int, default=None, help="EM initialisation seed (default 0)")
    p.add_argument("--no-mirror", action="store_true", help="do not add left/right mirrored clips")
    p.add_argument("--n-init", type=int, default=None, help="EM initialisations (default 3)")
    p.add_argument("--clips", nargs="*", default=None,
                   help="train on these clip names only (hold-out refused; default: every training clip)")
    p.set_defaults(func=run)


def train_config(args: argparse.Namespace):
    """The :class:`~pedx_graph.priors.train.TrainConfig` of the command: the ``--config`` YAML (or the defaults)
    with the flags that were given on top, every value's range checked."""
    from pedx_graph.config import load_config
    from pedx_graph.config_ranges import check_config
    from pedx_graph.priors.train import TrainConfig

    cfg = load_config(TrainConfig, args.config)
    flags = {"fps": args.fps, "seed": args.seed, "n_init": args.n_init,
             "clips": None if args.clips is None else tuple(args.clips), "mirror": False if args.no_mirror else None}
    return check_config(dataclasses.replace(cfg, **{k: v for k, v in flags.items() if v is not None}),
                        args.config or "<command line>")


def run(args: argparse.Namespace) -> int:
    from pedx_graph.motion import default_motion_dir
    from pedx_graph.priors.train import train_priors

    cfg = train_config(args)                               # a bad config stops before anything is read
    motion_dir = args.motion_dir or default_motion_dir()
    if motion_dir is None:
        log.error("no motion folder: pass --motion-dir (a folder with clips.csv and the CMU BVH files)")
        return 2
    result = train_priors(motion_dir, args.out, cfg)       # errors: one line from pedx_graph.cli (exit 1)
    ll = result.provenance["log_likelihood"]
    print(json.dumps({"out": str(args.out), "clips_train": len(result.provenance["clips_train"]),
                      "log_likelihood": {k: v for k, v in ll.items() if k != "holdout_per_clip"}}, indent=1))
    return 0
