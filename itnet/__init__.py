"""itnet: anytime category-level pose estimation of partial point clouds with IT-Net."""

__version__ = "0.1.0"
