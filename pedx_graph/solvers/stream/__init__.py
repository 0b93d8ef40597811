"""The streaming estimator's public names (causal per-frame estimates, smoothed tracks, datasets).

Modules, top-down: :mod:`.dataset` (a dataset streamed track by track) -> :mod:`.estimator`
(:class:`StreamingEstimator`) -> :mod:`.finalise` (an ended track), :mod:`.systems` (a sample's batched
Gauss-Newton systems), :mod:`.step` (one observation's update), :mod:`.causal_init` / :mod:`.prediction`
(a new frame's initial values), :mod:`.latency` (update-time statistics), :mod:`.state` (per-track state,
per-frame estimate), :mod:`.config` (:class:`StreamConfig`).
"""
from pedx_graph.solvers.stream.config import StreamConfig
from pedx_graph.solvers.stream.dataset import causal_label, stream_dataset, stream_task, stream_track, stream_warm_up
from pedx_graph.solvers.stream.estimator import StreamingEstimator
from pedx_graph.solvers.stream.latency import stream_timings
from pedx_graph.solvers.stream.state import FrameEstimate

__all__ = ["FrameEstimate", "StreamConfig", "StreamingEstimator", "causal_label", "stream_dataset", "stream_task",
           "stream_timings", "stream_track", "stream_warm_up"]
