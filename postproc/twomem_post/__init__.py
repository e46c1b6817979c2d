"""Post-processing of twomem result files (HDF5, layout in INTERFACE.md / docs/output.md)."""

__version__ = "0.1.0"
