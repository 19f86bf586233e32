"""Helpers for the frozen parameter dataclasses of every stage: a field with its one-line documentation, and
range checks that name the class and the field."""
from __future__ import annotations

from dataclasses import field

from .errors import ConfigError


def param(default, doc: str):
    """A dataclass field with a default and its documentation (``config dump`` prints it as a comment).
    ``default`` may be a dataclass type, for a nested section."""
    if isinstance(default, type):
        return field(default_factory=default, metadata={"doc": doc})
    return field(default=default, metadata={"doc": doc})


def check_positive(obj, *names: str) -> None:
    """``ConfigError`` naming the class and field unless every named field is > 0."""
    for n in names:
        v = getattr(obj, n)
        if not (v > 0):
            raise ConfigError(f"{type(obj).__name__}.{n} must be > 0, got {v!r}")


def check_range(obj, name: str, lo: float, hi: float) -> None:
    """``ConfigError`` naming the class and field unless ``lo <= value <= hi``."""
    v = getattr(obj, name)
    if not lo <= v <= hi:
        raise ConfigError(f"{type(obj).__name__}.{name} must be in [{lo}, {hi}], got {v!r}")
