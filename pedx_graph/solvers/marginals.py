"""Marginal covariances of a track's estimate: per frame (translation, root, body pose, 3D keypoints) and shape.

Gaussian (Laplace) approximation at the estimate: the graph is linearised at ``values`` (robust kernels
enter through their IRLS weights, the max-mixture priors through their selected component, the chamfer
term through its current correspondences), giving the information matrix ``Lambda = A^T A`` of the whitened
Jacobian ``A``.  Never a full joint over all variables: only the joint of each frame's variables with the
shape,

    z_i = [delta_root_i (3, rad, right perturbation), trans_i (3, m), body_pose_i (69, rad), betas (B)]

is formed, as a (75 + B, 75 + B) block ``Sigma_i`` of ``Lambda^-1``.

Two ways to get ``Sigma_i``:

* ``method="chain"`` (default): the track's graph is a chain of frames (the temporal prior links frame
  i - 1 and i) plus the shared shape (an "arrow").  A forward pass eliminates frame after frame (each
  passes information to the next frame and to the shape, exactly like a Kalman filter on ``(x_i, b)``), a
  backward pass (Rauch-Tung-Striebel) turns the conditionals ``x_i = K_i [x_{i+1}; b] + w_i`` into the joint
  marginals: ``Sigma_i = K_i Sigma_{i+1} K_i^T + W_i`` on the frame block, ``K_i Sigma_{i+1}[:, b]`` across.
  O(T (75 + B)^3), about a millisecond per frame.
* ``method="gtsam"``: ``gtsam.Marginals(graph, values).jointMarginalCovariance(frame keys + shape)`` per
  frame (slow on long tracks: each query re-eliminates the graph; kept as the reference).

From iSAM2 (:func:`isam_frame_covariance`): ``ISAM2.jointMarginalCovariance`` on the Bayes tree at the
current linearisation point, at any time.

Keypoint covariances (metres^2, world frame): ``Sigma_k = J_k Sigma_i J_k^T`` with ``J_k = [d_root, d_trans,
d_body_pose, d_betas]`` (3, 75 + B) of keypoint k from ``BodyModel.point_jacobians`` (right perturbation of
the root, as the ``Rot3`` retraction).

LiDAR chamfer information (``MarginalsConfig.chamfer_information``).  The chamfer factor linearises
point-to-point: each point's 3D offset to its nearest model vertex with the match held fixed, so sliding the
body along its surface by ``d`` looks like ``d`` of residual at every point (``N / sigma^2`` of information
in every direction).  The cost the solver actually minimises re-matches at every evaluation and is nearly
flat along the surface: moving a surface under its points changes their distances only along the surface
normals.  Measured on the simulated calibration scene (13 frames with 21-98 points, 7-16 m; curvature of
the re-matched cost from a parabola over +-1 cm of translation): the point-to-point Hessian overstated it
2.0x (depth), 2.8x (lateral) and 4.6x (vertical), the point-to-plane one matched it (1.02, 1.02, 0.53x);
over +-4 cm 2.9x / 4.1x / 11x against 1.4x (the kernel saturates).  At the true state the residuals of
neighbouring points are nearly uncorrelated (correlation 0.09 at 2-5 cm, <= 0.02 beyond), so the
information is not overstated by correlated errors but by the held correspondences.  With
``point_to_plane`` (default) each point contributes only along the unit normal ``n`` of its matched vertex
(area-weighted vertex normal of the posed mesh at the estimate): one row ``|M n| n^T J_v`` instead of the
three rows ``M J_v`` (``M`` the point's robust-weighted whitening, ``J_v`` the matched vertex's Jacobian).
``M`` and ``J_v`` are read off the linearised factor itself (its translation block is ``M``, since
``d v / d trans = I``), and the matched vertex's position from its root-rotation block
(``d v / d delta = -R [v_body]_x``), so no factor internals are needed; a factor whose rows do not
decode to a mesh vertex (within ``vertex_match_tol_m``) keeps its point-to-point information.  The point
estimate is not affected.

Under-constrained frames (no LiDAR and one view, a missing term): when a frame's information block is not
positive definite, a diffuse information ``diffuse_information`` is added on its diagonal so the pass
carries on, and the frame is reported with ``covariance_status = "under_constrained"``; its covariances are
written as null when any standard deviation exceeds the limits of :class:`MarginalsConfig`.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import gtsam
import numpy as np
from scipy.linalg import cho_factor, cho_solve, LinAlgError

from factors.common import BODY_POSE_DIM, ROOT_DIM, TRANS_DIM
from pedx_graph.solvers.chain import FRAME_DIM, ChainLayout, ChainSystem, NotAChainError
from pedx_graph.graph.config import MarginalsConfig  # noqa: F401  (defined with the fit's config)

log = logging.getLogger(__name__)

ROOT_SLICE = slice(0, 3)
TRANS_SLICE = slice(3, 6)
POSE_SLICE = slice(6, FRAME_DIM)


#: The information of a track in chain + arrow block form (75-d frames, one B-d shape): the ``frame``,
#: ``next``, ``frame_shape`` and ``shape`` blocks of a :class:`~pedx_graph.solvers.chain.ChainSystem`.
ChainInformation = ChainSystem


@dataclass
class TrackMarginals:
    """Joint marginal covariance of each frame's variables with the shape."""

    frame_covariances: np.ndarray
    """(T, 75 + B, 75 + B) over ``[root (3), trans (3), body_pose (69), betas (B)]``."""
    regularised: np.ndarray
    """(T,) bool: the frame's information block needed the diffuse regulariser."""
    seconds: float = 0.0
    method: str = "chain"
    linearize_seconds: float = 0.0
    """Part of ``seconds`` spent linearising the graph (the factor callbacks; chain method)."""

    @property
    def shape_covariance(self) -> np.ndarray:
        """(B, B) marginal covariance of the shape."""
        return self.frame_covariances[0, FRAME_DIM:, FRAME_DIM:]


