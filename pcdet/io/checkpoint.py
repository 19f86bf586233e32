"""Checkpoints as versioned plain data: a nested structure of dicts, lists, strings, numbers, None and numpy
arrays, stored as one ``.npz`` (no pickle) whose ``state.json`` entry holds the structure and the format version,
each array (numpy scalars as 0-d arrays, so their dtype survives) under its own key. Nothing in the file names a
Python class, so renaming or moving one leaves every earlier checkpoint readable; a file of another version, or
no checkpoint at all, is refused with one line naming it."""
from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import numpy as np

from ..errors import InputError

VERSION = 1
_ARRAY = "__array__"


def _flatten(obj, arrays: dict):
    if isinstance(obj, (np.ndarray, np.generic)):
        key = f"a{len(arrays)}"
        arrays[key] = np.asarray(obj)
        return {_ARRAY: key}
    if isinstance(obj, dict):
        if not all(isinstance(k, str) for k in obj):
            raise TypeError("checkpoint dicts take string keys")
        return {k: _flatten(v, arrays) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_flatten(v, arrays) for v in obj]
    if obj is None or isinstance(obj, (bool, int, float, str)):
        return obj
    raise TypeError(f"a checkpoint holds plain data, not {type(obj).__name__}")


def _unflatten(obj, arrays):
    if isinstance(obj, dict):
        if set(obj) == {_ARRAY}:
            a = arrays[obj[_ARRAY]]
            return a[()] if a.ndim == 0 else a
        return {k: _unflatten(v, arrays) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_unflatten(v, arrays) for v in obj]
    return obj


def pack(kind: str, state) -> bytes:
    """``state`` (plain data, see the module docstring) of a ``kind`` of checkpoint ("tracking", ...) as bytes."""
    arrays: dict[str, np.ndarray] = {}
    tree = _flatten(state, arrays)
    head = json.dumps({"format": "pcdet checkpoint", "version": VERSION, "kind": kind, "state": tree})
    buf = io.BytesIO()
    np.savez(buf, **{"state.json": np.array(head)}, **arrays)
    return buf.getvalue()


def unpack(data: bytes, kind: str, path) -> object:
    """The plain data ``pack(kind, ...)`` stored; ``InputError`` naming ``path`` when the bytes are no checkpoint
    of this ``kind`` in this version."""
    where = Path(path)
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as z:
            head = json.loads(str(z["state.json"]))
            arrays = {k: z[k] for k in z.files if k != "state.json"}
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, json.JSONDecodeError):
        raise InputError("not a pcdet checkpoint, or a damaged one", where) from None
    if not isinstance(head, dict) or head.get("format") != "pcdet checkpoint" or head.get("kind") != kind:
        raise InputError(f"not a pcdet {kind} checkpoint", where)
    if head.get("version") != VERSION:
        raise InputError(f"a checkpoint of version {head.get('version')!r}; this pcdet reads version {VERSION}",
                         where)
    try:
        return _unflatten(head["state"], arrays)
    except KeyError as e:
        raise InputError(f"damaged checkpoint: array {e} is missing", where) from None
