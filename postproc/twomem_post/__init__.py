"""Post-processing of twomem result files (HDF5, layout in docs/output.md)."""

__version__ = "0.2.0"
