"""pedx_graph.priors"""
