"""pedx_graph.motion"""
