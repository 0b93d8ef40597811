"""pedx_graph.body"""