def _key_layout(keys) -> tuple[dict[int, tuple[int, slice]], int]:
    """Map every frame key to (frame index, slice in the 75-d frame block); and the shape key."""
    layout = {}
    for i, k in enumerate(keys):
        layout[int(k.root)] = (i, ROOT_SLICE)
        layout[int(k.trans)] = (i, TRANS_SLICE)
        layout[int(k.body_pose)] = (i, POSE_SLICE)
    return layout, int(keys[0].betas)


def _dims_of(values: gtsam.Values, key: int) -> int:
    try:
        values.atRot3(key)
        return 3
    except RuntimeError:
        return int(np.asarray(values.atVector(key)).shape[0])


def chain_information(linear: gtsam.GaussianFactorGraph, keys, num_betas: int,
                      replace_rows: dict | None = None) -> ChainInformation:
    """The Hessians ``A^T A`` of the (whitened) linear factors in chain form
    (:meth:`pedx_graph.solvers.chain.ChainLayout.assemble`).

    ``keys`` are the track's :class:`FrameKeys` (frame order); ``replace_rows``: factor index -> whitened
    Jacobian to use instead of the factor's own (same columns).  Raises :class:`NotAChainError` when a
    factor links frames more than one apart.
    """
    return ChainLayout(keys, num_betas).assemble(linear, replace_rows)


def face_incidence(faces: np.ndarray, num_vertices: int):
    """(V, F) sparse vertex-face incidence (ones), to sum face quantities onto their vertices."""
    from scipy.sparse import csr_matrix

    faces = np.asarray(faces, dtype=np.int64)
    rows = faces.reshape(-1)
    cols = np.repeat(np.arange(len(faces)), 3)
    return csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(num_vertices, len(faces)))


