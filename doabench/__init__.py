"""doabench: benchmark suite and dataset generator for single-source DOA estimation and tracking."""
__version__ = "0.1.0"
