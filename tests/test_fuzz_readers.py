"""Fuzzing the input readers: any bytes give a value or the project's own error naming the file (issue 14).

Readers covered: 2D labels (``read_label2d``), point PLYs (``read_ply_vertices`` / ``read_ply_points``),
KITTI calibration (``read_kitti_text``, ``read_cam_to_cam``, ``read_cam_to_range``,
``read_stereo_calibration``, ``read_calibrations``), SMPL labels (``read_smpl_label``), timestamps
(``read_timestamps``), configs (``load_config`` of FitConfig / SimConfig, ``load_sim_config`` + ``validate``,
``from_dict``) and the body model (``BodyModel.load``).  Each gets three kinds of input: (a) arbitrary bytes
(with a few magic prefixes), (b) structured-but-wrong content (the right syntax with wrong shapes, types,
counts, NaN / inf / huge numbers, missing or unknown keys) and (c) mutations (bit flips, byte edits,
deletions, insertions, nasty tokens, truncation) of a valid file written by the project's own writers (the
simulator, ``encode_ply_points``, ``save_config``, ``save_model_npz``).

The contract checked: the reader returns a value of the documented type and shape (finite where the reader
promises finite values), or raises the project's error type (``DataFormatError`` for data files,
``ConfigError`` for configs, ``ModelFormatError`` for body models) with a one-line message naming the file
(and the field where the format has fields).  Any other exception fails the test.  Hypothesis runs
derandomized, without an example database and with bounded example counts, so the suite is deterministic
and fast.
"""
from __future__ import annotations

import copy
import dataclasses
import datetime
import io
import json
import pickle
import re
import shutil
import tempfile
import types
import typing
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from hypothesis.configuration import set_hypothesis_home_dir

from pedx_graph.body import BodyModel, ModelFormatError
from pedx_graph.body.io import save_model_npz
from synthetic_model import synthetic_model_arrays
from pedx_graph.config import ConfigError, from_dict, load_config, save_config, to_dict
from pedx_graph.config_ranges import check_config
from pedx_graph.data.calib import (
    cam_to_cam_path,
    cam_to_range_path,
    discover_pairs,
    read_calibrations,
    read_cam_to_cam,
    read_cam_to_range,
    read_kitti_text,
    read_stereo_calibration,
)
from pedx_graph.data.labels2d import Label2D, read_label2d
from pedx_graph.data.ply import encode_ply_points, read_ply_points, read_ply_vertices
from pedx_graph.data.reader import read_timestamps, timestamps_path
from pedx_graph.data.smpl_labels import read_smpl_label
from pedx_graph.data.types import PEDX_KEYPOINTS, DataFormatError, SmplLabel, StereoCalibration
from pedx_graph.graph.config import FitConfig
from pedx_graph.sim.config import SimConfig, load_sim_config
from pedx_graph.sim.simulate import simulate

# Hypothesis keeps caches and failure patches in a storage folder (default: ``.hypothesis`` in the working
# directory, i.e. the repository); keep them in the system's temporary folder instead.
set_hypothesis_home_dir(Path(tempfile.gettempdir()) / "pedx-graph-hypothesis")

#: Example counts: (a) arbitrary bytes, (b) structured content, (c) mutations of a valid file.
N_BYTES, N_STRUCTURED, N_MUTATIONS = 100, 120, 120
#: Fewer for the YAML configs: PyYAML parses in pure Python (several ms per file).
N_CONFIG = 50


def fuzz(max_examples: int):
    """Deterministic, bounded hypothesis settings without an example database."""
    return settings(max_examples=max_examples, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                           HealthCheck.large_base_example])


# ------------------------------------------------------------------------------------------ seeds

SEQ = "20991231T1200"
TID = "0123456789abcdef0123456789abcdef"


@pytest.fixture(scope="module")
def scratch(tmp_path_factory) -> Path:
    """Folder the fuzzed files are written into (one fixed name per test, overwritten per example)."""
    return tmp_path_factory.mktemp("fuzz")


@pytest.fixture(scope="module")
def seeds(tmp_path_factory) -> dict[str, bytes]:
    """Valid files of every kind, written by the project's own writers (a tiny simulated scene)."""
    root = tmp_path_factory.mktemp("seed_scene")
    cfg = SimConfig()
    cfg.scene.n_pedestrians = 2
    cfg.scene.n_frames = 2
    cfg.scene.n_parked_cars = 0
    cfg.scene.n_moving_cars = 0
    simulate(root, cfg, seed=1)
    pair = discover_pairs(root / "calib")[0]
    label = sorted((root / "labels" / "2d").rglob("*.json"))[0]
    smpl = sorted((root / "labels" / "3d" / "smpl").rglob("*.json"))[0]
    segment = max((root / "labels" / "3d" / "segment").rglob("*.ply"), key=lambda p: p.stat().st_size)
    points = read_ply_points(segment)
    arrays = synthetic_model_arrays(num_vertices=40, seed=0)
    arrays.pop("posedirs")                      # optional key; keeps the archive small
    model = save_model_npz(root / "model.npz", arrays)
    fit_yaml = save_config(FitConfig(), root / "fit_config.yaml")
    return {
        "label2d": label.read_bytes(),
        "smpl": smpl.read_bytes(),
        "ply_binary": segment.read_bytes(),
        "ply_float32": encode_ply_points(points, binary=True, dtype="float32"),
        "ply_ascii": encode_ply_points(points, binary=False),
        "cam_to_cam": cam_to_cam_path(root / "calib", pair).read_bytes(),
        "cam_to_range": cam_to_range_path(root / "calib", pair).read_bytes(),
        "pair": pair.encode(),
        "timestamps": timestamps_path(root, SEQ).read_bytes(),
        "sim_yaml": (root / "sim_config.yaml").read_bytes(),
        "fit_yaml": fit_yaml.read_bytes(),
        "model": model.read_bytes(),
    }


