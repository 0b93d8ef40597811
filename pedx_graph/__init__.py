"""pedx-graph: metric 3D pedestrian body models from stereo 2D labels and LiDAR, as GTSAM factor graphs."""
__version__ = "0.1.0"