def vertex_normals(vertices: np.ndarray, faces: np.ndarray, incidence=None) -> np.ndarray:
    """(V, 3) unit area-weighted vertex normals of a mesh (vertices (V, 3), faces (F, 3)); ``incidence``:
    :func:`face_incidence` of ``faces`` when already built."""
    faces = np.asarray(faces, dtype=np.int64)
    v0, v1, v2 = (vertices[faces[:, c]] for c in range(3))
    face_n = np.cross(v1 - v0, v2 - v0)
    incidence = face_incidence(faces, len(vertices)) if incidence is None else incidence
    normals = np.asarray(incidence @ face_n)
    return normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)


def point_to_plane_rows(a_mat: np.ndarray, root_cols: slice, trans_cols: slice, world_R_body: np.ndarray,
                        centre: np.ndarray, vertices: np.ndarray, normals: np.ndarray,
                        tol_m: float = 1e-6, tree=None) -> np.ndarray | None:
    """Point-to-plane rows (M, n) from a chamfer factor's whitened point-to-point Jacobian ``a_mat`` (3M, n).

    Per point (3 rows ``A_i = M_i J_v``): ``M_i`` = the translation block (``d v / d trans = I``), ``J_v =
    M_i^-1 A_i``; the root block of ``J_v`` is ``-R [y]_x`` with ``y`` the matched vertex relative to
    ``centre`` (the pelvis, the root's centre of rotation) in the body frame, so the vertex is at ``R y +
    centre``; its normal ``n`` is looked up among ``vertices`` (posed, world) and the row is ``|M_i n| n^T
    J_v``.  ``None`` when a point does not decode to a mesh vertex within ``tol_m`` (not a chamfer factor of
    this layout)."""
    from scipy.spatial import cKDTree

    a_mat = np.asarray(a_mat, float)
    if a_mat.shape[0] % 3:
        return None
    m = a_mat.shape[0] // 3
    blocks = a_mat.reshape(m, 3, -1)
    weight = blocks[:, :, trans_cols]
    try:
        jac_v = np.linalg.solve(weight, blocks)                                  # (M, 3, n)
    except np.linalg.LinAlgError:
        return None
    skew = -np.einsum("ji,mjk->mik", world_R_body, jac_v[:, :, root_cols])       # [y]_x
    y = np.stack([skew[:, 2, 1], skew[:, 0, 2], skew[:, 1, 0]], axis=1)
    world_v = y @ world_R_body.T + centre
    dist, idx = (tree or cKDTree(vertices)).query(world_v)
    if not np.all(np.isfinite(dist)) or np.max(dist) > tol_m:
        return None
    n = normals[idx]
    w = np.linalg.norm(np.einsum("mij,mj->mi", weight, n), axis=1)
    return w[:, None] * np.einsum("mi,min->mn", n, jac_v)


_INCIDENCE: list = [None, None]          # [model, its incidence]: the model is held, so never confused


def _incidence_of(model, faces: np.ndarray):
    """:func:`face_incidence` of a model's faces, built once per model (CSR rows = vertices)."""
    if _INCIDENCE[0] is not model:
        _INCIDENCE[:] = [model, face_incidence(faces, int(model.num_vertices)).tocsr()]
    return _INCIDENCE[1]


