"""The version of ncmeasure (one place; read by the build and by every module that records it)."""

__version__ = "0.1.0"
