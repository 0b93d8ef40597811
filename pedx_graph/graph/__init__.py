"""pedx_graph.graph"""
