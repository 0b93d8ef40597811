"""Solvers of a track's graph, top-down: the commands (``cli``, ``stream_cli``) -> a dataset (``fit``,
``stream``) -> one track (``track_lm``, ``admm``, ``isam_batch``) -> its solves (``staging``, ``flips``,
``isam``) and checks (``plausibility``, ``diagnostics``, ``residuals``, ``body_checks``, ``marginals``) ->
the one LM loop and linear algebra (``lm``, ``batched``, ``frame_system``, ``chain``) -> ``result``,
``context``.  docs/solvers.md has the map."""
