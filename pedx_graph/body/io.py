"""Reading and validating SMPL-format body model files (``.npz`` and ``.pkl``).

Keys (smplx names): ``v_template (V,3)``, ``shapedirs (V,3,B)``, ``posedirs (V,3,207)`` (optional),
``J_regressor (24,V)`` (dense or scipy-sparse), ``weights (V,24)``, ``kintree_table (2,24)`` (row 0 = parents,
root parent stored as 4294967295 = uint32(-1), or -1), ``f (F,3)``.  Optional pedx keys:
``pedx_keypoint_names``, ``pedx_keypoint_vertex_ids``, ``pedx_keypoint_joint_ids`` (18 each) and
``provenance`` (JSON string).  See ``docs/architecture.md``.

Original SMPL pickles store arrays as ``chumpy`` objects.  They are read here without chumpy: a restricted
unpickler maps every chumpy class to a stub that keeps the pickled state and recovers the array from it
(chumpy keeps the value of a ``Ch`` in its ``x`` attribute).  Only numpy, scipy.sparse and a few builtins may
be constructed by the unpickler; anything else is refused.

Every malformed file raises :class:`ModelFormatError` (a ``ValueError``) naming the file and the key.
"""
from __future__ import annotations

import io
import json
import logging
import pickle
import warnings
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from pedx_graph.keypoints import PEDX_KEYPOINTS
from pedx_graph.utils import atomic_write_bytes

log = logging.getLogger(__name__)

#: Number of SMPL joints; the pose vector has 3 x NUM_JOINTS entries.
NUM_JOINTS = 24
#: Number of pose-corrective features, 9 x (NUM_JOINTS - 1).
NUM_POSE_FEATURES = 9 * (NUM_JOINTS - 1)
#: How the root's parent is stored in ``kintree_table`` (uint32(-1)).
ROOT_PARENT_UINT32 = 4294967295

REQUIRED_KEYS = ("v_template", "shapedirs", "J_regressor", "weights", "kintree_table", "f")

CONVERT_HINT = (
    "Convert it once to .npz in an environment that has chumpy installed, e.g.\n"
    "  import pickle, numpy as np, scipy.sparse as sp\n"
    "  d = pickle.load(open(PKL, 'rb'), encoding='latin1')\n"
    "  np.savez(NPZ, **{k: (v.toarray() if sp.issparse(v) else np.asarray(v)) for k, v in d.items()\n"
    "                   if k in ('v_template','shapedirs','posedirs','J_regressor','weights','kintree_table','f')})"
)


class ModelFormatError(ValueError):
    """A body model file is missing a key or holds an array of the wrong shape, type or value."""


@dataclass(frozen=True)
class ModelData:
    """Validated arrays of an SMPL-format model (float64 / int64)."""

    v_template: np.ndarray
    """(V, 3) rest vertices, metres, body frame (Y up, +Z forward)."""
    shapedirs: np.ndarray
    """(V, 3, B) shape blend shapes (first ``num_betas`` of the file's components)."""
    posedirs: np.ndarray | None
    """(V, 3, 207) pose-corrective blend shapes, or None when absent or all zero."""
    j_regressor: sp.csr_matrix
    """(24, V) joint regressor (sparse CSR)."""
    weights: np.ndarray
    """(V, 24) skinning weights."""
    parents: np.ndarray
    """(24,) parent of each joint, -1 for the root; parents[j] < j."""
    faces: np.ndarray
    """(F, 3) triangle vertex indices."""
    keypoint_names: tuple[str, ...] | None = None
    """``pedx_keypoint_names`` when present (equal to PEDX_KEYPOINTS)."""
    keypoint_vertex_ids: np.ndarray | None = None
    """(18,) ``pedx_keypoint_vertex_ids`` when present (-1 = not a vertex)."""
    keypoint_joint_ids: np.ndarray | None = None
    """(18,) ``pedx_keypoint_joint_ids`` when present (-1 = not a joint)."""
    provenance: dict | None = None
    """Parsed ``provenance`` JSON, or None."""
    source: str = "<arrays>"
    """Where the arrays came from (file path or a description), for messages."""

    @property
    def num_vertices(self) -> int:
        return int(self.v_template.shape[0])

    @property
    def num_betas(self) -> int:
        return int(self.shapedirs.shape[2])


