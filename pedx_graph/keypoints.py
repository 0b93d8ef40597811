"""Keypoint names shared by every layer (labels, body model, evaluation), and the shipped keypoint sets' names.

A keypoint set (one detector format: ``pedx18``, ``coco17``, ``coco18``, ``body25``, ``body25b``) is a data file
``pedx_graph/body/data/keypoint_sets/<set>.json``; :func:`load_keypoint_set` reads its names, PedX
equivalents and definitions.  Where those points sit on a body model (the linear map over vertices and
joints) is :mod:`pedx_graph.body.keypoint_defs`; the label readers need only the names, so they live here.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

#: The 18 PedX keypoint names, in the order used everywhere in this package (pedx-format notes).
PEDX_KEYPOINTS: tuple[str, ...] = (
    "nose", "leye", "reye", "head", "mouth", "neck",
    "lsho", "rsho", "lelb", "relb", "lwri", "rwri",
    "lhip", "rhip", "lknee", "rknee", "lankl", "rankl",
)

#: The 13 joints the paper evaluates (Tables II/III); "hip" is the mid-point of lhip and rhip.
EVAL_JOINTS: tuple[str, ...] = (
    "rknee", "lknee", "rankl", "lankl", "rsho", "lsho",
    "relb", "lelb", "rwri", "lwri", "head", "neck", "hip",
)

#: SMPL's 24 joint names (index order of the kinematic tree).
SMPL_JOINTS: tuple[str, ...] = (
    "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2",
    "left_ankle", "right_ankle", "spine3", "left_foot", "right_foot", "neck", "left_collar",
    "right_collar", "head", "left_shoulder", "right_shoulder", "left_elbow", "right_elbow",
    "left_wrist", "right_wrist", "left_hand", "right_hand",
)

#: SMPL's parent of each joint (-1 for the root).
SMPL_PARENTS: tuple[int, ...] = (
    -1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21,
)


#: Folder of the keypoint-set data files, one ``<set>.json`` each (written by ``tools/build_keypoint_sets.py``).
KEYPOINT_SET_DIR = Path(__file__).resolve().parent / "body" / "data" / "keypoint_sets"


@dataclass(frozen=True)
class KeypointSet:
    """One detector format's keypoints: names in file order, and their definitions on the body model.

    ``definitions`` maps a topology (``"open"``: the open default model, identified by its faces' digest;
    ``"smpl"``: the SMPL topology, V = 6890) to ``name -> {"vertices": [[id, w], ...], "joints": [[id, w], ...]}``.
    ``pedx_equivalent`` maps the names that are PedX's points (same body point) to the PedX name; the steps
    that need a named point (initialisation, flips, body size) look names up through it (:meth:`index_of`).
    """

    name: str
    keypoints: tuple[str, ...]
    pedx_equivalent: dict[str, str]
    definitions: dict[str, dict]
    description: str = ""

    def index_of(self, pedx_name: str) -> int | None:
        """Index in this set of the keypoint that is PedX's ``pedx_name``, or None when the set lacks it."""
        for i, n in enumerate(self.keypoints):
            if self.pedx_equivalent.get(n) == pedx_name:
                return i
        return None


def keypoint_set_names() -> tuple[str, ...]:
    """Names of the shipped keypoint sets (the data files' stems), sorted."""
    return tuple(sorted(p.stem for p in KEYPOINT_SET_DIR.glob("*.json")))


@lru_cache(maxsize=None)
def load_keypoint_set(name: str) -> KeypointSet:
    """The shipped keypoint set ``name`` (``pedx18``, ``coco17``, ``coco18``, ``body25``, ``body25b``).

    Raises KeyError naming the known sets when there is no such data file.
    """
    path = KEYPOINT_SET_DIR / f"{name}.json"
    if not path.is_file():
        raise KeyError(f"unknown keypoint set {name!r}; known: {', '.join(keypoint_set_names())}")
    doc = json.loads(path.read_text(encoding="utf-8"))
    return KeypointSet(name=doc["name"], keypoints=tuple(doc["keypoints"]),
                       pedx_equivalent=dict(doc["pedx_equivalent"]), definitions=doc["definitions"],
                       description=doc.get("description", ""))


#: Parts of keypoint names that belong to the hips and legs (every shipped set's naming).
_LOWER_BODY_NAMES = ("hip", "knee", "ank", "toe", "heel")


@lru_cache(maxsize=None)
def _lower_body_tuple(name: str) -> tuple[bool, ...]:
    return tuple(any(part in k.lower() for part in _LOWER_BODY_NAMES) for k in load_keypoint_set(name).keypoints)


def lower_body_mask(name: str) -> np.ndarray:
    """(K,) bool: the keypoints of set ``name`` on the hips and legs (hips, knees, ankles, heels, toes); the
    others are the upper body (head, neck, shoulders, arms)."""
    return np.array(_lower_body_tuple(name), dtype=bool)


def mirror_index(names: tuple[str, ...]) -> tuple[tuple[int, int], ...]:
    """Left/right index pairs of a keypoint set, from its names (``LShoulder``/``RShoulder``,
    ``left_eye``/``right_eye``, ``lsho``/``rsho``)."""
    index = {n: i for i, n in enumerate(names)}
    pairs = []
    for i, name in enumerate(names):
        mirror = None
        if name.startswith("left_"):
            mirror = "right_" + name[5:]
        elif len(name) > 1 and name[0] == "L" and name[1].isupper():
            mirror = "R" + name[1:]
        elif name[0] == "l" and ("r" + name[1:]) in index:
            mirror = "r" + name[1:]
        if mirror is not None and mirror in index:
            pairs.append((i, index[mirror]))
    return tuple(pairs)


#: A limb's two ends by part of their names (every shipped set's naming: ``LShoulder``, ``left_shoulder``,
#: ``lsho``), joined on each side of the body.
_LIMB_PARTS = (("sho", "elb"), ("elb", "wri"), ("sho", "hip"), ("hip", "knee"), ("knee", "ank"))


@lru_cache(maxsize=None)
def limb_edges(name: str) -> tuple[tuple[int, int, str], ...]:
    """Limbs of keypoint set ``name`` as ``(i, j, side)``, from its names (:func:`mirror_index` tells the
    left from the right): shoulder-elbow, elbow-wrist, shoulder-hip, hip-knee and knee-ankle on each side
    (``side`` ``"left"`` / ``"right"``), and shoulder-shoulder and hip-hip across (``side`` ``""``); a set
    without some of those points has fewer."""
    names = load_keypoint_set(name).keypoints
    pairs = mirror_index(names)
    sides = {**{i: "left" for i, _ in pairs}, **{j: "right" for _, j in pairs}}

    def find(part: str, side: str) -> int | None:
        found = [i for i, n in enumerate(names) if part in n.lower() and sides.get(i) == side]
        return found[0] if found else None

    edges = []
    for side in ("left", "right"):
        for a, b in _LIMB_PARTS:
            i, j = find(a, side), find(b, side)
            if i is not None and j is not None:
                edges.append((i, j, side))
    for part in ("sho", "hip"):
        i, j = find(part, "left"), find(part, "right")
        if i is not None and j is not None:
            edges.append((i, j, ""))
    return tuple(edges)


def mirror_order(name: str) -> np.ndarray:
    """(K,) index that swaps every left/right pair of set ``name`` (:func:`mirror_index`), the others in
    place: ``uv[mirror_order(name)]`` is the detection with the person's left taken for its right."""
    order = np.arange(len(load_keypoint_set(name).keypoints))
    for a, b in mirror_index(load_keypoint_set(name).keypoints):
        order[a], order[b] = b, a
    return order
