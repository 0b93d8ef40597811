"""Model file reading: npz/pkl, chumpy pickles without chumpy, and a clear error for every malformed file."""
import json
import pickle
import sys
import types

import numpy as np
import pytest
import scipy.sparse as sp

from pedx_graph.body import BodyModel, ModelFormatError
from pedx_graph.body import model as model_module
from pedx_graph.body.io import load_model_data, save_model_npz


def _write(tmp_path, arrays, name="model.npz"):
    return save_model_npz(tmp_path / name, arrays)


def _copy(arrays):
    return {k: (v.copy() if hasattr(v, "copy") else v) for k, v in arrays.items()}


def test_npz_and_pkl_give_the_same_arrays(synthetic_smpl_file, synthetic_smpl_pkl):
    a, b = load_model_data(synthetic_smpl_file), load_model_data(synthetic_smpl_pkl)
    for name in ("v_template", "shapedirs", "posedirs", "weights", "parents", "faces"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    np.testing.assert_array_equal(a.j_regressor.toarray(), b.j_regressor.toarray())
    assert a.parents[0] == -1 and a.faces.dtype == np.int64
    assert a.provenance["builder"].endswith("synthetic_model_arrays")


def test_model_properties(synthetic_body_model, synthetic_smpl_arrays):
    m = synthetic_body_model
    assert m.num_vertices == 300 and m.num_joints == 24 and m.num_betas == 10
    assert m.faces.shape == synthetic_smpl_arrays["f"].shape
    assert list(m.parents[:5]) == [-1, 0, 0, 0, 1]
    assert m.provenance is not None and m.keypoint_names[0] == "nose"


def test_more_shape_components_keep_the_first_num_betas(tmp_path, synthetic_smpl_arrays):
    arrays = _copy(synthetic_smpl_arrays)
    extra = np.random.default_rng(30).normal(size=(300, 3, 290)) * 1e-3
    arrays["shapedirs"] = np.concatenate([arrays["shapedirs"], extra], axis=2)
    data = load_model_data(_write(tmp_path, arrays))
    assert data.num_betas == 10
    np.testing.assert_array_equal(data.shapedirs, synthetic_smpl_arrays["shapedirs"])
    assert load_model_data(_write(tmp_path, arrays, "b.npz"), num_betas=16).num_betas == 16


def test_root_parent_as_minus_one_and_zero_posedirs(tmp_path, synthetic_smpl_arrays):
    arrays = _copy(synthetic_smpl_arrays)
    kintree = arrays["kintree_table"].astype(np.int64)
    kintree[0, 0] = -1
    arrays["kintree_table"] = kintree
    arrays["posedirs"] = np.zeros_like(arrays["posedirs"])
    data = load_model_data(_write(tmp_path, arrays))
    assert data.parents[0] == -1 and data.posedirs is None
    del arrays["posedirs"]
    assert load_model_data(_write(tmp_path, arrays, "b.npz")).posedirs is None


def _malformed_cases(base):
    """(name, key expected in the message, mutate(arrays))."""
    def drop(key):
        return lambda a: a.pop(key)

    def set_(key, value):
        def f(a):
            a[key] = value(a) if callable(value) else value
        return f

    def nan_in(key):
        def f(a):
            arr = np.array(a[key].toarray() if sp.issparse(a[key]) else a[key], dtype=float)
            arr.flat[7] = np.nan
            a[key] = arr
        return f

    def kintree(fn):
        def f(a):
            k = a["kintree_table"].astype(np.int64)
            fn(k)
            a["kintree_table"] = k
        return f

    cases = [(f"missing {k}", k, drop(k)) for k in ("v_template", "shapedirs", "J_regressor", "weights",
                                                    "kintree_table", "f")]
    cases += [
        ("v_template 2 columns", "v_template", set_("v_template", lambda a: a["v_template"][:, :2])),
        ("shapedirs V mismatch", "shapedirs", set_("shapedirs", lambda a: a["shapedirs"][:-1])),
        ("posedirs wrong count", "posedirs", set_("posedirs", lambda a: a["posedirs"][:, :, :100])),
        ("regressor V mismatch", "J_regressor", set_("J_regressor", lambda a: a["J_regressor"].toarray()[:, :-1])),
        ("regressor 23 joints", "J_regressor", set_("J_regressor", lambda a: a["J_regressor"].toarray()[:-1])),
        ("weights wrong joints", "weights", set_("weights", lambda a: a["weights"][:, :20])),
        ("faces out of range", "'f'", set_("f", lambda a: a["f"] + 1000)),
        ("faces 4 columns", "'f'", set_("f", lambda a: np.zeros((3, 4), dtype=np.int64))),
        ("NaN in template", "v_template", nan_in("v_template")),
        ("NaN in shapedirs", "shapedirs", nan_in("shapedirs")),
        ("NaN in weights", "weights", nan_in("weights")),
        ("NaN in regressor", "J_regressor", nan_in("J_regressor")),
        ("kintree parent after child", "kintree_table", kintree(lambda k: k[0].__setitem__(4, 9))),
        ("kintree root not first", "kintree_table", kintree(lambda k: k[0].__setitem__(0, 3))),
        ("kintree self parent", "kintree_table", kintree(lambda k: k[0].__setitem__(5, 5))),
        ("kintree wrong shape", "kintree_table", set_("kintree_table", lambda a: a["kintree_table"][:, :20])),
        ("keypoint names", "pedx_keypoint_names",
         set_("pedx_keypoint_names", lambda a: np.array(list(a["pedx_keypoint_names"])[::-1]))),
        ("keypoint ids both", "pedx_keypoint_vertex_ids",
         set_("pedx_keypoint_joint_ids", lambda a: np.zeros(18, dtype=np.int64))),
        ("keypoint id range", "pedx_keypoint_vertex_ids",
         set_("pedx_keypoint_vertex_ids", lambda a: np.where(a["pedx_keypoint_vertex_ids"] >= 0, 10**6, -1))),
        ("keypoint keys partial", "pedx_keypoint_joint_ids", drop("pedx_keypoint_joint_ids")),
        ("provenance not json", "provenance", set_("provenance", np.array("{not json"))),
    ]
    return cases


CASES = _malformed_cases(None)


@pytest.mark.parametrize("name,key,mutate", CASES, ids=[c[0] for c in CASES])
def test_malformed_file_raises_model_format_error_naming_file_and_key(name, key, mutate, tmp_path,
                                                                       synthetic_smpl_arrays):
    arrays = _copy(synthetic_smpl_arrays)
    mutate(arrays)
    path = _write(tmp_path, arrays, "bad_model.npz")
    with pytest.raises(ModelFormatError) as info:
        BodyModel.load(path)
    message = str(info.value)
    assert "bad_model.npz" in message and key.strip("'") in message, message
    assert isinstance(info.value, ValueError)


def test_missing_file_and_unknown_suffix(tmp_path):
    with pytest.raises(FileNotFoundError):
        BodyModel.load(tmp_path / "nope.npz")
    (tmp_path / "model.obj").write_text("v 0 0 0\n")
    with pytest.raises(ModelFormatError, match="model.obj"):
        BodyModel.load(tmp_path / "model.obj")
    (tmp_path / "junk.npz").write_bytes(b"not a zip file")
    with pytest.raises(ModelFormatError, match="junk.npz"):
        BodyModel.load(tmp_path / "junk.npz")


def test_default_model_missing_gives_clear_file_not_found(tmp_path, monkeypatch):
    monkeypatch.setattr(model_module, "default_model_path", lambda: tmp_path / "pedx_open_neutral.npz")
    with pytest.raises(FileNotFoundError, match="build_open_body_model"):
        BodyModel.load()


def test_default_model_loads_when_present(tmp_path, monkeypatch, synthetic_smpl_file):
    monkeypatch.setattr(model_module, "default_model_path", lambda: synthetic_smpl_file)
    assert BodyModel.load().num_vertices == 300


# ------------------------------------------------------------------------------------ chumpy pickles


def _install_fake_chumpy(monkeypatch):
    """Modules ``chumpy`` and ``chumpy.ch`` with a class ``Ch`` keeping its array in ``x`` (as chumpy does)."""
    chumpy = types.ModuleType("chumpy")
    ch = types.ModuleType("chumpy.ch")

    class Ch:
        def __init__(self, x):
            self.x = np.asarray(x)
            self._dirty_vars = set()
            self._cache = {"r": None}

    class Select:                         # a chumpy expression node keeping its operand in ``a``
        def __init__(self, a):
            self.a = a
            self.idxs = np.arange(3)

    Ch.__module__, Ch.__qualname__ = "chumpy.ch", "Ch"
    Select.__module__, Select.__qualname__ = "chumpy.reordering", "Select"
    ch.Ch = Ch
    reordering = types.ModuleType("chumpy.reordering")
    reordering.Select = Select
    chumpy.ch = ch
    chumpy.reordering = reordering
    for name, mod in (("chumpy", chumpy), ("chumpy.ch", ch), ("chumpy.reordering", reordering)):
        monkeypatch.setitem(sys.modules, name, mod)
    return Ch, Select


@pytest.mark.parametrize("protocol", [0, 2])
def test_chumpy_pickle_is_read_without_chumpy(protocol, tmp_path, monkeypatch, synthetic_smpl_arrays):
    """Protocol 0 writes Python-2 names (copy_reg._reconstructor, __builtin__), like the original SMPL files."""
    Ch, Select = _install_fake_chumpy(monkeypatch)
    arrays = _copy(synthetic_smpl_arrays)
    for key in ("pedx_keypoint_names", "pedx_keypoint_vertex_ids", "pedx_keypoint_joint_ids", "provenance"):
        arrays.pop(key)
    payload = dict(arrays)
    for key in ("v_template", "shapedirs", "posedirs"):
        payload[key] = Ch(arrays[key])
    payload["weights"] = Select(Ch(arrays["weights"]))       # nested chumpy objects
    payload["J_regressor"] = sp.csc_matrix(arrays["J_regressor"])
    payload["bs_style"] = "lbs"
    path = tmp_path / "SMPL_like.pkl"
    with open(path, "wb") as fh:
        pickle.dump(payload, fh, protocol=protocol)
    if protocol == 0:
        assert b"copy_reg" in path.read_bytes()
    for name in ("chumpy", "chumpy.ch", "chumpy.reordering"):
        monkeypatch.delitem(sys.modules, name)
    assert "chumpy" not in sys.modules
    data = load_model_data(path)
    for key in ("v_template", "shapedirs", "posedirs", "weights"):
        np.testing.assert_array_equal(getattr(data, key), arrays[key])
    np.testing.assert_allclose(data.j_regressor.toarray(), arrays["J_regressor"].toarray())
    # 300 vertices, no pedx keys: not the SMPL topology, so keypoints need the explicit fallback
    with pytest.raises(ValueError, match="pedx_keypoint"):
        BodyModel.load(path)
    assert BodyModel.load(path, joints_only_keypoints=True).keypoint_map.source == "joints-only"


def test_unrecoverable_chumpy_object_explains_conversion(tmp_path, monkeypatch, synthetic_smpl_arrays):
    Ch, _ = _install_fake_chumpy(monkeypatch)
    payload = dict(_copy(synthetic_smpl_arrays))
    broken = Ch(np.zeros(3))
    del broken.x
    payload["v_template"] = broken
    path = tmp_path / "broken.pkl"
    with open(path, "wb") as fh:
        pickle.dump(payload, fh, protocol=2)
    for name in ("chumpy", "chumpy.ch", "chumpy.reordering"):
        monkeypatch.delitem(sys.modules, name)
    with pytest.raises(ModelFormatError, match=r"(?s)broken\.pkl.*v_template.*Convert it once"):
        load_model_data(path)


class _Evil:
    def __reduce__(self):
        import os
        return (os.getcwd, ())


def test_pickle_with_arbitrary_callables_is_refused(tmp_path, synthetic_smpl_arrays):
    payload = dict(_copy(synthetic_smpl_arrays))
    payload["extra"] = _Evil()
    path = tmp_path / "evil.pkl"
    with open(path, "wb") as fh:
        pickle.dump(payload, fh, protocol=2)
    with pytest.raises(ModelFormatError, match="refusing"):
        load_model_data(path)


def test_provenance_roundtrip(tmp_path, synthetic_smpl_arrays):
    arrays = _copy(synthetic_smpl_arrays)
    arrays["provenance"] = np.array(json.dumps({"builder": "x", "seed": 3}))
    assert load_model_data(_write(tmp_path, arrays)).provenance == {"builder": "x", "seed": 3}


def test_shipped_default_model_is_valid_when_present():
    """The open default model (built by tools/build_open_body_model.py) loads with its own keypoints."""
    assert model_module.default_model_path().is_file(), "the shipped open default model is missing"
    from pedx_graph.body.cli import model_heights

    model = BodyModel.load()
    assert model.num_joints == 24 and model.keypoint_map.source == "file"
    assert model.provenance is not None
    heights = model_heights(model)
    assert 1.3 < heights["mean"] < 2.1
