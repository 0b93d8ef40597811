"""Point-to-plane information of the LiDAR chamfer factors, from the term cache's matches.

The chamfer factor linearises point-to-point: each point's 3D offset to its nearest model vertex with the
match held fixed, so sliding the body along its surface by ``d`` looks like ``d`` of residual at every
point (``N / sigma^2`` of information in every direction).  The cost the solver actually minimises
re-matches at every evaluation and is nearly flat along the surface: moving a surface under its points
changes their distances only along the surface normals.  Measured on the simulated calibration scene
(13 frames with 21-98 points, 7-16 m; curvature of the re-matched cost from a parabola over +-1 cm of
translation): the point-to-point Hessian overstated it 2.0x (depth), 2.8x (lateral) and 4.6x (vertical),
the point-to-plane one matched it (1.02, 1.02, 0.53x); over +-4 cm 2.9x / 4.1x / 11x against 1.4x (the
kernel saturates).  At the true state the residuals of neighbouring points are nearly uncorrelated
(correlation 0.09 at 2-5 cm, <= 0.02 beyond), so the information is not overstated by correlated errors but
by the held correspondences.

With ``MarginalsConfig.chamfer_information = "point_to_plane"`` (default) each point contributes only along
the unit normal ``n`` of its matched vertex (area-weighted vertex normal of the posed mesh at the estimate,
:mod:`pedx_graph.solvers.marginals.normals`): one row ``|M n| n^T M^-1 A`` (:func:`plane_rows`) instead of the
three rows ``A = M J_v`` (``M`` the point's robust-weighted whitening, ``J_v`` the matched vertex's
Jacobian; ``M`` is the translation block of ``A`` since ``d v / d trans = I``).  Here the matched vertices
come from the term cache; for a graph linearised by GTSAM they are decoded from the Jacobians
(:mod:`pedx_graph.solvers.marginals.decode`).  The point estimate is not affected.
"""
from __future__ import annotations

import numpy as np

from pedx_graph.solvers.marginals.normals import matched_vertex_normals

#: Columns of a chamfer factor's ``d v / d trans`` block (keys ``[root, trans, body_pose, betas]``).
TRANS_COLUMNS = slice(3, 6)


def plane_rows(a: np.ndarray, weight: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Point-to-plane rows (M, n) ``|M_i n_i| n_i^T M_i^-1 A_i`` of M points: their whitened point-to-point
    rows ``a`` (M, 3, n), whitenings ``weight`` (M, 3, 3) (``A_i = M_i J_v``) and unit normals (M, 3)."""
    x = np.linalg.solve(np.swapaxes(weight, 1, 2), normals[:, :, None])[:, :, 0]        # M^-T n
    w = np.linalg.norm(np.einsum("mij,mj->mi", weight, normals), axis=1)
    return w[:, None] * np.einsum("mi,min->mn", x, a)


def add_chamfer_plane_information(system, linearizer, model) -> bool:
    """Add the point-to-plane information of every chamfer factor served by ``linearizer`` (a
    :class:`~pedx_graph.solvers.batched.BatchedLinearizer` whose body cache was just evaluated at the
    estimate) into ``system``, the matched vertices taken from the cache.  False (nothing added) when a
    factor is not robustified per point (its rows are then not per-point blocks)."""
    keys_list = linearizer.served.get("lidar_chamfer", [])
    if not keys_list:
        return True
    body = linearizer.body
    specs = body.specs("lidar_chamfer")
    if not all(specs[keys].robust_per_point and keys in body.chamfer_matches for keys in keys_list):
        return False
    frames = body.frame_index(keys_list)
    arrays = body.frame_arrays
    matched = np.unique(np.concatenate([body.chamfer_matches[keys] for keys in keys_list]))
    normals = matched_vertex_normals(model, arrays["pose"][frames], arrays["betas"][frames], arrays["trans"][frames],
                                     matched)
    row_of = {int(v): i for i, v in enumerate(matched)}
    hess = []
    for n, keys in enumerate(keys_list):
        _, blocks = body.factor_terms("lidar_chamfer", keys)
        a = np.concatenate(blocks, axis=1)
        a = a.reshape(a.shape[0] // 3, 3, -1)
        rows = plane_rows(a, a[:, :, TRANS_COLUMNS], normals[n][[row_of[int(v)] for v in body.chamfer_matches[keys]]])
        hess.append(rows.T @ rows)
    linearizer.scatter(system, keys_list, np.stack(hess), np.zeros((len(keys_list), hess[0].shape[0])))
    return True
