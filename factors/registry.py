"""The registry of energy terms: every term module listed here once, by name (one line per term).

Each listed module ``factors/<name>.py`` ends with ``TERM = Term(...)`` (:class:`factors.terms.Term`): its
kind and its assembler.  The solvers look terms up here by kind (:data:`TERMS`) and never name a term
themselves, so adding a term is its file plus its line below (docs/adding-a-term.md).
"""
from __future__ import annotations

from importlib import import_module

from factors.terms import Term

#: The term modules (``factors/<name>.py``), one line each.
TERM_MODULES = (
    "stereo_reprojection",
    "lidar_chamfer",
    "translation_prior",
    "heading_prior",
    "pose_prior",
    "joint_limits",
    "temporal_prior",
    "ground_contact",
)

#: kind -> :class:`~factors.terms.Term`, in the order of :data:`TERM_MODULES`.
TERMS: dict[str, Term] = {term.kind: term for term in (import_module(f"factors.{name}").TERM for name in TERM_MODULES)}

#: The kinds whose factors act on one frame's variables (and the shape) only.
OWN_FRAME_KINDS: tuple[str, ...] = tuple(kind for kind, term in TERMS.items() if term.own_frame)


def frame_terms() -> list[Term]:
    """The registered terms that build their own per-frame factor (``Term.frame_factor``)."""
    return [term for term in TERMS.values() if term.frame_factor is not None]