def test_seeds_are_valid(seeds, scratch):
    """The unmutated seeds read without error (else the mutation tests would test nothing)."""
    path = write(scratch / "seed_label.json", seeds["label2d"])
    assert read_label2d(path, SEQ, "cam", 0, TID).n_labelled > 0
    assert read_smpl_label(write(smpl_path(scratch), seeds["smpl"])).pose.shape == (72,)
    for kind in ("ply_binary", "ply_float32", "ply_ascii"):
        assert len(read_ply_points(write(scratch / f"seed_{kind}.ply", seeds[kind]))) > 0
    calib_dir = write_calib(scratch / "seed_calib", seeds, seeds["cam_to_cam"], seeds["cam_to_range"])
    assert list(read_calibrations(calib_dir)) == [seeds["pair"].decode()]
    assert len(read_timestamps(write(scratch / "seed_ts.txt", seeds["timestamps"]))) == 2
    assert load_config(FitConfig, write(scratch / "seed_fit.yaml", seeds["fit_yaml"])) == FitConfig()
    assert load_sim_config(write(scratch / "seed_sim.yaml", seeds["sim_yaml"])).scene.n_frames == 2
    assert BodyModel.load(write(scratch / "seed_model.npz", seeds["model"])).num_vertices == 40


# ------------------------------------------------------------------------------------ strategies

#: Byte strings a mutation can splice in: numbers the parsers must refuse or bound, separators, encodings.
TOKENS = [b"nan", b"NaN", b"inf", b"-inf", b"Infinity", b"1e999", b"-1e999", b"1e-320", b"null", b"true",
          b"0", b"-1", b"1" + b"0" * 400, b"9" * 5000, b"\x00", b"\xff\xfe", b"\n", b"\r\n", b"\r", b" ",
          b"\t", b":", b",", b"[", b"]", b"{", b"}", b'"', b"-", b".", b"e", b"#", b"\xc2\xb2", b"\xd9\xa1",
          b"\xef\xbc\x91", b"[" * 1100, b"\\u0000", b"0x1f", b"1_000", b"end_header\n", b"element vertex 5\n",
          b"property list uchar int x\n", b"property double x\n", b"format binary_big_endian 1.0\n",
          b"!!python/object:os.system", b"&a [*a]", b"~", b"- - -"]

#: Prefixes that steer arbitrary bytes towards each decoder's format branches.
MAGICS = [b"", b"ply\n", b"ply\nformat ascii 1.0\n", b"ply\nformat binary_little_endian 1.0\n", b"{", b"[",
          b'{"category": "pedestrian", "keypoint": ', b"PK\x03\x04", b"PK\x05\x06", b"\x93NUMPY\x01\x00",
          b"\x80\x04", b"P_rect_00: ", b"R: ", b"%YAML 1.1\n", b"noise:\n  ", b"scene: ", b"\xef\xbb\xbf"]


def rng_of(draw) -> np.random.Generator:
    """A generator seeded by hypothesis, for structural choices with exact probabilities (hypothesis biases its
    small integer draws towards the bounds)."""
    return np.random.default_rng(draw(st.integers(0, 2 ** 32 - 1)))


def arbitrary_bytes() -> st.SearchStrategy[bytes]:
    """(a) Any bytes, often behind a format's magic."""
    return st.tuples(st.sampled_from(MAGICS), st.binary(max_size=2048)).map(lambda t: t[0] + t[1])


@st.composite
def mutated(draw, data: bytes) -> bytes:
    """(c) ``data`` after 1-6 random edits: bit flips, byte sets, deletions, insertions, tokens, truncation."""
    out = bytearray(data)
    for _ in range(draw(st.integers(1, 6))):
        op = draw(st.sampled_from(["flip", "set", "delete", "insert", "token", "truncate", "duplicate"]))
        pos = draw(st.integers(0, max(len(out) - 1, 0)))
        if op == "flip" and out:
            out[pos] ^= 1 << draw(st.integers(0, 7))
        elif op == "set" and out:
            out[pos] = draw(st.integers(0, 255))
        elif op == "delete":
            del out[pos:pos + draw(st.integers(1, 64))]
        elif op == "insert":
            out[pos:pos] = draw(st.binary(min_size=1, max_size=16))
        elif op == "token":
            out[pos:pos + draw(st.integers(0, 8))] = draw(st.sampled_from(TOKENS))
        elif op == "truncate":
            del out[pos:]
        elif op == "duplicate":
            out[pos:pos] = out[pos:pos + draw(st.integers(1, 64))]
    return bytes(out)


#: JSON text substituted for string markers after ``json.dumps``: numbers Python's json cannot map to a float.
RAW_JSON = {"@@BIG@@": "1" + "0" * 400, "@@NEGBIG@@": "-" + "9" * 400, "@@HUGE@@": "7" * 5000,
            "@@E999@@": "1e999", "@@DEEP@@": "[" * 3000 + "]" * 3000, "@@DEEP500@@": "[" * 500 + "1" + "]" * 500}

SCALARS = st.one_of(
    st.none(), st.booleans(), st.integers(-10 ** 6, 10 ** 6), st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from(["", "nan", "inf", "1e999", "12.5", " 7 ", "abc", "true", "1", "0", "1_0", "\uff11", "\u00b2"]),
    st.sampled_from(sorted(RAW_JSON)),
)
NASTY = st.recursive(SCALARS, lambda inner: st.lists(inner, max_size=4)
                     | st.dictionaries(st.sampled_from(["x", "y", "visible", "a", ""]), inner, max_size=3),
                     max_leaves=10)
COORD = st.one_of(st.floats(-5000, 5000), st.floats(-5000, 5000), st.integers(-5000, 5000), NASTY)


def json_text(obj) -> bytes:
    text = json.dumps(obj, allow_nan=True)
    for marker, raw in RAW_JSON.items():
        text = text.replace(json.dumps(marker), raw)
    return text.encode()


