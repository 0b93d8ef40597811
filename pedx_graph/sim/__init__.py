"""pedx_graph.sim"""
