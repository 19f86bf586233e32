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


def internal_error(e: BaseException) -> str:
    """One line for an unexpected exception met while processing one frame of a batch (a bug, not bad input):
    its type, where in pcdet it was raised and its message, so the frame can be reported and the batch go on.
    ``internal error (please report it): IndexError at pcdet/refine.py:169 in _pairs_many: ...``"""
    import traceback

    frames = [(f.filename.replace("\\", "/"), f.lineno, f.name) for f in traceback.extract_tb(e.__traceback__)]
    ours = [f for f in frames if "/pcdet/" in f[0]] or frames
    where = ""
    if ours:
        path, line, name = ours[-1]
        shown = f"pcdet/{path.rsplit('/pcdet/', 1)[-1]}" if "/pcdet/" in path else path
        where = f" at {shown}:{line} in {name}"
    return f"internal error (please report it): {type(e).__name__}{where}: {e}"
