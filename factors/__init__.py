"""Custom GTSAM factors of pedx-graph: one energy term of the PedX method per module."""
