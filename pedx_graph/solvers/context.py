"""The estimator context (body model, priors) of a fit config, made once per process."""
from __future__ import annotations

import hashlib
import threading
from pathlib import Path

from pedx_graph.execution.tasks import limit_blas_threads
from pedx_graph.graph.context import EstimatorContext
from pedx_graph.graph.config import FitConfig

# --- per-process state (body model and priors are loaded once per worker) -------------------------------
_WORKER: dict = {}

_WORKER_LOCK = threading.Lock()



def keypoint_sets_digest(folder: str) -> str:
    """A digest of the keypoint-set files in ``folder`` (``FitConfig.keypoint_sets``; names and contents): a
    folder calibrated again under the same name is another context.  Empty for no folder."""
    if not folder:
        return ""
    digest = hashlib.blake2b(digest_size=16)
    for path in sorted(Path(folder).glob("*.json")):
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    return f"{folder}:{digest.hexdigest()}"


def estimator_context(config: FitConfig):
    """The estimator context (body model, priors) of ``config``, made once per process (per config)."""
    key = (config.body_model, config.pose_prior, config.temporal_prior, config.prior_covariance_scale,
           config.chamfer_vertices, config.noise.shape_sigma, keypoint_sets_digest(config.keypoint_sets))
    limit_blas_threads()       # small dense products: processes over tracks use the cores instead
    with _WORKER_LOCK:         # a Dask worker may run tasks in several threads
        if _WORKER.get("key") != key:
            _WORKER["ctx"] = EstimatorContext.create(config)
            _WORKER["key"] = key
        return _WORKER["ctx"]

