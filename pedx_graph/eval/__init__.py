"""pedx_graph.eval"""
