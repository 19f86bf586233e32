"""Recording and dataset readers: one module per format, one Protocol, an explicit registry."""
from .bop import BopDataset

__all__ = ["BopDataset"]
