"""facegeo: one photo of a face in, a measured 3D morphable-model fit out."""

__version__ = "0.1.0"
