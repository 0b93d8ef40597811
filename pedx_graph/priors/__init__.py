"""Trained Gaussian-mixture priors: pose (69-d body pose) and temporal (75-d frame-to-frame difference).

Public API::

    from pedx_graph.priors import load_pose_prior, load_temporal_prior

    pose_prior = load_pose_prior()              # GaussianMixturePrior, 8 components, D = 69
    r, jac, k = pose_prior.residual(body_pose, want_jacobian=True)     # (70,), (70, 69), component
    temporal_prior = load_temporal_prior()      # 10 components, D = 75, dt = 0.1 s

The shipped files live in ``pedx_graph/priors/data`` (``pose_gmm.npz``, ``temporal_gmm.npz``,
``provenance.json``); ``pedx-graph train-prior`` retrains them (see :mod:`pedx_graph.priors.train`).
"""
from __future__ import annotations

import os
from pathlib import Path

from pedx_graph.priors.gmm import GaussianMixturePrior, PriorFormatError

#: Folder of the shipped priors.
DATA_DIR = Path(__file__).resolve().parent / "data"


def _load(path: str | os.PathLike | None, default_name: str) -> GaussianMixturePrior:
    path = DATA_DIR / default_name if path is None else Path(path)
    if not path.is_file():
        raise PriorFormatError(f"{path}: prior file not found (train one with 'pedx-graph train-prior --out DIR')")
    return GaussianMixturePrior.load_npz(path)


def load_pose_prior(path: str | os.PathLike | None = None) -> GaussianMixturePrior:
    """The pose GMM (69-d body pose, radians); ``path`` None loads the shipped ``pose_gmm.npz``."""
    return _load(path, "pose_gmm.npz")


def load_temporal_prior(path: str | os.PathLike | None = None) -> GaussianMixturePrior:
    """The temporal GMM (75-d difference at ``prior.dt``); ``path`` None loads ``temporal_gmm.npz``."""
    return _load(path, "temporal_gmm.npz")


__all__ = ["DATA_DIR", "GaussianMixturePrior", "PriorFormatError", "load_pose_prior", "load_temporal_prior"]
