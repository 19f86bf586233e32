"""Error types that carry the offending file, so the CLI can print one clear line."""
from __future__ import annotations


class InputError(ValueError):
    """Bad input data: names the file (when there is one) and the problem.

    Subclasses ``ValueError`` so callers that catch ``ValueError`` keep working.
    """

    def __init__(self, problem: str, path: object | None = None):
        self.path = None if path is None else str(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}" if self.path else problem)


class ConfigError(InputError):
    """A parameter outside its range or of the wrong type (pipeline files, options)."""


class DependencyError(RuntimeError):
    """An optional dependency that a chosen feature needs is not installed (the message says how to get it)."""
