"""Checksums of the files and folders a run publishes (markers record them; reads verify them)."""

from __future__ import annotations

import hashlib
from pathlib import Path


def sha256_file(path: Path, chunk: int = 1 << 20) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        while block := handle.read(chunk):
            digest.update(block)
    return digest.hexdigest()


TIMINGS_FILE = "timings.json"
"""A file of wall-clock facts about how an artefact was made: not part of what it is, so outside its checksum
(the same command and seed give the same checksum on a busy machine and an idle one)."""


def sha256_tree(folder: Path, skip: frozenset[str] = frozenset()) -> tuple[str, int]:
    """(checksum over relative paths and contents of every file but ``TIMINGS_FILE``, file count), in any walk order.

    ``skip``: names of top-level files or folders that record how something was made, not what it is.
    """
    digest = hashlib.sha256()
    root = Path(folder)
    files = sorted(
        p
        for p in root.rglob("*")
        if p.is_file() and p.name != TIMINGS_FILE and p.relative_to(root).parts[0] not in skip
    )
    for path in files:
        digest.update(path.relative_to(folder).as_posix().encode() + b"\0" + sha256_file(path).encode())
    return digest.hexdigest(), len(files)
