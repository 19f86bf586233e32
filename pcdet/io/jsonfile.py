"""Reading JSON files with errors that name the file."""
from __future__ import annotations

import json
from pathlib import Path

from ..errors import InputError
from .text import read_text


def read_json(path, expect_object: bool = True, what: str = "file"):
    """The parsed contents of ``path``: ``FileNotFoundError`` when it is missing, ``InputError`` (naming the
    file) when it is not valid JSON or, with ``expect_object``, not a JSON object. ``what`` names the kind of
    file in the messages ("camera file", say)."""
    path = Path(path)
    try:
        doc = json.loads(read_text(path, what))
    except json.JSONDecodeError as e:
        raise InputError(f"{what} is not valid JSON ({e})", path) from None
    if expect_object and not isinstance(doc, dict):
        raise InputError(f"{what} must hold a JSON object", path)
    return doc