def add_chamfer_plane_information(system, linearizer, model) -> bool:
    """Add the point-to-plane information of every chamfer factor served by ``linearizer`` (a
    :class:`~pedx_graph.solvers.batched.BatchedLinearizer` whose body cache was just evaluated at the
    estimate) into ``system`` — the same rows as :func:`point_to_plane_rows`, but with the matched vertices
    taken from the cache instead of decoded from the Jacobian.  False (nothing added) when a factor is not
    robustified per point (its rows are then not per-point blocks)."""
    keys_list = linearizer.served.get("lidar_chamfer", [])
    if not keys_list:
        return True
    body = linearizer.body
    specs = body.specs("lidar_chamfer")
    if not all(specs[keys].robust_per_point and keys in body.chamfer_matches for keys in keys_list):
        return False
    fkeys, states = body.frame_states
    index = {int(k.root): i for i, k in enumerate(fkeys)}
    frames = [index[keys[0]] for keys in keys_list]
    pose = np.stack([states[f].full_pose for f in frames])
    betas = np.stack([states[f].betas for f in frames])
    trans = np.stack([states[f].trans for f in frames])
    # Normals of the matched vertices only: their incident faces, posed through the corners they need.
    faces = np.asarray(model.faces, dtype=np.int64)
    incidence = _incidence_of(model, faces)
    matched = np.unique(np.concatenate([body.chamfer_matches[keys] for keys in keys_list]))
    sub = incidence[matched]                                       # (U, Fc) sparse
    face_ids = np.unique(sub.indices)
    corners, corner_index = np.unique(faces[face_ids], return_inverse=True)
    posed = np.asarray(model.vertices_subset(pose, betas, trans, corners), float)    # (F, C, 3)
    tri = posed[:, corner_index.reshape(-1, 3)]                                       # (F, Fs, 3, 3)
    face_n = np.cross(tri[:, :, 1] - tri[:, :, 0], tri[:, :, 2] - tri[:, :, 0])      # (F, Fs, 3)
    sub = sub[:, face_ids]
    num = len(frames)
    normals = np.asarray(sub @ face_n.transpose(1, 0, 2).reshape(len(face_ids), 3 * num))
    normals = normals.reshape(len(matched), num, 3).transpose(1, 0, 2)
    normals /= np.maximum(np.linalg.norm(normals, axis=2, keepdims=True), 1e-300)
    row_of = {int(v): i for i, v in enumerate(matched)}
    hess = []
    for n, keys in enumerate(keys_list):
        _, blocks = body.factor_terms("lidar_chamfer", keys)
        a = np.concatenate(blocks, axis=1)
        m = a.shape[0] // 3
        a = a.reshape(m, 3, -1)
        weight = a[:, :, 3:6]                              # M_i: d v / d trans = I
        nrm = normals[n][[row_of[int(v)] for v in body.chamfer_matches[keys]]]
        x = np.linalg.solve(np.swapaxes(weight, 1, 2), nrm[:, :, None])[:, :, 0]      # M_i^-T n
        w = np.linalg.norm(np.einsum("mij,mj->mi", weight, nrm), axis=1)
        rows = w[:, None] * np.einsum("mi,min->mn", x, a)                            # |M n| n^T M^-1 A
        hess.append(rows.T @ rows)
    linearizer.scatter(system, keys_list, np.stack(hess), np.zeros((len(keys_list), hess[0].shape[0])))
    return True


def chamfer_plane_rows(linear: gtsam.GaussianFactorGraph, values: gtsam.Values, keys, factor_kinds,
                       model, tol_m: float = 1e-6) -> dict:
    """Factor index -> point-to-plane rows for every LiDAR chamfer factor of ``linear`` (kind
    ``lidar_chamfer`` in ``factor_kinds``) that decodes (:func:`point_to_plane_rows`)."""
    from scipy.spatial import cKDTree

    layout, shape_key = _key_layout(keys)
    chamfer = [j for j, kind in enumerate(factor_kinds) if kind == "lidar_chamfer" and j < linear.size()]
    if not chamfer:
        return {}
    betas = np.asarray(values.atVector(int(keys[0].betas)), float)
    pelvis_rest = np.asarray(model.rest_joints(betas))[0]
    faces = np.asarray(model.faces, dtype=np.int64)
    out, meshes, incidence = {}, {}, None
    for j in chamfer:
        factor = linear.at(j)
        if factor is None:
            continue
        fkeys = [int(k) for k in factor.keys()]
        frames = {layout[k][0] for k in fkeys if k != shape_key}
        if len(frames) != 1:
            continue
        i = frames.pop()
        cols, col = {}, 0
        for k in fkeys:
            dim = len(betas) if k == shape_key else layout[k][1].stop - layout[k][1].start
            cols[k] = slice(col, col + dim)
            col += dim
        k = keys[i]
        if int(k.root) not in cols or int(k.trans) not in cols:
            continue
        rot = values.atRot3(k.root).matrix()
        trans = np.asarray(values.atVector(k.trans), float)
        if i not in meshes:
            pose = np.concatenate([gtsam.Rot3.Logmap(values.atRot3(k.root)), values.atVector(k.body_pose)])
            verts = np.asarray(model.forward(pose, betas, trans).vertices, float)
            if incidence is None:
                incidence = face_incidence(faces, len(verts))
            meshes[i] = (verts, vertex_normals(verts, faces, incidence), cKDTree(verts))
        verts, normals, tree = meshes[i]
        rows = point_to_plane_rows(factor.jacobian()[0], cols[int(k.root)], cols[int(k.trans)], rot,
                                   pelvis_rest + trans, verts, normals, tol_m, tree)
        if rows is None:
            log.info("marginals: chamfer factor %d does not decode to mesh vertices; kept point-to-point", j)
            continue
        out[j] = rows
    return out