# ----------------------------------------------------------------------------------------------- pickles


class _ChumpyStub:
    """Stands in for any chumpy class while unpickling; keeps the pickled state."""

    def __init__(self, *args, **kwargs):
        self._args = args
        self._state = {}

    def __setstate__(self, state):
        if isinstance(state, tuple) and len(state) == 2 and isinstance(state[0], dict):
            merged = dict(state[0])
            merged.update(state[1] or {})
            state = merged
        self._state = state if isinstance(state, dict) else {"state": state}

    def recover(self) -> np.ndarray | None:
        """The array this chumpy object held: its ``x`` (Ch) or ``a`` attribute, else the only array."""
        state = getattr(self, "_state", {})           # absent when built by copyreg without a state
        for key in ("x", "a"):
            value = state.get(key)
            if value is not None:
                value = _unstub(value)
                if isinstance(value, np.ndarray) or sp.issparse(value):
                    return value
        arrays = [v for v in state.values() if isinstance(v, np.ndarray)]
        return arrays[0] if len(arrays) == 1 else None


def _unstub(value):
    return value.recover() if isinstance(value, _ChumpyStub) else value


_SAFE_BUILTINS = {"object", "set", "frozenset", "dict", "list", "tuple", "slice", "complex", "bytearray",
                  "int", "float", "str", "bool", "range"}


class _RestrictedUnpickler(pickle.Unpickler):
    """Builds only numpy arrays/dtypes, scipy.sparse matrices, safe builtins and chumpy stubs."""

    def find_class(self, module, name):
        if module == "chumpy" or module.startswith("chumpy."):
            return _ChumpyStub
        if module in ("copy_reg", "copyreg") and name == "_reconstructor":
            import copyreg
            return copyreg._reconstructor
        if module == "_codecs" and name == "encode":          # how protocol-2 pickles store bytes
            import codecs
            return codecs.encode
        if module in ("__builtin__", "builtins") and name in _SAFE_BUILTINS:
            import builtins
            return getattr(builtins, name)
        if module == "numpy" or module.startswith("numpy."):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                return super().find_class(module, name)
        if module == "scipy.sparse" or module.startswith("scipy.sparse."):
            if hasattr(sp, name):
                return getattr(sp, name)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                return super().find_class(module, name)
        raise pickle.UnpicklingError(f"refusing to construct {module}.{name} from a model pickle")


def _rebuild_sparse(value):
    """Rebuild a CSC/CSR matrix from its pickled core arrays (old scipy pickles carry stale attributes)."""
    state = getattr(value, "__dict__", {})
    if not all(k in state for k in ("data", "indices", "indptr", "_shape")):
        return value
    cls = sp.csc_matrix if type(value).__name__.startswith("csc") else sp.csr_matrix
    return cls((np.asarray(state["data"]), np.asarray(state["indices"]), np.asarray(state["indptr"])),
               shape=tuple(int(n) for n in state["_shape"]))


def _load_pickle(path: Path) -> dict:
    try:
        with open(path, "rb") as fh:
            data = _RestrictedUnpickler(fh, encoding="latin1").load()
    except (pickle.UnpicklingError, EOFError, AttributeError, ImportError, TypeError, ValueError) as exc:
        raise ModelFormatError(f"{path}: cannot read the pickle ({exc}).\n{CONVERT_HINT}") from exc
    except OSError as exc:
        raise ModelFormatError(f"{path}: cannot read the file ({exc.strerror or exc})") from exc
    except Exception as exc:    # noqa: BLE001 -- corrupt opcodes reach the constructors the unpickler may call
        # (numpy, scipy.sparse, builtins) with arbitrary arguments, or ask for absurd sizes (MemoryError,
        # OverflowError, KeyError, IndexError, RecursionError, ...): all mean an unreadable file
        raise ModelFormatError(f"{path}: cannot read the pickle ({type(exc).__name__}: {exc})") from exc
    if not isinstance(data, dict):
        raise ModelFormatError(f"{path}: the pickle holds a {type(data).__name__}, expected a dict of arrays")
    out = {}
    for key, value in data.items():
        if isinstance(value, _ChumpyStub):
            arr = value.recover()
            if arr is None:
                raise ModelFormatError(
                    f"{path}: key '{key}' is a chumpy object whose array could not be recovered without "
                    f"chumpy.\n{CONVERT_HINT}")
            value = arr
        if sp.issparse(value):
            try:
                value = _rebuild_sparse(value)
            except (TypeError, ValueError) as exc:
                raise ModelFormatError(f"{path}: key '{key}' is an unreadable sparse matrix ({exc})") from exc
        out[str(key)] = value
    return out


