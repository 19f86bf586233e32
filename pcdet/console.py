"""What the command line shows a person: the two consoles, the one-line ``error:`` message, and the guard
that turns the library's own error types into it (anything else is a bug and keeps its traceback)."""
from __future__ import annotations

import functools
import sys

import typer
from rich.console import Console
from rich.markup import escape

from .errors import DependencyError, InputError

console = Console(stderr=True)
out_console = Console(width=None if sys.stdout.isatty() else 200)  # wide tables stay whole when piped

EXPECTED = (InputError, FileNotFoundError, DependencyError)


def fail(msg: str, code: int = 1):
    """Print ``error: msg`` on stderr and exit with ``code``."""
    console.print(f"[bold red]error:[/] {escape(msg)}", highlight=False, soft_wrap=True)
    raise typer.Exit(code)


def guard(fn):
    """Turn the library's expected errors (bad input, missing files, missing optional dependencies) into one
    clear line and a non-zero exit."""

    @functools.wraps(fn)
    def wrapper(*a, **k):
        try:
            return fn(*a, **k)
        except EXPECTED as e:
            fail(str(e))
    return wrapper
