"""Joint-angle limits (part of E_P): knees and elbows must not bend backwards.

For each limited axis-angle component ``x = theta[index]`` (radians) of the 69-d body pose, a hinge residual

    r = (x - clip(x, lower, upper)) / sigma          (zero inside the limits)

The directions follow SMPLify's angle prior: a knee flexes with positive rotation about its x axis, the
left elbow with negative and the right elbow with positive rotation about y.  The limit acts on the
axis-angle component, which equals the hinge angle when the joint rotates about that single axis (an
approximation otherwise).  Jacobian: 1/sigma outside the limits, 0 inside (a kink at the bound).
"""
from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from factors.common import BODY_POSE_DIM, as_f64, set_jacobians
from factors.terms import NormalEquations, RowNoise, Term, concatenate, rows_normal_equations

#: The factor kind (``TrackProblem.factor_kinds``, the term cache's registry).
KIND = "joint_limits"


@dataclass(frozen=True)
class JointLimit:
    """Bounds on one axis-angle component of the 69-d body pose."""

    name: str
    """Human-readable name (e.g. ``"left_knee.x"``)."""
    index: int
    """Index into the 69-d body pose: ``3 * (smpl_joint - 1) + axis``."""
    lower: float
    """Lower bound, radians."""
    upper: float
    """Upper bound, radians."""


def _idx(joint: int, axis: int) -> int:
    return 3 * (joint - 1) + axis


#: Knees (SMPL 4, 5) about x in [-0.1, 2.6] rad; left elbow (18) about y in [-2.6, 0.1];
#: right elbow (19) about y in [-0.1, 2.6].  0.1 rad tolerates label noise around the straight limb.
DEFAULT_JOINT_LIMITS: tuple[JointLimit, ...] = (
    JointLimit("left_knee.x", _idx(4, 0), -0.1, 2.6),
    JointLimit("right_knee.x", _idx(5, 0), -0.1, 2.6),
    JointLimit("left_elbow.y", _idx(18, 1), -2.6, 0.1),
    JointLimit("right_elbow.y", _idx(19, 1), -0.1, 2.6),
)


def joint_limit_batch(body_pose: np.ndarray, limits: tuple[JointLimit, ...] = DEFAULT_JOINT_LIMITS
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Hinge residuals (F, L) radians of F body poses (F, 69), the limited components ``index`` (L,) and
    the mask (F, L) of the active (violated) limits: row l of the Jacobian is ``mask * e_index[l]``."""
    body_pose = as_f64(body_pose)
    idx = np.array([lim.index for lim in limits], dtype=np.int64)
    lo = np.array([lim.lower for lim in limits])
    hi = np.array([lim.upper for lim in limits])
    x = body_pose[:, idx]
    r = x - np.clip(x, lo, hi)
    return r, idx, r != 0.0


def joint_limit_error(body_pose: np.ndarray, limits: tuple[JointLimit, ...] = DEFAULT_JOINT_LIMITS,
                      want_jacobian: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """Unwhitened hinge residual (L,) in radians and its Jacobian (L, 69) w.r.t. the body pose."""
    body_pose = as_f64(body_pose)
    r, idx, active = joint_limit_batch(body_pose[None], limits)
    jac = None
    if want_jacobian:
        jac = np.zeros((idx.size, body_pose.size))
        jac[np.arange(idx.size), idx] = active[0].astype(np.float64)
    return r[0], jac


@dataclass(frozen=True)
class JointLimitSpec:
    """A joint-limit factor's limits and noise (``sigma_rad``, isotropic)."""

    limits: tuple[JointLimit, ...]
    sigma_rad: float


def make_joint_limit_factor(key_body_pose: int, sigma_rad: float = 0.05,
                            limits: tuple[JointLimit, ...] = DEFAULT_JOINT_LIMITS, cache=None) -> gtsam.CustomFactor:
    """Hinge joint-limit factor on ``key_body_pose`` (vector, 69); ``sigma_rad`` in radians.  ``cache``: a
    batched evaluator the factor registers with (``pedx_graph.graph.batch.BatchedBodyModel``)."""
    if not limits:
        raise ValueError("joint limits: empty limit list")
    for lim in limits:
        if not (0 <= lim.index < BODY_POSE_DIM and lim.lower <= lim.upper):
            raise ValueError(f"joint limit {lim.name}: bad index or bounds {lim}")
    rows = len(limits)
    spec = JointLimitSpec(tuple(limits), float(sigma_rad))
    if cache is not None:
        cache.register(KIND, [key_body_pose], spec)

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list | None) -> np.ndarray:
        r, jac = joint_limit_error(values.atVector(this.keys()[0]), limits, H is not None)
        if H is not None:
            set_jacobians(H, [jac], rows, [BODY_POSE_DIM])
        return r

    return gtsam.CustomFactor(noise_of(spec).model(), [key_body_pose], error)


def noise_of(spec: JointLimitSpec) -> RowNoise:
    """``sigma_rad`` radians on every limit's row, no kernel."""
    return RowNoise(np.full(len(spec.limits), spec.sigma_rad))


def assemble(cache, keys_list: list[tuple[int, ...]], jacobians: bool) -> NormalEquations:
    """The joint-limit factors ``keys_list`` (column: the body pose) from the cache's prefetched poses, one
    :func:`joint_limit_batch` call per distinct limit set; the Jacobian row of limit l is ``active e_index``,
    so the normal equations cover only the limited components (:attr:`NormalEquations.columns`)."""
    frames = cache.frame_index(keys_list)
    specs = cache.specs(KIND)
    groups: dict[tuple, list[int]] = {}
    for n, keys in enumerate(keys_list):
        spec = specs[keys]
        groups.setdefault((spec.limits, spec.sigma_rad), []).append(n)
    columns = np.unique([lim.index for limits, _ in groups for lim in limits])
    parts = []
    for (limits, sigma), members in groups.items():
        r, idx, active = joint_limit_batch(cache.frame_arrays["pose"][frames[members], 3:], limits)
        jac = None
        if jacobians:
            jac = np.zeros(r.shape + (len(columns),))
            jac[:, np.arange(len(idx)), np.searchsorted(columns, idx)] = active
        parts.append(rows_normal_equations([keys_list[n] for n in members], r, jac, np.full(r.shape, 1.0 / sigma),
                                           [("none", 1.0)], columns))
    return concatenate(parts)


TERM = Term(KIND, assemble)
