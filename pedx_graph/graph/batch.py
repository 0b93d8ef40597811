"""Batched body-model evaluation for the factors of one track.

GTSAM calls every CustomFactor on its own, so each per-frame factor would evaluate the body model for its
one frame: per-call numpy overhead then dominates (keypoints + Jacobians cost ~0.9 ms as a single-frame call
but ~0.13 ms per frame when batched over 100 frames, see benchmarks/results/bench_body.md).

:class:`BatchedBodyModel` wraps a :class:`~pedx_graph.body.BodyModel` and is handed to the factors instead of
the model.  Before the solver linearises or evaluates the graph it calls :meth:`prefetch` with the values:
all frames are evaluated in one batched call and cached by the exact bytes of each frame's
``(pose, betas, trans)``.  A factor's call with the same inputs is then a dictionary look-up; any other call
(gtsam's own optimisers, iSAM2, Marginals, a changed estimate) falls through to the model, so results never
depend on the cache — only speed does.
"""
from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from factors.common import FrameKeys, read_frame_state
from pedx_graph.body import BodyModel


def _tag(pose: np.ndarray, betas: np.ndarray, trans: np.ndarray | None) -> bytes:
    t = b"" if trans is None else np.ascontiguousarray(trans, dtype=np.float64).tobytes()
    return (np.ascontiguousarray(pose, dtype=np.float64).tobytes()
            + np.ascontiguousarray(betas, dtype=np.float64).tobytes() + t)


@dataclass(frozen=True)
class _FrameJacobians:
    points: np.ndarray
    d_root: np.ndarray
    d_body_pose: np.ndarray
    d_trans: np.ndarray
    d_betas: np.ndarray


class BatchedBodyModel:
    """A body model whose per-frame results are prefetched for all frames of a track at once."""

    def __init__(self, model: BodyModel, subset_vertex_ids: np.ndarray | None = None):
        self.model = model
        self.subset_vertex_ids = subset_vertex_ids
        self._keypoint_jacobians: dict[bytes, _FrameJacobians] = {}
        self._keypoints: dict[bytes, np.ndarray] = {}
        self._subset_vertices: dict[bytes, np.ndarray] = {}

    def __getattr__(self, name):          # faces, num_betas, rest_joints, ... come from the model
        return getattr(self.model, name)

    # -- prefetch ------------------------------------------------------------------------------------
    def prefetch(self, values: gtsam.Values, keys: list[FrameKeys], jacobians: bool,
                 vertices: bool = True) -> None:
        """Evaluate every frame of ``keys`` at ``values`` in one batch (keypoints, with Jacobians when
        ``jacobians``; the subset vertices when ``vertices`` and a subset is set); forget older entries."""
        states = [read_frame_state(values, k.as_list()) for k in keys]
        if not states:
            return
        pose = np.stack([s.full_pose for s in states])
        betas = np.stack([s.betas for s in states])
        trans = np.stack([s.trans for s in states])
        tags = [_tag(s.full_pose, s.betas, s.trans) for s in states]
        self._keypoint_jacobians.clear()
        self._keypoints.clear()
        self._subset_vertices.clear()
        if jacobians:
            jac = self.model.point_jacobians(pose, betas, trans)
            for i, tag in enumerate(tags):
                self._keypoint_jacobians[tag] = _FrameJacobians(jac.points[i], jac.d_root[i], jac.d_body_pose[i],
                                                                jac.d_trans[i], jac.d_betas[i])
        else:
            kps = self.model.keypoints(pose, betas, trans)
            for i, tag in enumerate(tags):
                self._keypoints[tag] = kps[i]
        if vertices and self.subset_vertex_ids is not None:
            verts = self.model.vertices_subset(pose, betas, trans, self.subset_vertex_ids)
            for i, tag in enumerate(tags):
                self._subset_vertices[tag] = verts[i]

    # -- the BodyModel interface used by the factors -----------------------------------------------------
    def point_jacobians(self, pose, betas, trans=None, vertex_ids=None):
        if vertex_ids is None and np.ndim(pose) == 1:
            hit = self._keypoint_jacobians.get(_tag(pose, betas, trans))
            if hit is not None:
                return hit
        return self.model.point_jacobians(pose, betas, trans, vertex_ids=vertex_ids)

    def keypoints(self, pose, betas, trans=None):
        if np.ndim(pose) == 1:
            tag = _tag(pose, betas, trans)
            hit = self._keypoints.get(tag)
            if hit is not None:
                return hit
            jac = self._keypoint_jacobians.get(tag)
            if jac is not None:
                return jac.points
        return self.model.keypoints(pose, betas, trans)

    def vertices_subset(self, pose, betas, trans, vertex_ids):
        subset = self.subset_vertex_ids
        if (np.ndim(pose) == 1 and subset is not None and np.shape(vertex_ids) == subset.shape
                and (vertex_ids is subset or np.array_equal(vertex_ids, subset))):
            hit = self._subset_vertices.get(_tag(pose, betas, trans))
            if hit is not None:
                return hit
        return self.model.vertices_subset(pose, betas, trans, vertex_ids)