def _chol(matrix: np.ndarray, diffuse: float) -> tuple[tuple, bool]:
    """Cholesky factor of a symmetric matrix; adds ``diffuse * I`` (once, then 1e3x) when not PD."""
    sym = 0.5 * (matrix + matrix.T)
    try:
        return cho_factor(sym, lower=True, check_finite=True), False
    except LinAlgError:
        pass
    eps = diffuse
    for _ in range(6):
        try:
            return cho_factor(sym + eps * np.eye(len(sym)), lower=True), True
        except LinAlgError:
            eps *= 1e3
    raise LinAlgError("information block is not positive definite even after regularisation")


def chain_marginals(info: ChainInformation, diffuse: float = 1e-6) -> TrackMarginals:
    """Joint marginals ``Sigma_i`` of ``(x_i, betas)`` for every frame by forward elimination + RTS pass."""
    t0 = time.perf_counter()
    t, d, b = info.frame.shape[0], FRAME_DIM, info.shape.shape[0]
    regularised = np.zeros(t, bool)
    gains, noises = [], []
    acc_xx = info.frame[0].copy()
    acc_xb = info.frame_shape[0].copy()
    acc_bb = info.shape.copy()
    for i in range(t - 1):
        factor, regularised[i] = _chol(acc_xx, diffuse)
        rhs = np.concatenate([info.next[i], acc_xb], axis=1)            # (D, D + B)
        g = cho_solve(factor, rhs)                                       # Lambda_ii^-1 [L_{i,i+1}, L_ib]
        gains.append(-g)
        noises.append(cho_solve(factor, np.eye(d)))
        cross_next = info.next[i]
        next_xx = info.frame[i + 1] - cross_next.T @ g[:, :d]
        next_xb = info.frame_shape[i + 1] - cross_next.T @ g[:, d:]
        acc_bb = acc_bb - acc_xb.T @ g[:, d:]
        acc_xx, acc_xb = next_xx, next_xb
    joint = np.block([[acc_xx, acc_xb], [acc_xb.T, acc_bb]])
    factor, regularised[t - 1] = _chol(joint, diffuse)
    covs = np.empty((t, d + b, d + b))
    covs[t - 1] = cho_solve(factor, np.eye(d + b))
    for i in range(t - 2, -1, -1):
        nxt = covs[i + 1]
        gain = gains[i]                                                 # (D, D + B)
        cov_xx = gain @ nxt @ gain.T + noises[i]
        cov_xb = gain @ nxt[:, d:]
        covs[i, :d, :d] = cov_xx
        covs[i, :d, d:] = cov_xb
        covs[i, d:, :d] = cov_xb.T
        covs[i, d:, d:] = nxt[d:, d:]
    covs = 0.5 * (covs + np.swapaxes(covs, 1, 2))
    return TrackMarginals(frame_covariances=covs, regularised=regularised, seconds=time.perf_counter() - t0,
                          method="chain")


def _frame_query_keys(k) -> list[int]:
    return [int(k.root), int(k.trans), int(k.body_pose), int(k.betas)]