#: What reading a corrupt ``.npz`` (a zip of ``.npy`` members) can raise besides OSError / ValueError / EOFError:
#: bad zip structure or CRC, bad deflate data, an unsupported compression method, the encrypted flag.
_ZIP_ERRORS = (zipfile.BadZipFile, zlib.error, NotImplementedError, RuntimeError)


def _load_npz(path: Path) -> dict:
    try:
        with open(path, "rb") as fh:
            magic = fh.read(4)
    except OSError as exc:
        raise ModelFormatError(f"{path}: cannot read the file ({exc.strerror or exc})") from exc
    if magic not in (b"PK\x03\x04", b"PK\x05\x06"):        # np.load would also take a bare .npy or a pickle
        raise ModelFormatError(f"{path}: not a readable .npz file (no zip archive signature; truncated or "
                               f"not an .npz)")
    try:
        with np.load(path, allow_pickle=False) as npz:
            out = {}
            for key in npz.files:
                try:
                    out[key] = npz[key]
                except ValueError as exc:
                    if "allow_pickle" not in str(exc):
                        raise ModelFormatError(f"{path}: key '{key}' cannot be read ({' '.join(str(exc).split())})"
                                               ) from exc
                    raise ModelFormatError(
                        f"{path}: key '{key}' is stored as a pickled object array, which is not loaded for "
                        f"safety; store it as a plain numeric array ({exc})") from exc
                except (OSError, EOFError, *_ZIP_ERRORS) as exc:
                    raise ModelFormatError(f"{path}: key '{key}' cannot be read ({' '.join(str(exc).split())})"
                                           ) from exc
            return out
    except ModelFormatError:
        raise
    except (OSError, ValueError, EOFError, *_ZIP_ERRORS) as exc:
        raise ModelFormatError(f"{path}: not a readable .npz file ({' '.join(str(exc).split())})") from exc


