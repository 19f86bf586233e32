"""Reading text files with errors that name the file."""
from __future__ import annotations

from pathlib import Path

from ..errors import InputError


def read_text(path, what: str = "file") -> str:
    """The UTF-8 text of ``path``: ``FileNotFoundError`` when it is missing, ``InputError`` naming the file when
    it is not text (bytes that are not UTF-8). ``what`` names the kind of file in the messages."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: {what} not found")
    try:
        return path.read_text(encoding="utf-8")
    except UnicodeDecodeError as e:
        raise InputError(f"{what} is not UTF-8 text ({e.reason} at byte {e.start})", path) from None