def joint_marginal_matrix(joint, keys: list[int], dims: list[int]) -> np.ndarray:
    """Assemble a gtsam ``JointMarginal`` into one dense matrix in the order of ``keys``."""
    offsets = np.concatenate([[0], np.cumsum(dims)])
    out = np.zeros((offsets[-1], offsets[-1]))
    for a, ka in enumerate(keys):
        for c, kc in enumerate(keys):
            out[offsets[a]:offsets[a + 1], offsets[c]:offsets[c + 1]] = joint.at(ka, kc)
    return out


def gtsam_marginals(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, keys,
                    num_betas: int) -> TrackMarginals:
    """The same joint marginals with ``gtsam.Marginals`` (one joint query per frame; the reference)."""
    t0 = time.perf_counter()
    marginals = gtsam.Marginals(graph, values)
    dims = [ROOT_DIM, TRANS_DIM, BODY_POSE_DIM, num_betas]
    covs = np.stack([joint_marginal_matrix(marginals.jointMarginalCovariance(_frame_query_keys(k)),
                                           _frame_query_keys(k), dims) for k in keys])
    return TrackMarginals(frame_covariances=covs, regularised=np.zeros(len(keys), bool),
                          seconds=time.perf_counter() - t0, method="gtsam")


def _batched_information(linearizer, values: gtsam.Values, config: MarginalsConfig, model):
    """Chain information from a :class:`~pedx_graph.solvers.batched.BatchedLinearizer` (no GTSAM callbacks),
    with the point-to-plane chamfer information when configured; None when that cannot be formed here."""
    plane = config.chamfer_information == "point_to_plane"
    if config.chamfer_information not in ("point_to_plane", "point_to_point"):
        raise ValueError(f"chamfer_information must be 'point_to_plane' or 'point_to_point', "
                         f"got {config.chamfer_information!r}")
    if plane and model is None:
        return None
    system = linearizer.system(values, skip=("lidar_chamfer",) if plane else ())
    if plane and not add_chamfer_plane_information(system, linearizer, model):
        return None
    return system


def compute_marginals(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, keys,
                      config: MarginalsConfig | None = None,
                      linear: gtsam.GaussianFactorGraph | None = None, prefetch=None,
                      factor_kinds=None, model=None, linearizer=None) -> TrackMarginals:
    """Joint marginals of every frame with the shape (``config.method``; chain falls back to gtsam).

    ``linear``: the graph already linearised at ``values`` (e.g. by the solver's last iteration), which
    saves the factor callbacks (most of the cost); ``prefetch(values, jacobians)``: called before linearising
    (``TrackProblem.prefetch`` batch-evaluates the body model for all frames).  ``factor_kinds`` (the
    problem's kind of each factor) and ``model`` (the body model): needed for the point-to-plane chamfer
    information (``config.chamfer_information``; the gtsam method always uses the linearisation as is).
    ``linearizer``: the track's :class:`~pedx_graph.solvers.batched.BatchedLinearizer`; the chain method then
    takes the information from its batched evaluation (equal to the linearisation, no callbacks) and the
    chamfer's matched vertices from the cache."""
    config = config or MarginalsConfig()
    num_betas = _dims_of(values, int(keys[0].betas))
    if config.method == "gtsam":
        return gtsam_marginals(graph, values, keys, num_betas)
    if config.method != "chain":
        raise ValueError(f"marginals method must be 'chain' or 'gtsam', got {config.method!r}")
    t0 = time.perf_counter()
    if linearizer is not None and linear is None:
        info = _batched_information(linearizer, values, config, model)
        if info is not None:
            t_lin = time.perf_counter() - t0
            out = chain_marginals(info, config.diffuse_information)
            out.seconds = time.perf_counter() - t0
            out.linearize_seconds = t_lin
            return out
    if linear is None:
        if prefetch is not None:
            prefetch(values, True)
        linear = graph.linearize(values)
    t_lin = time.perf_counter() - t0
    replace = {}
    if config.chamfer_information == "point_to_plane" and factor_kinds is not None and model is not None:
        replace = chamfer_plane_rows(linear, values, keys, factor_kinds, model, config.vertex_match_tol_m)
    elif config.chamfer_information not in ("point_to_plane", "point_to_point"):
        raise ValueError(f"chamfer_information must be 'point_to_plane' or 'point_to_point', "
                         f"got {config.chamfer_information!r}")
    try:
        info = chain_information(linear, keys, num_betas, replace)
    except NotAChainError as exc:
        log.info("marginals: %s; using gtsam.Marginals", exc)
        return gtsam_marginals(graph, values, keys, num_betas)
    out = chain_marginals(info, config.diffuse_information)
    out.seconds = time.perf_counter() - t0
    out.linearize_seconds = t_lin
    return out


