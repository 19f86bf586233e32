"""Output paths checked before any work starts, and a lock that keeps two runs out of one folder.

``check_file`` / ``check_folder`` refuse a path of the wrong kind (a folder where a file is to be written, or
the reverse) and prove that the place can be written by creating (and removing) a file there, creating
missing parent folders on the way. Each raises ``InputError`` naming the path, so the command line prints one
line and stops before a frame is processed.
"""
from __future__ import annotations

import errno
import fcntl
import os
import tempfile
from pathlib import Path

from ..errors import InputError


def _probe(folder: Path, path: Path) -> None:
    """Create the folder (and its parents) and a temporary file in it, or say why not, naming ``path``."""
    for parent in [folder, *folder.parents]:
        if parent.exists():
            if not parent.is_dir():
                raise InputError(f"cannot be written: {parent} is a file, not a folder", path)
            break
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".pcdet-probe.", dir=folder)
        os.close(fd)
        os.unlink(tmp)
    except OSError as e:
        raise InputError(f"cannot be written ({e.strerror or e})", path) from None


def check_file(path, what: str = "output") -> Path:
    """An output file's path, checked: not an existing folder, its folder writable (created if missing)."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"is a folder, but the {what} must be a file: give a file name", path)
    _probe(path.parent if str(path.parent) else Path("."), path)
    return path


def check_folder(path, what: str = "output") -> Path:
    """An output folder, checked: not an existing file, and writable (created if missing)."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise InputError(f"is a file, but the {what} must be a folder: give a folder name", path)
    _probe(path, path)
    return path


class FolderLock:
    """An exclusive lock on ``folder/.pcdet.lock`` for as long as it is held (``with FolderLock(out): ...``).
    A second holder is refused with ``InputError`` naming the folder and the process that holds it. The lock
    dies with its process (``flock``), so a killed run leaves nothing to clean up."""

    def __init__(self, folder):
        self.folder = Path(folder)
        self._fd: int | None = None

    def acquire(self) -> "FolderLock":
        """Take the lock (``InputError`` when another process holds it); returns self."""
        self.folder.mkdir(parents=True, exist_ok=True)
        path = self.folder / ".pcdet.lock"
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as e:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
            os.close(fd)
            if e.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise InputError(f"another pcdet run (process {holder}) is writing into this folder; wait for "
                                 "it to finish or choose another output folder", self.folder) from None
            raise
        os.ftruncate(fd, 0)
        os.pwrite(fd, str(os.getpid()).encode(), 0)
        self._fd = fd
        return self

    def release(self) -> None:
        """Give the lock up (nothing happens when it is not held)."""
        if self._fd is not None:
            fcntl.flock(self._fd, fcntl.LOCK_UN)
            os.close(self._fd)
            self._fd = None

    def __enter__(self) -> "FolderLock":
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()
