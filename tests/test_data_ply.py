"""Point PLY reading and writing: ascii / binary, non-finite masking, malformed files."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from pedx_graph.data.ply import encode_ply_points, read_ply_points, read_ply_vertices, write_ply_points
from pedx_graph.data.types import DataFormatError


@pytest.mark.parametrize("binary", [True, False])
@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_round_trip(tmp_path, binary, dtype):
    points = np.random.default_rng(0).normal(size=(50, 3)) * 10
    path = write_ply_points(tmp_path / "a.ply", points, binary=binary, dtype=dtype)
    back = read_ply_points(path)
    expected = points.astype(dtype).astype(np.float64)
    np.testing.assert_array_equal(back, expected)


def test_empty_cloud(tmp_path):
    path = write_ply_points(tmp_path / "e.ply", np.zeros((0, 3)))
    assert read_ply_points(path).shape == (0, 3)


@pytest.mark.parametrize("binary", [True, False])
def test_nonfinite_points_masked(tmp_path, binary):
    points = np.array([[1.0, 2.0, 3.0], [np.inf, np.inf, np.inf], [4.0, 5.0, 6.0], [np.nan, 0.0, 0.0]])
    path = write_ply_points(tmp_path / "inf.ply", points, binary=binary, dtype="float32")
    np.testing.assert_array_equal(read_ply_points(path), [[1, 2, 3], [4, 5, 6]])
    assert read_ply_points(path, mask_nonfinite=False).shape == (4, 3)


def test_a_signalling_nan_in_a_binary_float_is_masked_without_a_warning(tmp_path):
    """A binary float32 whose bits are a signalling NaN (a corrupt or padded file) is a non-finite point like
    any other: masked, and no RuntimeWarning from quieting it while widening to float64."""
    body = np.array([[1.0, 2.0, 3.0], [0.0, 0.0, 0.0]], dtype="<f4")
    body.view("<u4")[1, 0] = 0x7F800001                     # exponent all ones, quiet bit clear
    header = b"ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\nproperty float y\n" \
             b"property float z\nend_header\n"
    path = tmp_path / "snan.ply"
    path.write_bytes(header + body.tobytes())
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        np.testing.assert_array_equal(read_ply_points(path), [[1, 2, 3]])


def test_extra_properties_big_endian_and_preceding_element(tmp_path):
    """A binary big-endian file with an intensity property and a scalar element before 'vertex'."""
    rows = np.array([(1.5, -2.0, 3.25, 7), (0.0, 1.0, 2.0, 9)],
                    dtype=[("x", ">f4"), ("y", ">f4"), ("z", ">f4"), ("intensity", ">u2")])
    header = ("ply\nformat binary_big_endian 1.0\nelement meta 2\nproperty int stamp\n"
              "element vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
              "property ushort intensity\nend_header\n").encode()
    path = tmp_path / "be.ply"
    path.write_bytes(header + np.array([1, 2], ">i4").tobytes() + rows.tobytes())
    np.testing.assert_array_equal(read_ply_points(path), [[1.5, -2.0, 3.25], [0.0, 1.0, 2.0]])
    assert read_ply_vertices(path)["intensity"].tolist() == [7, 9]


def test_ascii_with_face_element_after_vertices(tmp_path):
    text = ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
            "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
            "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    path = tmp_path / "mesh.ply"
    path.write_text(text)
    assert read_ply_points(path).shape == (3, 3)


@pytest.mark.parametrize("content, field", [
    (b"not a ply", "header"),
    (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n1 2\n", "z"),
    (b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
     b"end_header\n1 2 3\n", "vertex"),
    (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\n"
     b"end_header\n1 b 3\n", "vertex"),
    (b"ply\nformat binary_little_endian 1.0\nelement vertex 5\nproperty float x\nproperty float y\n"
     b"property float z\nend_header\n" + b"\0" * 12, "vertex"),
])
def test_malformed(tmp_path, content, field):
    path = tmp_path / "bad.ply"
    path.write_bytes(content)
    with pytest.raises(DataFormatError) as info:
        read_ply_points(path)
    assert "bad.ply" in str(info.value) and f"'{field}'" in str(info.value)


def test_encode_rejects_wrong_shape():
    with pytest.raises(ValueError):
        encode_ply_points(np.zeros((3, 2)))