def read_model_file(path: str | Path) -> dict:
    """Raw key -> array mapping of an SMPL-format ``.npz`` or ``.pkl`` (no validation)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"body model file not found: {path}")
    suffix = path.suffix.lower()
    if suffix == ".npz":
        return _load_npz(path)
    if suffix in (".pkl", ".pickle"):
        return _load_pickle(path)
    raise ModelFormatError(f"{path}: unknown model file type '{suffix}' (expected .npz or .pkl)")


# -------------------------------------------------------------------------------------------- validation


def _float_array(raw: dict, key: str, shape: tuple, src: str) -> np.ndarray:
    """``raw[key]`` as float64 with the given shape (None = any size); must be finite."""
    value = raw[key]
    if sp.issparse(value):
        value = value.toarray()
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ModelFormatError(f"{src}: key '{key}' is not numeric ({exc})") from exc
    if arr.ndim != len(shape) or any(s is not None and s != a for s, a in zip(shape, arr.shape)):
        want = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
        raise ModelFormatError(f"{src}: key '{key}' has shape {arr.shape}, expected {want}")
    if not np.all(np.isfinite(arr)):
        raise ModelFormatError(f"{src}: key '{key}' contains NaN or infinite values")
    return arr


def _parents_from_kintree(raw: dict, src: str) -> np.ndarray:
    value = raw["kintree_table"]
    arr = np.asarray(value)
    if arr.ndim != 2 or arr.shape != (2, NUM_JOINTS):
        raise ModelFormatError(f"{src}: key 'kintree_table' has shape {arr.shape}, expected (2, {NUM_JOINTS})")
    if not np.issubdtype(arr.dtype, np.number):
        raise ModelFormatError(f"{src}: key 'kintree_table' is not numeric (dtype {arr.dtype})")
    row = arr[0].astype(np.float64)
    if not np.all(np.isfinite(row)) or np.any(row != np.round(row)):
        raise ModelFormatError(f"{src}: key 'kintree_table' holds non-integer parents")
    row = row.astype(np.int64)
    parents = np.where((row == ROOT_PARENT_UINT32) | (row == -1), -1, row)
    if parents[0] != -1:
        raise ModelFormatError(
            f"{src}: key 'kintree_table': joint 0 must be the root (parent {ROOT_PARENT_UINT32} or -1), "
            f"got parent {row[0]}")
    for j in range(1, NUM_JOINTS):
        if not 0 <= parents[j] < j:
            raise ModelFormatError(
                f"{src}: key 'kintree_table': parent of joint {j} is {row[j]}; parents must be listed before "
                f"their children (0 <= parent < joint)")
    return parents


def _optional_keypoints(raw: dict, src: str, num_vertices: int):
    keys = ("pedx_keypoint_names", "pedx_keypoint_vertex_ids", "pedx_keypoint_joint_ids")
    present = [k for k in keys if k in raw]
    if not present:
        return None, None, None
    if len(present) != 3:
        missing = [k for k in keys if k not in raw][0]
        raise ModelFormatError(f"{src}: missing key '{missing}' (the pedx keypoint keys come together)")
    names = tuple(str(n) for n in np.asarray(raw["pedx_keypoint_names"]).reshape(-1))
    if names != PEDX_KEYPOINTS:
        raise ModelFormatError(
            f"{src}: key 'pedx_keypoint_names' must equal {list(PEDX_KEYPOINTS)}, got {list(names)}")
    ids = {}
    for key, limit in (("pedx_keypoint_vertex_ids", num_vertices), ("pedx_keypoint_joint_ids", NUM_JOINTS)):
        arr = np.asarray(raw[key])
        if arr.shape != (len(PEDX_KEYPOINTS),) or not np.issubdtype(arr.dtype, np.integer):
            raise ModelFormatError(
                f"{src}: key '{key}' must be an integer array of shape ({len(PEDX_KEYPOINTS)},), "
                f"got {arr.dtype} {arr.shape}")
        arr = arr.astype(np.int64)
        if np.any((arr < -1) | (arr >= limit)):
            raise ModelFormatError(f"{src}: key '{key}' holds ids outside [-1, {limit})")
        ids[key] = arr
    vid, jid = ids["pedx_keypoint_vertex_ids"], ids["pedx_keypoint_joint_ids"]
    bad = np.flatnonzero((vid >= 0) == (jid >= 0))
    if bad.size:
        raise ModelFormatError(
            f"{src}: keypoint '{PEDX_KEYPOINTS[bad[0]]}': exactly one of 'pedx_keypoint_vertex_ids' and "
            f"'pedx_keypoint_joint_ids' must be >= 0")
    return names, vid, jid


def _provenance(raw: dict, src: str) -> dict | None:
    if "provenance" not in raw:
        return None
    value = raw["provenance"]
    text = value.item() if isinstance(value, np.ndarray) and value.shape == () else value
    if isinstance(text, bytes):
        text = text.decode("utf-8")
    if not isinstance(text, str):
        raise ModelFormatError(f"{src}: key 'provenance' must be a JSON string, got {type(text).__name__}")
    try:
        out = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ModelFormatError(f"{src}: key 'provenance' is not valid JSON ({exc})") from exc
    return out if isinstance(out, dict) else {"value": out}


def validate_model_arrays(raw: dict, source: str = "<arrays>", num_betas: int = 10) -> ModelData:
    """Check an SMPL-format key -> array mapping and return :class:`ModelData`.

    ``num_betas``: keep the first ``num_betas`` shape components (all of them if the file has fewer).
    Raises :class:`ModelFormatError` naming ``source`` and the offending key.
    """
    src = str(source)
    for key in REQUIRED_KEYS:
        if key not in raw:
            raise ModelFormatError(f"{src}: missing key '{key}' (SMPL-format keys: {list(REQUIRED_KEYS)} "
                                   f"and optional 'posedirs')")
    if num_betas < 1:
        raise ValueError(f"num_betas must be >= 1, got {num_betas}")
    v_template = _float_array(raw, "v_template", (None, 3), src)
    num_v = v_template.shape[0]
    if num_v < 1:
        raise ModelFormatError(f"{src}: key 'v_template' has no vertices")
    shapedirs = _float_array(raw, "shapedirs", (num_v, 3, None), src)
    if shapedirs.shape[2] < 1:
        raise ModelFormatError(f"{src}: key 'shapedirs' has no components")
    if shapedirs.shape[2] < num_betas:
        log.info("%s: 'shapedirs' has %d components (< %d requested); using all", src, shapedirs.shape[2],
                 num_betas)
    shapedirs = np.ascontiguousarray(shapedirs[:, :, :num_betas])
    posedirs = None
    if "posedirs" in raw and raw["posedirs"] is not None:
        posedirs = _float_array(raw, "posedirs", (num_v, 3, NUM_POSE_FEATURES), src)
        if not np.any(posedirs):
            posedirs = None
    jreg_raw = raw["J_regressor"]
    if sp.issparse(jreg_raw):
        if jreg_raw.shape != (NUM_JOINTS, num_v):
            raise ModelFormatError(
                f"{src}: key 'J_regressor' has shape {jreg_raw.shape}, expected ({NUM_JOINTS}, {num_v})")
        j_regressor = sp.csr_matrix(jreg_raw, dtype=np.float64)
        if not np.all(np.isfinite(j_regressor.data)):
            raise ModelFormatError(f"{src}: key 'J_regressor' contains NaN or infinite values")
    else:
        j_regressor = sp.csr_matrix(_float_array(raw, "J_regressor", (NUM_JOINTS, num_v), src))
    j_regressor.eliminate_zeros()
    weights = _float_array(raw, "weights", (num_v, NUM_JOINTS), src)
    row_sum = weights.sum(axis=1)
    if np.any(np.abs(row_sum - 1.0) > 1e-3):
        log.warning("%s: 'weights' rows do not sum to 1 (range %.4g..%.4g)", src, row_sum.min(), row_sum.max())
    parents = _parents_from_kintree(raw, src)
    faces_arr = np.asarray(raw["f"])
    if faces_arr.ndim != 2 or faces_arr.shape[1] != 3:
        raise ModelFormatError(f"{src}: key 'f' has shape {faces_arr.shape}, expected (F, 3)")
    if faces_arr.size and not np.issubdtype(faces_arr.dtype, np.integer):
        if not np.issubdtype(faces_arr.dtype, np.floating) or not np.all(np.isfinite(faces_arr)) \
                or np.any(faces_arr != np.round(faces_arr)):
            raise ModelFormatError(f"{src}: key 'f' must hold integer vertex indices (dtype {faces_arr.dtype})")
    if faces_arr.size and (faces_arr.min() < 0 or faces_arr.max() >= num_v):     # checked before the cast
        raise ModelFormatError(f"{src}: key 'f' holds vertex indices outside [0, {num_v}) (V mismatch?)")
    faces = faces_arr.astype(np.int64)
    names, vid, jid = _optional_keypoints(raw, src, num_v)
    return ModelData(v_template=v_template, shapedirs=shapedirs, posedirs=posedirs, j_regressor=j_regressor,
                     weights=weights, parents=parents, faces=faces, keypoint_names=names,
                     keypoint_vertex_ids=vid, keypoint_joint_ids=jid, provenance=_provenance(raw, src),
                     source=src)


def load_model_data(path: str | Path, num_betas: int = 10) -> ModelData:
    """Read and validate an SMPL-format ``.npz`` / ``.pkl`` file (see module docstring)."""
    return validate_model_arrays(read_model_file(path), source=str(path), num_betas=num_betas)


def save_model_npz(path: str | Path, arrays: dict) -> Path:
    """Write an SMPL-format dict to ``.npz`` atomically (sparse matrices stored dense)."""
    buf = io.BytesIO()
    np.savez(buf, **{k: (v.toarray() if sp.issparse(v) else np.asarray(v)) for k, v in arrays.items()})
    return atomic_write_bytes(path, buf.getvalue())
