"""Atomic file writes: a reader sees the old file or the new one, never half of either.

Each write goes to a uniquely named temporary file in the target's directory (so the final
``os.replace`` is a same-filesystem rename) and is renamed into place only once complete.
"""

from __future__ import annotations

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
    ``fsync`` also survives power loss, at a cost per file.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_path_for(target)
    try:
        yield tmp
        if fsync:
            _fsync_file(tmp)
        os.replace(tmp, target)
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
