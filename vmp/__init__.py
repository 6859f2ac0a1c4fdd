"""vmp-slam: 2D laser SLAM with the vector mapping paradigm and laser milestones."""

__version__ = "0.1.0"