@st.composite
def label2d_json(draw) -> bytes:
    """(b) JSON of the 2D-label shape with wrong types, NaN / inf / huge numbers, nulls and unknown names."""
    entry = st.fixed_dictionaries({}, optional={"x": COORD, "y": COORD,
                                                "visible": st.one_of(st.booleans(), NASTY)})
    names = st.sampled_from(list(PEDX_KEYPOINTS) + ["elbow", ""])
    keypoint = st.one_of(st.none(), NASTY, st.dictionaries(names, st.one_of(st.none(), entry, NASTY), max_size=8))
    vertex = st.one_of(st.lists(COORD, min_size=2, max_size=2), st.lists(COORD, max_size=3), NASTY)
    polygon = st.one_of(st.none(), NASTY, st.lists(vertex, max_size=6))
    obj = draw(st.fixed_dictionaries({}, optional={
        "category": st.one_of(st.sampled_from(["pedestrian", "vehicle"]), NASTY),
        "tracking_id": st.one_of(st.just(TID), NASTY), "subtype": NASTY, "frame_id": NASTY,
        "keypoint": keypoint, "polygon": polygon}))
    if rng_of(draw).random() < 0.1:
        obj = draw(st.one_of(NASTY, st.just([obj])))
    return json_text(obj)


@st.composite
def vector(draw, length: int):
    """A release vector of ``length`` values, or one with a wrong length, a nested (possibly ragged) shape or
    a nasty element, or no vector at all."""
    rng = rng_of(draw)
    kind = rng.choice(["ok", "element", "length", "nested", "ragged", "nasty", "absent"])
    values = rng.normal(size=length).tolist()
    if kind == "element":
        values[int(rng.integers(length))] = draw(NASTY)
    elif kind == "length":
        values = values[:int(rng.integers(length))] if rng.random() < 0.5 else values + [0.5]
    elif kind == "nested":
        values = np.reshape(values, (-1, 3) if length % 3 == 0 else (1, -1)).tolist()
    elif kind == "ragged":
        values = [values[:length // 2], values[length // 2:] + [1.0]]
    elif kind == "nasty":
        values = draw(NASTY)
    return "@@ABSENT@@" if kind == "absent" else values


@st.composite
def smpl_json(draw) -> bytes:
    """(b) JSON of the SMPL-label shape: wrong lengths, nested shapes, strings, nulls, NaN / huge numbers."""
    obj = {"betas": draw(vector(10)), "pose": draw(vector(72)), "trans": draw(vector(3)),
           "keypoints_3d": draw(NASTY)}
    obj = {k: v for k, v in obj.items() if v != "@@ABSENT@@"}
    if rng_of(draw).random() < 0.1:
        obj = draw(st.one_of(NASTY, st.just([obj])))
    return json_text(obj)


PLY_TYPES = ["char", "uchar", "short", "ushort", "int", "uint", "float", "double", "int8", "uint8", "int16",
             "uint16", "int32", "uint32", "float32", "float64"]
PLY_NUMPY = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
             "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
             "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


@st.composite
def ply_file(draw) -> bytes:
    """(b) PLYs with odd headers (formats, counts, types, duplicate or list properties, several elements) and
    bodies that fit the header, nearly fit it (a row or a value more or less), are truncated or are random."""
    fmt = draw(st.sampled_from(["ascii", "binary_little_endian", "binary_big_endian", "binary_middle_endian"]))
    rng = rng_of(draw)
    lines = ["ply", f"format {fmt} 1.0"] if rng.random() < 0.95 else ["ply"]
    body = bytearray()
    order = ">" if fmt == "binary_big_endian" else "<"
    for _ in range(draw(st.integers(0, 3))):
        name = draw(st.sampled_from(["vertex", "vertex", "face", "camera"]))
        count = draw(st.integers(0, 6))
        count_text = str(count) if rng.random() < 0.9 else draw(st.sampled_from(
            ["-1", "1.5", "x", "99999999999", "0" * 30, "9" * 5000, "\u00b2", ""]))
        lines.append(f"element {name} {count_text}")
        props = []
        for _ in range(draw(st.integers(0, 5))):
            kind = draw(st.sampled_from(PLY_TYPES + ["list uchar int", "list float float", "quad", ""]))
            prop = draw(st.sampled_from(["x", "y", "z", "x", "intensity", "vertex_indices"]))
            lines.append(f"property {kind} {prop}")
            props.append(kind)
        scalar = all(k in PLY_NUMPY for k in props)
        rows = max(count + draw(st.sampled_from([0, 0, 0, -1, 1])), 0)
        if fmt == "ascii" or not scalar:
            for _ in range(rows):
                width = max(len(props) + draw(st.sampled_from([0, 0, 0, -1, 1])), 0)
                words = [draw(st.sampled_from(["1.5", "-2", "nan", "inf", "1e999", "300", "1e10", "abc", "3"]))
                         if rng.random() < 0.2 else repr(float(rng.normal(scale=10))) for _ in range(width)]
                body += (" ".join(words) + "\n").encode()
        else:
            dtype = np.dtype([(f"p{i}", order + PLY_NUMPY[k]) for i, k in enumerate(props)])
            body += rng.integers(0, 256, size=rows * dtype.itemsize, dtype=np.uint8).tobytes()
    for _ in range(draw(st.integers(0, 1))):
        lines.insert(draw(st.integers(1, len(lines))), draw(st.sampled_from(
            ["comment ok", "obj_info x", "", "bogus line", "property float x", "element", "format ascii"])))
    lines.append("end_header")
    data = ("\n".join(lines) + "\n").encode() + bytes(body)
    if rng.random() < 0.2:
        data = data[:int(rng.integers(len(data) + 1))]
    return data


def kitti_lines(text: bytes) -> list[tuple[str, list[str]]]:
    out = []
    for line in text.decode().splitlines():
        key, values = line.split(":", 1)
        out.append((key, values.split()))
    return out


@st.composite
def kitti_text(draw, seed: bytes) -> bytes:
    """(b) A calibration file's ``key: values`` lines with keys dropped, renamed or repeated, values replaced by
    NaN / inf / huge / non-numeric tokens or scaled, a value more or less, and garbage lines."""
    entries = kitti_lines(seed)
    if rng_of(draw).random() < 0.2 and [k for k, _ in entries] == ["R", "T"]:     # R + T -> Tr
        rot, trans = np.array(entries[0][1]).reshape(3, 3), np.array(entries[1][1]).reshape(3, 1)
        entries = [("Tr", np.hstack([rot, trans]).ravel().tolist())]
    for _ in range(draw(st.integers(1, 4))):
        i = draw(st.integers(0, len(entries) - 1)) if entries else 0
        op = draw(st.sampled_from(["drop", "rename", "repeat", "token", "scale", "more", "less", "garbage"]))
        if not entries:
            break
        key, values = entries[i]
        values = list(values)
        j = draw(st.integers(0, max(len(values) - 1, 0)))
        if op == "drop":
            del entries[i]
            continue
        if op == "rename":
            key = draw(st.sampled_from(["P_rect_02", "R_rect_00", "S_rect_00", "Tr", "R", "T", "calib_time", "",
                                        " P_rect_00", "p_rect_00"]))
        elif op == "repeat":
            entries.insert(i, (key, values))
        elif op == "token" and values:
            values[j] = draw(st.sampled_from(["nan", "inf", "-inf", "1e999", "abc", "1,5", "0x10", "--1", "1e308",
                                              "0", "-0", "\u00b2", "1" + "0" * 400]))
        elif op == "scale" and values and re.fullmatch(r"[-+0-9.e]+", values[j]):
            values[j] = repr(float(values[j]) * draw(st.sampled_from([0.0, -1.0, 1e-300, 1e300, 1e6, 1.0001])))
        elif op == "more":
            values.append(draw(st.sampled_from(["0", "1.0", "nan"])))
        elif op == "less" and values:
            values.pop()
        elif op == "garbage":
            entries.insert(i, (draw(st.sampled_from(["no colon here", "# comment", "", "::", "key:"])), []))
        entries[i] = (key, values)
    lines = [f"{k}: {' '.join(v)}" if not (k.startswith("#") or k in ("", "no colon here") or k.endswith(":"))
             else k for k, v in entries]
    return ("\n".join(lines) + "\n").encode()


@st.composite
def timestamps_text(draw) -> bytes:
    """(b) Timestamp tables: one or two columns, odd frame tokens (unicode digits, huge, signs, file names)."""
    frame = st.sampled_from(["0", "1", "0000002", "-3", "1.5", "seq_0000004.ply", "\u00b2", "\u0661", "\uff11",
                             "9" * 5000, "x", "1e3"])
    value = st.sampled_from(["0.1", "1512694800.123", "1512694800123456789", "nan", "inf", "1e999", "abc", "-0"])
    rows = draw(st.lists(st.tuples(frame, value, st.sampled_from([" ", ",", "\t", " , "])), min_size=0, max_size=6))
    two_columns = draw(st.booleans())
    lines = [f"{f}{sep}{v}" if two_columns else v for f, v, sep in rows]
    if draw(st.booleans()):
        lines.insert(0, "# frame seconds")
    return ("\n".join(lines) + "\n").encode()


YAML_VALUES = st.one_of(
    st.none(), st.booleans(), st.integers(-10, 10), st.integers(-10 ** 400, 10 ** 400),
    st.floats(allow_nan=True, allow_infinity=True), st.floats(-1e3, 1e3),
    st.sampled_from(["", "abc", "1.5", "2001-12-14", "none", "pedx", "default", "x_y", "a-b", "left", "any"]),
    st.lists(st.floats(-2, 2), max_size=4), st.lists(st.integers(0, 5000), max_size=3),
    st.lists(st.sampled_from(["a", "walk", "head"]), max_size=3),
    st.dictionaries(st.sampled_from(["a", "x"]), st.integers(0, 3), max_size=2),
    st.lists(st.lists(st.integers(0, 3), max_size=2), max_size=2),
)


def key_paths(data: dict, prefix: tuple = ()) -> list[tuple]:
    out = []
    for key, value in data.items():
        out.append(prefix + (key,))
        if isinstance(value, dict):
            out.extend(key_paths(value, prefix + (key,)))
    return out


#: The default configs as YAML would hold them.
CONFIG_DICTS = {FitConfig: to_dict(FitConfig()), SimConfig: to_dict(SimConfig())}


@st.composite
def config_dict(draw, base: dict) -> tuple[object, list[str]]:
    """(b) A config dict with 1-3 keys set to a wrong type / out-of-range value, deleted or unknown ones
    added (sometimes no mapping at all).  Returns it and the edited dotted key paths (``<root>``: all)."""
    data = json.loads(json.dumps(base))
    paths = key_paths(data)
    edited = []
    rng = rng_of(draw)
    for _ in range(draw(st.integers(1, 3))):
        path = paths[int(rng.integers(len(paths)))]
        parent = data
        for key in path[:-1]:
            parent = parent.get(key) if isinstance(parent, dict) else None
        if not isinstance(parent, dict):
            continue
        op = draw(st.sampled_from(["set", "set", "set", "scale", "delete", "unknown"]))
        if op == "set":
            parent[path[-1]] = draw(YAML_VALUES)
        elif op == "scale" and isinstance(parent.get(path[-1]), (int, float)) \
                and not isinstance(parent.get(path[-1]), bool):
            parent[path[-1]] = parent[path[-1]] * draw(st.sampled_from([-1, 0, 10 ** 6, -(10 ** 6)]))
        elif op == "delete":
            parent.pop(path[-1], None)
        elif op == "unknown":
            path = path[:-1] + (draw(st.sampled_from(["typo", "keypoint_sigma", "1", "n_frame"])),)
            parent[path[-1]] = draw(YAML_VALUES)
        edited.append(".".join(str(k) for k in path))
    if rng.random() < 0.05:
        data = draw(YAML_VALUES)
        edited = ["<root>"]
    return data, edited


@st.composite
def model_arrays_npz(draw, base: dict) -> bytes:
    """(b) A body-model archive with one or two arrays replaced (wrong shape, dtype, NaN, huge) or removed."""
    arrays = {k: (v.toarray() if hasattr(v, "toarray") else np.asarray(v)) for k, v in base.items()}
    rng = np.random.default_rng(draw(st.integers(0, 2 ** 32 - 1)))
    for _ in range(draw(st.integers(1, 2))):
        key = draw(st.sampled_from(sorted(arrays) + ["posedirs"]))
        op = draw(st.sampled_from(["drop", "shape", "dtype", "nan", "huge", "strings", "empty", "scalar"]))
        old = arrays.get(key, np.zeros((40, 3, 207)))
        if op == "drop":
            arrays.pop(key, None)
        elif op == "shape":
            shape = tuple(max(int(n) + int(rng.integers(-1, 2)), 0) for n in old.shape) or (2,)
            arrays[key] = rng.normal(size=shape)
        elif op == "dtype" and old.dtype.kind in "iufb":
            arrays[key] = old.astype(draw(st.sampled_from(["f4", "i8", "u1", "?", "c16", "S8", "U4", "M8[s]"])))
        elif op == "nan" and old.size and old.dtype.kind in "fc":
            arrays[key] = old.copy()
            arrays[key].flat[int(rng.integers(old.size))] = np.nan
        elif op == "huge" and old.size and old.dtype.kind in "iuf":
            arrays[key] = old.astype(np.float64) * 1e300
        elif op == "strings":
            arrays[key] = np.array(["nose"] * max(old.shape[:1] or (1,)))
        elif op == "empty":
            arrays[key] = np.zeros((0,) + old.shape[1:], dtype=old.dtype)
        elif op == "scalar":
            arrays[key] = np.array(3.0)
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


# ------------------------------------------------------------------------------------------ checks


def write(path: Path, data: bytes) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)
    return path


def smpl_path(scratch: Path) -> Path:
    return scratch / SEQ / f"{SEQ}_0000007_{TID}.json"


def write_calib(calib_dir: Path, seeds: dict, cam_to_cam: bytes, cam_to_range: bytes) -> Path:
    pair = seeds["pair"].decode()
    if calib_dir.exists():
        shutil.rmtree(calib_dir)
    write(cam_to_cam_path(calib_dir, pair), cam_to_cam)
    write(cam_to_range_path(calib_dir, pair), cam_to_range)
    return calib_dir


def data_error(read, *paths: Path, fields: typing.Callable[[str], bool] | None = None):
    """``read()``'s value, or None after a DataFormatError that names one of ``paths`` (and a field accepted by
    ``fields``, when given) in one line.  Any other exception propagates and fails the test."""
    try:
        return read()
    except DataFormatError as exc:
        message = str(exc)
        assert exc.path in {str(p) for p in paths}, message
        assert message.startswith(exc.path), message
        assert "\n" not in message and "\r" not in message, message
        if fields is not None:
            assert exc.field is not None and fields(exc.field), message
        return None


def config_error(read, source: str):
    """``read()``'s value, or None after a one-line ConfigError naming ``source``."""
    try:
        return read()
    except ConfigError as exc:
        message = str(exc)
        assert message.startswith(f"{source}:"), message
        assert "\n" not in message, message
        return None


def check_label(label) -> None:
    if label is None:
        return
    assert isinstance(label, Label2D)
    assert isinstance(label.category, str)
    view = label.view
    assert view.keypoints.shape == (18, 2) and view.keypoints.dtype == np.float64
    assert view.visible.shape == (18,) and view.visible.dtype == bool
    assert np.array_equal(np.isfinite(view.keypoints[:, 0]), np.isfinite(view.keypoints[:, 1]))
    assert not np.any(view.visible & ~view.labelled)
    if view.polygon is not None:
        assert view.polygon.ndim == 2 and view.polygon.shape[1] == 2 and len(view.polygon) >= 3
        assert np.all(np.isfinite(view.polygon))


def label_field(field: str) -> bool:
    return field in ("<json>", "category") or field.startswith(("keypoint", "polygon"))


def check_smpl(label) -> None:
    if label is None:
        return
    assert isinstance(label, SmplLabel)
    assert (label.sequence, label.frame, label.tracking_id) == (SEQ, 7, TID)
    for name, size in (("betas", 10), ("pose", 72), ("trans", 3)):
        value = getattr(label, name)
        assert value.shape == (size,) and value.dtype == np.float64 and np.all(np.isfinite(value)), name
    assert not set(label.extra) & {"betas", "pose", "trans"}


def smpl_field(field: str) -> bool:
    return field in ("<json>", "betas", "pose", "trans")


def check_ply(path: Path) -> None:
    vertices = data_error(lambda: read_ply_vertices(path), path, fields=bool)
    if vertices is not None:
        assert isinstance(vertices, dict)
        lengths = {v.shape for v in vertices.values()}
        assert len(lengths) <= 1 and all(len(s) == 1 for s in lengths)
    points = data_error(lambda: read_ply_points(path), path, fields=bool)
    if points is not None:
        assert points.ndim == 2 and points.shape[1] == 3 and points.dtype == np.float64
        assert np.all(np.isfinite(points))
        assert vertices is not None


def check_calibration(calib: StereoCalibration | None) -> None:
    if calib is None:
        return
    assert isinstance(calib, StereoCalibration)
    for name, shape in (("left_P_rect", (3, 4)), ("right_P_rect", (3, 4)), ("rect_R_cam", (3, 3)),
                        ("world_T_cam", (4, 4))):
        value = getattr(calib, name)
        assert value.shape == shape and np.all(np.isfinite(value)), name
    for rot in (calib.rect_R_cam, calib.world_T_cam[:3, :3]):
        np.testing.assert_allclose(rot.T @ rot, np.eye(3), atol=1e-9)
        assert np.linalg.det(rot) > 0
    np.testing.assert_array_equal(calib.world_T_cam[3], [0.0, 0.0, 0.0, 1.0])
    assert calib.focal_px > 0 and calib.baseline_m > 0
    assert all(isinstance(n, int) and n > 0 for n in calib.image_size)


def read_all_calibration(calib_dir: Path, seeds: dict, good_dir: Path) -> None:
    """Every calibration reader on the files in ``calib_dir``; a good second pair must survive a bad one."""
    pair = seeds["pair"].decode()
    c2c, c2r = cam_to_cam_path(calib_dir, pair), cam_to_range_path(calib_dir, pair)
    for path in (c2c, c2r):
        entries = data_error(lambda: read_kitti_text(path), path, fields=bool)
        if entries is not None:
            assert all(isinstance(k, str) and isinstance(v, str) for k, v in entries.items())
    data_error(lambda: read_cam_to_cam(c2c, left_camera=pair.split("-")[0]), c2c, fields=bool)
    world_T_cam = data_error(lambda: read_cam_to_range(c2r), c2r, fields=bool)
    if world_T_cam is not None:
        assert world_T_cam.shape == (4, 4) and np.all(np.isfinite(world_T_cam))
    calib = data_error(lambda: read_stereo_calibration(calib_dir, pair), c2c, c2r, fields=bool)
    check_calibration(calib)
    # a second, valid pair in the same folder: reading the folder gives at least that pair
    other = "aaa-bbb"
    write(cam_to_cam_path(calib_dir, other), cam_to_cam_path(good_dir, pair).read_bytes())
    write(cam_to_range_path(calib_dir, other), cam_to_range_path(good_dir, pair).read_bytes())
    calibrations = read_calibrations(calib_dir)
    assert other in calibrations
    assert (pair in calibrations) == (calib is not None)
    for value in calibrations.values():
        check_calibration(value)


def conforms(value, tp) -> bool:
    """Whether ``value`` has the declared type ``tp`` (dataclasses recursively)."""
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        hints = typing.get_type_hints(tp)
        return isinstance(value, tp) and all(conforms(getattr(value, f.name), hints[f.name])
                                             for f in dataclasses.fields(tp))
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        return any(conforms(value, arg) for arg in args)
    if tp is type(None):
        return value is None
    if origin is tuple:
        if not isinstance(value, tuple):
            return False
        if len(args) == 2 and args[1] is Ellipsis:
            return all(conforms(v, args[0]) for v in value)
        return len(value) == len(args) and all(conforms(v, a) for v, a in zip(value, args))
    if origin is list:
        return isinstance(value, list) and all(conforms(v, args[0]) for v in value)
    if tp is float:
        return isinstance(value, float)
    if tp is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if tp in (bool, str):
        return isinstance(value, tp)
    raise AssertionError(f"conforms(): type {tp} not handled")


def check_configs(path: Path, cls: type | None = None) -> None:
    """The config readers (of ``cls``; None: all) on ``path``: a value of the declared types, or a ConfigError
    naming the file."""
    source = str(path)
    if cls in (None, FitConfig):
        cfg = config_error(lambda: load_config(FitConfig, path), source)
        assert cfg is None or conforms(cfg, FitConfig)
    if cls in (None, SimConfig):
        cfg = config_error(lambda: load_config(SimConfig, path), source)
        assert cfg is None or conforms(cfg, SimConfig)
        sim = config_error(lambda: load_sim_config(path).validate(source), source)
        assert sim is None or conforms(sim, SimConfig)


def config_keys(message: str) -> list[str]:
    return re.findall(r"'([^']*)'", message)


# ------------------------------------------------------------------------------------------- 2D labels


@fuzz(N_BYTES)
@given(data=arbitrary_bytes())
def test_label2d_any_bytes(scratch, data):
    path = write(scratch / "label.json", data)
    check_label(data_error(lambda: read_label2d(path, SEQ, "cam", 0, TID), path, fields=label_field))


#: Regression inputs (each made a reader raise something else than its error type before it was fixed).
BIG_INT = b"1" + b"0" * 400               # beyond the float range: OverflowError in float() / np.asarray
LONG_INT = b"7" * 5000                    # beyond Python's int-string limit: ValueError in json / int()
DEEP_JSON = b"[" * 3000 + b"]" * 3000     # RecursionError in json


def smpl_text(trans: bytes) -> bytes:
    zeros = lambda n: ", ".join(["0.0"] * n).encode()   # noqa: E731
    return b'{"betas": [' + zeros(10) + b'], "pose": [' + zeros(72) + b'], "trans": ' + trans + b"}"


@fuzz(N_STRUCTURED)
@given(data=label2d_json())
@example(data=b'{"category": "pedestrian", "keypoint": {"nose": {"x": ' + BIG_INT + b', "y": 2}}}')
@example(data=b'{"category": "pedestrian", "polygon": [[' + BIG_INT + b', 1], [2, 2], [3, 1]]}')
@example(data=b'{"category": "pedestrian", "frame_id": ' + LONG_INT + b"}")
@example(data=DEEP_JSON)
def test_label2d_wrong_shapes_and_values(scratch, data):
    path = write(scratch / "label.json", data)
    check_label(data_error(lambda: read_label2d(path, SEQ, "cam", 0, TID), path, fields=label_field))


@fuzz(N_MUTATIONS)
@given(data=st.data())
def test_label2d_mutated(scratch, seeds, data):
    path = write(scratch / "label.json", data.draw(mutated(seeds["label2d"])))
    check_label(data_error(lambda: read_label2d(path, SEQ, "cam", 0, TID), path, fields=label_field))


# ------------------------------------------------------------------------------------------ SMPL labels


@fuzz(N_BYTES)
@given(data=arbitrary_bytes())
def test_smpl_label_any_bytes(scratch, data):
    path = write(smpl_path(scratch), data)
    check_smpl(data_error(lambda: read_smpl_label(path), path, fields=smpl_field))


@fuzz(N_STRUCTURED)
@given(data=smpl_json())
@example(data=smpl_text(b"[" + BIG_INT + b", 0, 0]"))
@example(data=smpl_text(b"[" + LONG_INT + b", 0, 0]"))
@example(data=smpl_text(DEEP_JSON))
def test_smpl_label_wrong_shapes_and_values(scratch, data):
    path = write(smpl_path(scratch), data)
    check_smpl(data_error(lambda: read_smpl_label(path), path, fields=smpl_field))


@fuzz(N_MUTATIONS)
@given(data=st.data())
def test_smpl_label_mutated(scratch, seeds, data):
    path = write(smpl_path(scratch), data.draw(mutated(seeds["smpl"])))
    check_smpl(data_error(lambda: read_smpl_label(path), path, fields=smpl_field))


# ------------------------------------------------------------------------------------------------ PLY


@fuzz(N_BYTES)
@given(data=arbitrary_bytes())
def test_ply_any_bytes(scratch, data):
    check_ply(write(scratch / "points.ply", data))


PLY_HEAD = b"ply\nformat binary_little_endian 1.0\nelement vertex 1\n"


@fuzz(N_STRUCTURED)
@given(data=ply_file())
@example(data=PLY_HEAD + b"property float x\nproperty float x\nproperty float z\nend_header\n" + bytes(12))
@example(data=b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\n"
              b"property uchar intensity\nend_header\n1 2 3 nan\n")
@example(data=b"ply\nformat ascii 1.0\nelement vertex " + LONG_INT + b"\nproperty float x\nend_header\n")
def test_ply_odd_headers_and_bodies(scratch, data):
    check_ply(write(scratch / "points.ply", data))


@pytest.mark.parametrize("value", ["nan", "inf", "256", "-1", "2.5", "1e300"])
def test_ply_ascii_integer_property_out_of_its_type(scratch, value):
    """An ASCII value an integer property cannot hold is an error naming the property, not a wrapped or
    truncated number."""
    path = write(scratch / "intensity.ply", b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\n"
                 b"property float y\nproperty float z\nproperty uchar intensity\nend_header\n1 2 3 7\n"
                 b"1 2 3 " + value.encode() + b"\n")
    with pytest.raises(DataFormatError, match="intensity") as info:
        read_ply_vertices(path)
    assert info.value.path == str(path) and info.value.field == "intensity"


@fuzz(N_MUTATIONS)
@given(kind=st.sampled_from(["ply_binary", "ply_float32", "ply_ascii"]), data=st.data())
def test_ply_mutated(scratch, seeds, kind, data):
    check_ply(write(scratch / "points.ply", data.draw(mutated(seeds[kind]))))


# -------------------------------------------------------------------------------------------- calibration


@fuzz(N_BYTES)
@given(cam_to_cam=arbitrary_bytes(), cam_to_range=st.one_of(st.none(), arbitrary_bytes()))
def test_calibration_any_bytes(scratch, seeds, cam_to_cam, cam_to_range):
    good = write_calib(scratch / "calib_good", seeds, seeds["cam_to_cam"], seeds["cam_to_range"])
    calib_dir = write_calib(scratch / "calib", seeds, cam_to_cam,
                            seeds["cam_to_range"] if cam_to_range is None else cam_to_range)
    read_all_calibration(calib_dir, seeds, good)


@fuzz(N_STRUCTURED)
@given(data=st.data())
def test_calibration_wrong_keys_and_values(scratch, seeds, data):
    good = write_calib(scratch / "calib_good", seeds, seeds["cam_to_cam"], seeds["cam_to_range"])
    which = data.draw(st.sampled_from(["cam_to_cam", "cam_to_range", "both"]))
    c2c, c2r = seeds["cam_to_cam"], seeds["cam_to_range"]
    if which in ("cam_to_cam", "both"):
        c2c = data.draw(kitti_text(c2c))
    if which in ("cam_to_range", "both"):
        c2r = data.draw(kitti_text(c2r))
    read_all_calibration(write_calib(scratch / "calib", seeds, c2c, c2r), seeds, good)


@fuzz(N_MUTATIONS)
@given(data=st.data())
def test_calibration_mutated(scratch, seeds, data):
    good = write_calib(scratch / "calib_good", seeds, seeds["cam_to_cam"], seeds["cam_to_range"])
    which = data.draw(st.sampled_from(["cam_to_cam", "cam_to_range"]))
    c2c, c2r = seeds["cam_to_cam"], seeds["cam_to_range"]
    if which == "cam_to_cam":
        c2c = data.draw(mutated(c2c))
    else:
        c2r = data.draw(mutated(c2r))
    read_all_calibration(write_calib(scratch / "calib", seeds, c2c, c2r), seeds, good)


# --------------------------------------------------------------------------------------------- timestamps


def check_timestamps(path: Path) -> None:
    table = data_error(lambda: read_timestamps(path), path)
    if table is not None:
        assert table and all(isinstance(f, int) and isinstance(t, float) and np.isfinite(t)
                             for f, t in table.items())


@fuzz(N_BYTES)
@given(data=arbitrary_bytes())
def test_timestamps_any_bytes(scratch, data):
    check_timestamps(write(scratch / "timestamps.txt", data))


@fuzz(N_STRUCTURED)
@given(data=timestamps_text())
@example(data="\u00b2 0.5\n".encode())
@example(data=LONG_INT + b" 0.5\n")
def test_timestamps_odd_tables(scratch, data):
    check_timestamps(write(scratch / "timestamps.txt", data))


@fuzz(N_MUTATIONS)
@given(data=st.data())
def test_timestamps_mutated(scratch, seeds, data):
    check_timestamps(write(scratch / "timestamps.txt", data.draw(mutated(seeds["timestamps"]))))


# ------------------------------------------------------------------------------------------------ configs


@fuzz(N_BYTES)
@given(data=arbitrary_bytes())
@example(data=b"\x80")                                         # not UTF-8
@example(data=b"{a")                                           # YAML's multi-line message
@example(data=b"ground:\n  world_up: abc\n")                   # an optional tuple given a string
@example(data=b"cameras:\n  forward:\n    image_size: [5]\n")  # a fixed-length tuple of the wrong length
@example(data=b"solver:\n  flip_segments: abc\n")              # a tuple given a scalar
@example(data=b"fps: " + BIG_INT + b"\n")                       # a float beyond the float range
@example(data=b"1: 2\na: 3\n")                                  # unknown keys of mixed types
@example(data=b"[" * 600)                                      # RecursionError in PyYAML
def test_config_any_bytes(scratch, data):
    check_configs(write(scratch / "config.yaml", data))


@fuzz(N_CONFIG)
@given(cls=st.sampled_from([FitConfig, SimConfig]), data=st.data())
def test_config_wrong_types_keys_and_ranges(scratch, cls, data):
    mapping, edited = data.draw(config_dict(CONFIG_DICTS[cls]))
    path = write(scratch / "config.yaml", yaml.safe_dump(mapping, sort_keys=False).encode())
    check_configs(path, cls)
    # the mapping itself, without YAML: a value of the declared types or an error naming the source and key
    try:
        cfg = from_dict(cls, mapping, source="<fuzz>")
    except ConfigError as exc:
        message = str(exc)
        assert message.startswith("<fuzz>:") and "\n" not in message, message
        named = config_keys(message)
        assert named, message
        key = named[0].rstrip(".")          # the first quoted name is the key at fault
        assert "<root>" in edited or any(path == key or path.startswith(key + ".") or key.startswith(path + ".")
                                         for path in edited), (message, edited)
    else:
        assert conforms(cfg, cls)


#: Values of the wrong type or range for any config key (as YAML could give them).
WRONG_CONFIG_VALUES = [None, "abc", [], [1.0, 2.0, 3.0, 4.0], [[1]], {"a": 1}, True, 10 ** 400, float("nan"),
                       -1, 1.5, datetime.date(2001, 12, 14)]


@pytest.mark.parametrize("cls", [FitConfig, SimConfig])
def test_config_every_key_with_wrong_values(cls):
    """Every key of the config, set to each wrong value: a ConfigError whose first quoted name is that key, or
    a config of the declared types, whose range check passes or raises a ConfigError."""
    base = CONFIG_DICTS[cls]
    for path in key_paths(base):
        dotted = ".".join(path)
        for value in WRONG_CONFIG_VALUES:
            mapping = copy.deepcopy(base)
            parent = mapping
            for key in path[:-1]:
                parent = parent[key]
            parent[path[-1]] = value
            try:
                cfg = from_dict(cls, mapping, source="<fuzz>")
            except ConfigError as exc:
                message = str(exc)
                assert message.startswith("<fuzz>:") and "\n" not in message, message
                named = config_keys(message)[0].rstrip(".")
                assert named == dotted or named.startswith(dotted + "."), (dotted, value, message)
                continue
            assert conforms(cfg, cls), (dotted, value)
            # range checks (SimConfig: also its validate) may name the other key of a pair (min / max)
            config_error(lambda: check_config(cfg, "<fuzz>"), "<fuzz>")


@fuzz(N_CONFIG)
@given(kind=st.sampled_from(["fit_yaml", "sim_yaml"]), data=st.data())
def test_config_mutated(scratch, seeds, kind, data):
    cls = FitConfig if kind == "fit_yaml" else SimConfig
    check_configs(write(scratch / "config.yaml", data.draw(mutated(seeds[kind]))), cls)


# ------------------------------------------------------------------------------------------- body model


def check_model(path: Path) -> None:
    try:
        model = BodyModel.load(path)
    except ModelFormatError as exc:
        message = str(exc)
        assert message.startswith(f"{path}:"), message
        assert "\n" not in message, message
    else:
        assert isinstance(model, BodyModel)
        assert model.v_template.ndim == 2 and model.v_template.shape[1] == 3
        assert np.all(np.isfinite(model.v_template)) and np.all(np.isfinite(model.shapedirs))


def npy_bytes() -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.zeros((2, 3)))
    return buf.getvalue()


