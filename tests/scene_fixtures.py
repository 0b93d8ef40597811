"""Small simulated scenes and file-tree digests shared by the end-to-end tests (default rig unless given)."""
from __future__ import annotations

import hashlib
from pathlib import Path

from pedx_graph.sim.config import SimConfig
from pedx_graph.sim.simulate import simulate


def small_scene(out: Path, pedestrians: int, frames: int, seed: int, config: SimConfig | None = None,
                **simulate_kwargs) -> Path:
    """Simulate ``pedestrians`` x ``frames`` (on ``config``, default: the default rig) into ``out``; returns it."""
    cfg = config or SimConfig()
    cfg.scene.n_pedestrians = pedestrians
    cfg.scene.n_frames = frames
    simulate(out, cfg, seed=seed, **simulate_kwargs)
    return out


def tree_digest(root: Path) -> dict[str, str]:
    """Relative path -> SHA-256 of every file under ``root`` (byte-identity checks)."""
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}
