"""Error types that carry the offending file, so the CLI can print one clear line."""
from __future__ import annotations

from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent


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


def _package_place(filename: str) -> str | None:
    """``pcdet/<module path>`` where ``filename`` lies inside this package (found by the package's own location,
    so a checkout in a folder that happens to be called ``pcdet`` is not mistaken for it), else ``None``."""
    try:
        return "pcdet/" + Path(filename).resolve().relative_to(_PACKAGE).as_posix()
    except (ValueError, OSError):
        return None


def internal_error(e: BaseException) -> str:
    """One line for an unexpected exception met while processing one frame of a batch (a bug, not bad input):
    its type, where in pcdet it was raised and its message, so the frame can be reported and the batch go on.
    ``internal error (please report it): IndexError at pcdet/refine.py:169 in _pairs_many: ...``; where no frame
    of the traceback lies in pcdet, the last frame is named by its own path."""
    import traceback

    frames = traceback.extract_tb(e.__traceback__)
    ours = [(place, f) for f in frames if (place := _package_place(f.filename)) is not None]
    where = ""
    if ours:
        place, f = ours[-1]
        where = f" at {place}:{f.lineno} in {f.name}"
    elif frames:
        where = f" at {frames[-1].filename}:{frames[-1].lineno} in {frames[-1].name}"
    return f"internal error (please report it): {type(e).__name__}{where}: {e}"
