"""Surface reconstruction lives in :mod:`pointviz.reconstruct` (the viewer reconstructs too)."""

from ..reconstruct import Reconstruction, alpha_shape, ball_pivoting, mean_spacing, poisson

__all__ = ["Reconstruction", "alpha_shape", "ball_pivoting", "mean_spacing", "poisson"]
