"""pedx_graph.data"""