@fuzz(N_BYTES)
@given(data=arbitrary_bytes())
@example(data=npy_bytes())        # a bare .npy: np.load returns an array, not an archive
@example(data=b"PK\x03\x04")
def test_body_model_any_bytes(scratch, data):
    check_model(write(scratch / "model.npz", data))


@pytest.fixture(scope="module")
def model_arrays() -> dict:
    arrays = synthetic_model_arrays(num_vertices=40, seed=0)
    arrays.pop("posedirs")
    return arrays


@fuzz(N_STRUCTURED)
@given(data=st.data())
def test_body_model_wrong_arrays(scratch, model_arrays, data):
    check_model(write(scratch / "model.npz", data.draw(model_arrays_npz(model_arrays))))


@fuzz(N_MUTATIONS)
@given(data=st.data())
def test_body_model_mutated(scratch, seeds, data):
    check_model(write(scratch / "model.npz", data.draw(mutated(seeds["model"]))))


@pytest.mark.parametrize("fraction", [0.0, 0.001, 0.25, 0.5, 0.75, 0.999])
def test_body_model_truncated(scratch, seeds, fraction):
    """A truncated archive (an interrupted copy) is a ModelFormatError naming the file, never BadZipFile."""
    path = write(scratch / f"truncated_{fraction}.npz", seeds["model"][:int(len(seeds["model"]) * fraction)])
    with pytest.raises(ModelFormatError, match=re.escape(str(path))):
        BodyModel.load(path)