def isam_frame_covariance(isam: gtsam.ISAM2, frame_keys, num_betas: int) -> np.ndarray:
    """(75 + B, 75 + B) joint marginal of one frame's variables and the shape from an iSAM2 Bayes tree."""
    query = _frame_query_keys(frame_keys)
    joint = isam.jointMarginalCovariance(query)
    return joint_marginal_matrix(joint, query, [ROOT_DIM, TRANS_DIM, BODY_POSE_DIM, num_betas])


def keypoint_covariances(model, pose: np.ndarray, betas: np.ndarray, trans: np.ndarray,
                         frame_cov: np.ndarray) -> np.ndarray:
    """(18, 3, 3) covariances (m^2, world) of the keypoints of one frame from its joint marginal (75+B)^2."""
    jac = model.point_jacobians(np.asarray(pose, float), np.asarray(betas, float), np.asarray(trans, float))
    full = np.concatenate([np.asarray(jac.d_root), np.asarray(jac.d_trans), np.asarray(jac.d_body_pose),
                           np.asarray(jac.d_betas)], axis=-1)                 # (18, 3, 75 + B)
    return np.matmul(np.matmul(full, frame_cov), np.swapaxes(full, 1, 2))


def keypoint_covariances_batch(model, pose: np.ndarray, betas: np.ndarray, trans: np.ndarray,
                               frame_covs: np.ndarray) -> np.ndarray:
    """(T, 18, 3, 3) keypoint covariances of T frames at once: pose (T, 72), betas (B,), trans (T, 3),
    joint marginals (T, 75 + B, 75 + B)."""
    pose = np.asarray(pose, float)
    betas_t = np.broadcast_to(np.asarray(betas, float), (len(pose), len(betas)))
    jac = model.point_jacobians(pose, betas_t, np.asarray(trans, float))
    full = np.concatenate([np.asarray(jac.d_root), np.asarray(jac.d_trans), np.asarray(jac.d_body_pose),
                           np.asarray(jac.d_betas)], axis=-1)                 # (T, 18, 3, 75 + B)
    return np.matmul(np.matmul(full, frame_covs[:, None]), np.swapaxes(full, -1, -2))


