"""Shared pytest fixtures.

Body model fixtures write synthetic SMPL-format files (random body-like template, shape and pose blend
shapes, sparse joint regressor, uint32 kintree) so no licensed model is ever needed:

* ``synthetic_smpl_arrays``  - the key -> array dict (scipy-sparse ``J_regressor``, as in SMPL pickles);
* ``synthetic_smpl_file``    - the same arrays as an ``.npz`` (Path);
* ``synthetic_smpl_pkl``     - the same arrays as a plain ``.pkl`` (Path);
* ``synthetic_body_model``   - a ``pedx_graph.body.BodyModel`` loaded from ``synthetic_smpl_file``.

All are session-scoped and read-only: copy an array before changing it.
"""
from __future__ import annotations

import pickle

import pytest

SYNTHETIC_NUM_VERTICES = 300
SYNTHETIC_SEED = 0


@pytest.fixture(scope="session")
def synthetic_smpl_arrays() -> dict:
    from synthetic_model import synthetic_model_arrays

    return synthetic_model_arrays(num_vertices=SYNTHETIC_NUM_VERTICES, seed=SYNTHETIC_SEED)


@pytest.fixture(scope="session")
def synthetic_smpl_file(tmp_path_factory, synthetic_smpl_arrays):
    from pedx_graph.body.io import save_model_npz

    return save_model_npz(tmp_path_factory.mktemp("body") / "synthetic_smpl.npz", synthetic_smpl_arrays)


@pytest.fixture(scope="session")
def synthetic_smpl_pkl(tmp_path_factory, synthetic_smpl_arrays):
    path = tmp_path_factory.mktemp("body_pkl") / "synthetic_smpl.pkl"
    with open(path, "wb") as fh:
        pickle.dump(dict(synthetic_smpl_arrays), fh, protocol=2)
    return path


@pytest.fixture(scope="session")
def synthetic_body_model(synthetic_smpl_file):
    from pedx_graph.body import BodyModel

    return BodyModel.load(synthetic_smpl_file)
