"""The paper's baselines (Sec. V), on the same inputs (:class:`~pedx_graph.data.types.Track`) and output
(:class:`~pedx_graph.solvers.fit.TrackResult`) as the estimator:

==============  =====================================================  ==========================================
name            what                                                   module
==============  =====================================================  ==========================================
triangulation   2D keypoints visible in both images, triangulated      :mod:`pedx_graph.baselines.triangulation`
left_disp       left keypoints back-projected at the disparity depth   :mod:`pedx_graph.baselines.left_disparity`
smplify_disp    per-frame monocular body fit (left image), scaled by   :mod:`pedx_graph.baselines.smplify_disparity`
                the disparity depth of the visible keypoints
==============  =====================================================  ==========================================

The first two fit no body: only their ``world_keypoints`` (``keypoints_3d`` in the written labels) are
meaningful (``extra_track["keypoints_only"]`` is True).  Run one with
:func:`pedx_graph.baselines.run.run_baseline` or a whole dataset with
:func:`pedx_graph.baselines.run.fit_dataset_baseline` (``pedx-graph baseline NAME DATASET --out RESULTS``).
"""
from pedx_graph.baselines.left_disparity import left_disparity_baseline
from pedx_graph.baselines.smplify_disparity import SmplifyDispConfig, smplify_disparity_baseline
from pedx_graph.baselines.triangulation import triangulation_baseline

__all__ = ["triangulation_baseline", "left_disparity_baseline", "smplify_disparity_baseline", "SmplifyDispConfig"]
