"""``pedx-graph info [--model PATH]``: describe a body model file (counts, heights, keypoints, provenance)."""
from __future__ import annotations

import argparse
import json
import sys

import numpy as np


def model_heights(model) -> dict[str, float]:
    """T-pose heights (max - min of the vertices along body Y, metres) of the mean shape and beta_1 = -2, +2."""
    betas = np.zeros((3, model.num_betas))
    betas[1, 0], betas[2, 0] = -2.0, 2.0
    verts = model.forward(np.zeros(72), betas, np.zeros(3)).vertices
    height = verts[..., 1].max(axis=-1) - verts[..., 1].min(axis=-1)
    return {"mean": float(height[0]), "beta1=-2": float(height[1]), "beta1=+2": float(height[2])}


def describe(model) -> str:
    """Human-readable summary of a :class:`pedx_graph.body.BodyModel`."""
    heights = model_heights(model)
    kp = model.keypoint_map
    lines = [
        f"model:      {model.source}",
        f"vertices:   {model.num_vertices}",
        f"joints:     {model.num_joints}",
        f"faces:      {len(model.faces)}",
        f"betas:      {model.num_betas}",
        f"posedirs:   {'yes' if model.posedirs is not None else 'no (zero or absent)'}",
        f"keypoints:  {kp.num_keypoints if kp else 0} ({kp.source if kp else 'none'})",
        "height (T-pose, max-min along body Y):",
        f"  mean shape   {heights['mean']:.3f} m",
        f"  beta1 = -2   {heights['beta1=-2']:.3f} m",
        f"  beta1 = +2   {heights['beta1=+2']:.3f} m",
    ]
    if model.provenance:
        lines.append("provenance:")
        lines += ["  " + line for line in json.dumps(model.provenance, indent=2, sort_keys=True).splitlines()]
    else:
        lines.append("provenance: none recorded in the file")
    return "\n".join(lines)


def run_info(args: argparse.Namespace) -> int:
    from pedx_graph.body.io import ModelFormatError
    from pedx_graph.body.model import BodyModel

    try:
        model = BodyModel.load(args.model, num_betas=args.num_betas,
                               joints_only_keypoints=args.joints_only_keypoints)
    except FileNotFoundError as exc:
        print(f"pedx-graph info: {exc}", file=sys.stderr)
        return 1
    except (ModelFormatError, ValueError) as exc:
        print(f"pedx-graph info: invalid body model: {exc}", file=sys.stderr)
        return 1
    print(describe(model))
    return 0


def register(subparsers) -> None:
    """Add the ``info`` command."""
    parser = subparsers.add_parser("info", help="describe a body model file",
                                   description=__doc__.splitlines()[0])
    parser.add_argument("--model", default=None,
                        help="SMPL-format .npz/.pkl (default: the open model pedx_open_neutral.npz)")
    parser.add_argument("--num-betas", type=int, default=10, help="shape components to use (default 10)")
    parser.add_argument("--joints-only-keypoints", action="store_true",
                        help="for models without keypoint definitions, put face keypoints at the head joint")
    parser.set_defaults(func=run_info)
