"""Running one task per track, in this process, on a local process pool or on a Dask cluster, into a
results folder that survives faults (manifest, completion markers, resume, an always-written summary).

* :mod:`~pedx_graph.execution.tasks`: the per-track task function every executor runs;
* :mod:`~pedx_graph.execution.executors`: inline, local process pool, Dask (``--cluster``);
* :mod:`~pedx_graph.execution.outdir`: the results folder (refusals, manifest, markers, summary);
* :mod:`~pedx_graph.execution.runner`: the loop feeding an executor and writing each track as it completes;
* :mod:`~pedx_graph.execution.options`: the command-line flags shared by ``fit``, ``stream`` and ``baseline``.
"""
