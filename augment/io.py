"""Atomic file writes: a reader sees the old file or the new one, never half of either.

Each write goes to a uniquely named temporary file in the target's directory (so the final
``os.replace`` is a same-filesystem rename) and is renamed into place only once complete. With ``fsync`` the
file is flushed before the rename and its directory after it, so what was published survives power loss (a
rename alone can be lost with the directory block that records it).
"""

from __future__ import annotations

import errno
import os
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, TypeVar

import numpy as np
from pydantic import BaseModel

from motionaug.schemas.errors import MotionDataError


def temp_path_for(path: str | os.PathLike[str]) -> Path:
    """A fresh hidden sibling of ``path``; ``*.tmp`` so a crash leaves nothing git or readers pick up."""
    target = Path(path)
    return target.with_name(f".{target.name}.{os.getpid()}.{uuid.uuid4().hex[:12]}.tmp")


@contextmanager
def atomic_path(path: str | os.PathLike[str], fsync: bool = False) -> Iterator[Path]:
    """Yield a temporary path to write; on success it replaces ``path``, on error it is removed.

    For writers that want a file name rather than a handle (pyarrow, np.save to a path).
    ``fsync`` also survives power loss, at a cost per file (two fsyncs: the file, then its directory).
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_path_for(target)
    try:
        yield tmp
        if fsync:
            _fsync_file(tmp)
        os.replace(tmp, target)
        if fsync:
            fsync_dir(target.parent)
    finally:
        tmp.unlink(missing_ok=True)


@contextmanager
def atomic_open(path: str | os.PathLike[str], mode: str = "wb", fsync: bool = False) -> Iterator[IO]:
    """``open`` for writing, atomically. Text modes write UTF-8 with ``\\n`` line ends on every OS."""
    if not mode.startswith("w"):
        raise ValueError(f"atomic_open writes only; got mode {mode!r}")
    text_args = {} if "b" in mode else {"encoding": "utf-8", "newline": "\n"}
    with atomic_path(path, fsync=fsync) as tmp:
        with open(tmp, mode.replace("w", "x"), **text_args) as handle:
            yield handle


def atomic_write_text(path: str | os.PathLike[str], text: str, fsync: bool = False) -> None:
    with atomic_open(path, "w", fsync=fsync) as handle:
        handle.write(text)


def atomic_save_npy(path: str | os.PathLike[str], array: np.ndarray, fsync: bool = False) -> None:
    """``np.save`` without pickles; the same array always gives the same bytes."""
    with atomic_open(path, "wb", fsync=fsync) as handle:
        np.save(handle, array, allow_pickle=False)


def _fsync_file(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def fsync_dir(path: str | os.PathLike[str]) -> None:
    """Flush a directory's entries (a rename or a new file in it) to disk; a no-op where directories cannot
    be opened (Windows) or synced (some FUSE and network file systems answer EINVAL)."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except (PermissionError, IsADirectoryError):
        return
    try:
        os.fsync(fd)
    except OSError as err:
        if err.errno not in (errno.EINVAL, errno.ENOTSUP, errno.EBADF):
            raise
    finally:
        os.close(fd)


def fsync_tree(folder: str | os.PathLike[str]) -> None:
    """Flush every file and folder under ``folder`` (before the folder is renamed into place as one artefact)."""
    root = Path(folder)
    for path in sorted(root.rglob("*"), key=lambda p: -len(p.parts)):
        if path.is_file() and not path.is_symlink():
            _fsync_file(path)
        elif path.is_dir():
            fsync_dir(path)
    fsync_dir(root)


M = TypeVar("M", bound=BaseModel)


def read_json_model(path: str | os.PathLike[str], model: type[M], what: str) -> M:
    """A pydantic model from a JSON file, or a one-line error naming the file and what it should be."""
    path = Path(path)
    if not path.is_file():
        raise MotionDataError(str(path.parent), f"not {what}: no {path.name}")
    try:
        return model.model_validate_json(path.read_text(encoding="utf-8"))
    except ValueError as err:
        raise MotionDataError(str(path), f"unreadable {what} ({str(err).splitlines()[0]})") from None
