"""pedx_graph.solvers"""
