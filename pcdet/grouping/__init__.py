"""Correspondence grouping: turn candidate matches into object hypotheses (one per instance)."""
from .hypothesis import Hypothesis
from .ransac import ransac_instances

__all__ = ["Hypothesis", "ransac_instances"]
