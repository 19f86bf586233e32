"""Reading JSON files with errors that name the file."""
from __future__ import annotations

import json
from pathlib import Path

from ..errors import InputError


def read_json(path, expect_object: bool = True):
    """The parsed contents of ``path``: ``FileNotFoundError`` when it is missing, ``InputError`` (naming the
    file) when it is not valid JSON or, with ``expect_object``, not a JSON object."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: file not found")
    try:
        doc = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise InputError(f"not valid JSON ({e})", path) from None
    if expect_object and not isinstance(doc, dict):
        raise InputError("expected a JSON object", path)
    return doc
