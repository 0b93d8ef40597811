"""Streaming a dataset: each track's frames in timestamp order through its own estimator, one task per
track, causal and smoothed labels written as each track completes."""
from __future__ import annotations

import copy
import dataclasses

import numpy as np

from pedx_graph.data.noise_estimate import resolve_noise
from pedx_graph.data.types import SmplLabel, Track
from pedx_graph.detections.fit_layout import fit_layout
from pedx_graph.execution.executors import ExecutorSpec
from pedx_graph.execution.runner import RunSpec, run_dataset
from pedx_graph.execution.tasks import label_files, result_output
from pedx_graph.graph.config import FitConfig
from pedx_graph.keypoints import PEDX_KEYPOINTS
from pedx_graph.solvers.context import estimator_context
from pedx_graph.solvers.stream.config import StreamConfig
from pedx_graph.solvers.stream.estimator import StreamingEstimator
from pedx_graph.solvers.stream.latency import stream_timings
from pedx_graph.solvers.stream.state import FrameEstimate


def causal_label(sequence: str, est: FrameEstimate) -> SmplLabel:
    """The causal estimate of one frame as a result label (its update time goes to the summary's timings,
    never into the file)."""
    extra = {"keypoints_3d": est.world_keypoints, "keypoint_names": list(PEDX_KEYPOINTS),
             "timestamp": est.timestamp, "solver": "isam2-causal"}
    extra.update(est.extra)
    return SmplLabel(sequence=sequence, frame=int(est.frame), tracking_id=est.tracking_id, betas=est.betas,
                     pose=est.pose, trans=est.trans, extra=extra)


def stream_track(track: Track, ctx, config: FitConfig, stream_config: StreamConfig):
    """Stream one track's frames in timestamp order through its own :class:`StreamingEstimator`.

    Returns ``(smoothed results, causal estimates, failed)``: the smoothed :class:`TrackResult` of each piece
    of the track (one unless it paused longer than ``track_timeout_s``), the causal :class:`FrameEstimate`
    of every frame whose update succeeded, and ``{"frame" or "stage", "error"}`` of each failed update and
    of each piece refused as implausible."""
    report_model = ctx.model                  # results: PedX keypoints of the original model, whatever the labels
    track, ctx, config = fit_layout(track, ctx, config)   # detector sets: their own points, 18 + E rows
    estimator = StreamingEstimator(ctx, config, copy.deepcopy(stream_config), sequence=track.sequence,
                                   ground=track.ground)
    results, causal, failed = [], [], []

    def collect():
        results.extend(estimator.pop_finished())
        failed.extend({"stage": "plausibility", "error": bad["error"]} for bad in estimator.pop_failed())

    for fr in sorted(track.frames, key=lambda f: (float(f.timestamp), f.frame)):
        current = estimator.add_frame(float(fr.timestamp), {track.tracking_id: fr}, track.calibrations)
        if track.tracking_id in current:
            causal.append(current[track.tracking_id])
        else:
            failed.append({"frame": int(fr.frame), "error": "update failed (see the log)"})
        collect()
    results.extend(estimator.finish())
    collect()
    if ctx.model is not report_model:
        for res in results:
            res.world_keypoints = report_model.keypoints(res.pose, np.broadcast_to(res.betas, (len(res.pose),
                                                                                               len(res.betas))),
                                                         res.trans)
        causal = [dataclasses.replace(est, world_keypoints=report_model.keypoints(est.pose, est.betas, est.trans))
                  for est in causal]
    return results, causal, failed


def stream_task(track: Track, params: tuple):
    """The task of one track in :func:`stream_dataset` (run in a worker): ``params = (config, stream_config,
    ctx or None)`` -> :class:`~pedx_graph.execution.tasks.TrackOutput` with the smoothed labels, the causal
    labels (under ``causal/``), the track's records (failed updates in the first one's ``failed_updates``)
    and its per-update latencies (``update_ms``, ``cpu_ms``, ``isam_ms``) as timings."""
    config, stream_config, ctx = params
    results, causal, failed = stream_track(track, ctx or estimator_context(config), config, stream_config)
    if not results:
        reasons = "; ".join(sorted({bad["error"] for bad in failed})) or "no frame"
        raise RuntimeError(f"no smoothed estimate of the track ({reasons})")
    causal_files = label_files([causal_label(track.sequence, e) for e in causal], prefix="causal")
    output = result_output(results, extra_files=causal_files, extra_timings={
        "update_ms": [e.update_seconds * 1e3 for e in causal], "cpu_ms": [e.cpu_seconds * 1e3 for e in causal],
        "isam_ms": [e.isam_seconds * 1e3 for e in causal]}, track=track)
    if failed:
        output.records[0]["failed_updates"] = failed
    return output


def stream_warm_up(params: tuple) -> None:
    """Load the estimator context of ``params = (config, stream_config, ctx or None)`` in this worker."""
    if params[2] is None:
        estimator_context(params[0])


def stream_dataset(dataset, out, config: FitConfig | None = None, stream_config: StreamConfig | None = None,
                   ctx=None, sequences: list[str] | None = None, *, workers: int = 1, cluster: str | None = None,
                   resume: bool = False, overwrite: bool = False, progress: bool = False,
                   keep_records: bool = True, on_track=None) -> dict:
    """Stream every track of ``dataset`` (its frames in timestamp order, one task per track) and write under
    ``out`` as each track completes:

    * ``causal/labels/3d/smpl/...``: the causal estimate of the track after each of its frames;
    * ``labels/3d/smpl/...``: the smoothed estimate of the track once it ends (with covariances);
    * ``summary.json``: per track errors, diagnostics, failed updates; the update latencies (per track and
      over the run) in its ``timings`` section;
    * ``fit_config.yaml`` / ``stream_config.yaml``, ``manifest.json``, ``done/`` (completion markers).

    Each track is its own task (as ``fit``): results do not depend on which tracks share a process or a
    run, a failing track stops nothing else, resume and scale-out are per track.  (:class:`StreamingEstimator`
    itself takes all pedestrians of a sample at once, as a live system would; here each task feeds one.)
    Executor, resume and overwrite as :func:`pedx_graph.solvers.fit.fit_dataset`; a given ``ctx`` (estimator
    context) is used in this process only (``workers=1``).
    """
    config = config or FitConfig()
    stream_config = stream_config or StreamConfig()

    def make_params(tracks):
        # the click and range noise from the data, as the batch fit (pedx_graph.data.noise_estimate)
        resolved = resolve_noise(tracks, config.noise)
        return (dataclasses.replace(config, noise=resolved.noise), stream_config, ctx), {"noise": resolved.record}

    spec = RunSpec(command="stream", method="isam2-stream", method_key="solver", dataset=dataset,
                   task_fn=stream_task, configs={"fit_config": config, "stream_config": stream_config},
                   make_params=make_params, sequences=sequences, reader_config=config.reader_config(),
                   summarise_timings=stream_timings, inline_only=ctx is not None, warm_up=stream_warm_up)
    return run_dataset(spec, out, ExecutorSpec(workers=workers, cluster=cluster), resume=resume,
                       overwrite=overwrite, progress=progress, keep_records=keep_records, on_track=on_track)