@pytest.fixture(scope="module")
def model_pickle(model_arrays) -> bytes:
    """The synthetic model as an SMPL-style pickle (protocol 2, scipy-sparse regressor)."""
    return pickle.dumps(dict(model_arrays), protocol=2)


def check_model_pickle(path: Path) -> None:
    try:
        model = BodyModel.load(path)
    except ModelFormatError as exc:
        assert str(exc).startswith(f"{path}:"), str(exc)      # a conversion hint may follow on further lines
    else:
        assert isinstance(model, BodyModel) and np.all(np.isfinite(model.v_template))


@fuzz(N_BYTES)
@given(data=st.tuples(st.sampled_from([b"", b"\x80\x02}q\x00(X", b"\x80\x04\x95", b"(dp0\n"]),
                      st.binary(max_size=1024)).map(lambda t: t[0] + t[1]))
@example(data=b"\x80\x04\x95" + b"\xff" * 8)                     # a frame longer than any file
@example(data=b"\x80\x04\x8e" + (2 ** 62).to_bytes(8, "little"))  # bytes of 4 EiB
def test_body_model_pickle_any_bytes(scratch, data):
    check_model_pickle(write(scratch / "model.pkl", data))


@fuzz(N_MUTATIONS)
@given(data=st.data())
def test_body_model_pickle_mutated(scratch, model_pickle, data):
    check_model_pickle(write(scratch / "model.pkl", data.draw(mutated(model_pickle))))