def frame_fields(model, pose: np.ndarray, betas: np.ndarray, trans: np.ndarray, frame_cov: np.ndarray,
                 regularised: bool, config: MarginalsConfig, cov_keypoints: np.ndarray | None = None) -> dict:
    """The per-frame result fields: covariances of trans, root, body pose, keypoints, and a status
    (``cov_keypoints`` (18, 3, 3) when already computed)."""
    cov_trans = frame_cov[TRANS_SLICE, TRANS_SLICE]
    cov_root = frame_cov[ROOT_SLICE, ROOT_SLICE]
    sig_t = float(np.sqrt(max(np.max(np.linalg.eigvalsh(cov_trans)), 0.0)))
    sig_r = float(np.sqrt(max(np.max(np.linalg.eigvalsh(cov_root)), 0.0)))
    too_wide = sig_t > config.max_trans_sigma_m or sig_r > config.max_root_sigma_rad
    status = "under_constrained" if (regularised or too_wide) else "ok"
    if too_wide:
        return {"covariance_status": status, "cov_trans": None, "cov_root": None, "cov_body_pose": None,
                "cov_keypoints_3d": None, "sigma_trans_max_m": sig_t, "sigma_root_max_rad": sig_r}
    cov_pose = frame_cov[POSE_SLICE, POSE_SLICE]
    if config.body_pose_blocks:
        cov_pose = np.stack([cov_pose[3 * j:3 * j + 3, 3 * j:3 * j + 3] for j in range(BODY_POSE_DIM // 3)])
    return {"covariance_status": status, "cov_trans": cov_trans, "cov_root": cov_root,
            "cov_body_pose": cov_pose,
            "cov_keypoints_3d": (keypoint_covariances(model, pose, betas, trans, frame_cov)
                                 if cov_keypoints is None else cov_keypoints),
            "sigma_trans_max_m": sig_t, "sigma_root_max_rad": sig_r}


def marginals_to_fields(marginals: TrackMarginals, estimate, model,
                        config: MarginalsConfig | None = None) -> tuple[list[dict], dict]:
    """``(extra_per_frame, extra_track)`` for :class:`TrackResult` from computed marginals and the estimate
    (``estimate``: anything with ``pose (T, 72)``, ``betas (B,)``, ``trans (T, 3)``)."""
    config = config or MarginalsConfig()
    cov_kp = keypoint_covariances_batch(model, estimate.pose, estimate.betas, estimate.trans,
                                        marginals.frame_covariances)
    per_frame = [frame_fields(model, estimate.pose[i], estimate.betas, estimate.trans[i],
                              marginals.frame_covariances[i], bool(marginals.regularised[i]), config, cov_kp[i])
                 for i in range(len(estimate.pose))]
    n_bad = int(sum(f["covariance_status"] != "ok" for f in per_frame))
    track = {"cov_betas": marginals.shape_covariance, "marginals_method": marginals.method,
             "marginals_seconds": marginals.seconds, "marginals_under_constrained_frames": n_bad}
    return per_frame, track


def problem_linearizer(problem):
    """A :class:`~pedx_graph.solvers.batched.BatchedLinearizer` of ``problem`` when its factors use the batched
    term cache (tracks built by ``build_track_graph``), else None."""
    if getattr(getattr(problem, "body", None), "term_cache", None) is None or not hasattr(problem, "layout"):
        return None
    from pedx_graph.solvers.batched import BatchedLinearizer
    try:
        return BatchedLinearizer(problem)
    except NotAChainError:
        return None


def problem_marginals(problem, values: gtsam.Values, ctx, config: MarginalsConfig | None = None) -> TrackMarginals:
    """:func:`compute_marginals` of a solved track's problem (a ``TrackProblem``) with everything it offers:
    its prefetch, factor kinds and batched linearizer, and the body model of ``ctx``."""
    return compute_marginals(problem.graph, values, problem.keys, config,
                             prefetch=getattr(problem, "prefetch", None),
                             factor_kinds=getattr(problem, "factor_kinds", None), model=ctx.model,
                             linearizer=problem_linearizer(problem))


def track_marginals(problem, values: gtsam.Values, ctx, config: MarginalsConfig | None = None
                    ) -> tuple[list[dict], dict]:
    """Per-frame and per-track covariance fields of ``values`` (the solved estimate of ``problem``).

    Never raises on an under-constrained track: failures are reported in the track fields
    (``marginals_error``) and every frame gets ``covariance_status = "failed"``.
    """
    from pedx_graph.graph.build import extract_estimate

    config = config or MarginalsConfig()
    try:
        marginals = problem_marginals(problem, values, ctx, config)
    except (RuntimeError, LinAlgError, ValueError) as exc:
        log.warning("marginals failed: %s", exc)
        return ([{"covariance_status": "failed"} for _ in problem.keys],
                {"marginals_error": f"{type(exc).__name__}: {exc}"})
    return marginals_to_fields(marginals, extract_estimate(problem, values, ctx), ctx.model, config)
