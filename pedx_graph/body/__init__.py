"""pedx_graph.body: SMPL-format body models in numpy: loading, LBS, PedX keypoints, analytic Jacobians.

Public API::

    from pedx_graph.body import BodyModel, PEDX_KEYPOINTS
    m = BodyModel.load()                        # open default model (pedx_graph/body/data/pedx_open_neutral.npz)
    out = m.forward(pose, betas, trans)         # out.vertices, out.joints, out.keypoints
    jac = m.point_jacobians(pose, betas, trans) # points, d_root, d_body_pose, d_trans, d_betas
"""
from pedx_graph.body.io import ModelData, ModelFormatError, load_model_data, validate_model_arrays
from pedx_graph.body.jacobians import PointJacobians
from pedx_graph.body.keypoint_defs import KeypointMap
from pedx_graph.body.model import BodyModel, BodyOutput, default_model_path
from pedx_graph.keypoints import PEDX_KEYPOINTS, SMPL_JOINTS, SMPL_PARENTS

__all__ = [
    "BodyModel", "BodyOutput", "PointJacobians", "KeypointMap", "ModelData", "ModelFormatError",
    "load_model_data", "validate_model_arrays", "default_model_path",
    "PEDX_KEYPOINTS", "SMPL_JOINTS", "SMPL_PARENTS",
]
