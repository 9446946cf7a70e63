"""The folder an import writes: built in a staging sibling and swapped in at the end, so a failed import leaves the
target exactly as it was (never an emptied ``all.txt``, orphan clips or a stale ``labels.jsonl``).

Modes: ``new`` (the target must be absent or empty), ``append`` (the target's clips stay; clips whose id it
already holds are skipped, never overwritten), ``force`` (a target that holds a corpus is replaced).
"""

from __future__ import annotations

import os
import shutil
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import pyarrow.parquet as pq

from motionaug.augment.corpus.corpus import detect_format
from motionaug.augment.corpus.humanml3d import MOTION_DIR
from motionaug.augment.corpus.parquet import parquet_files
from motionaug.augment.io import atomic_write_text
from motionaug.schemas.errors import MotionDataError

ImportMode = Literal["new", "append", "force"]


@dataclass
class ImportTarget:
    """``out`` and its staging sibling ``stage``; ``existing``: clip ids the target holds (append only)."""

    out: Path
    fmt: str
    mode: ImportMode
    stage: Path
    existing: set[str] = field(default_factory=set)

    @property
    def appending(self) -> bool:
        return bool(self.existing)

    @classmethod
    def open(cls, out: Path, fmt: str, mode: ImportMode) -> ImportTarget:
        """Check ``out`` for ``mode`` and make the staging folder (for append, a hard-linked copy of ``out``)."""
        if mode not in ("new", "append", "force"):
            raise MotionDataError("mode", f"unknown import mode {mode!r}; use new, append or force")
        has_corpus = _check(out, fmt, mode)
        out.parent.mkdir(parents=True, exist_ok=True)
        stage = out.with_name(f".{out.name}.{uuid.uuid4().hex[:12]}.tmp")
        if mode == "append" and has_corpus:
            shutil.copytree(out, stage, copy_function=_link_or_copy)
            return cls(out, fmt, mode, stage, _corpus_ids(out, fmt))
        stage.mkdir()
        return cls(out, fmt, mode, stage)

    def old_lines(self, name: str) -> list[str]:
        """Non-blank lines of ``out/name`` when appending (what the merged file starts with)."""
        path = self.out / name
        if not self.appending or not path.is_file():
            return []
        return [line for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]

    def take_over(self, *names: str) -> None:
        """Drop the staged copies of files the import rewrites (the originals in ``out`` are untouched)."""
        for name in names:
            (self.stage / name).unlink(missing_ok=True)

    def merge_lines(self, name: str) -> list[str]:
        """``out/name``'s lines then the staged ``name``'s, written to the staged file; returns them."""
        staged = self.stage / name
        new = [ln for ln in staged.read_text(encoding="utf-8").splitlines() if ln.strip()] if staged.is_file() else []
        lines = self.old_lines(name) + new
        if lines or staged.is_file():
            atomic_write_text(staged, "".join(f"{line}\n" for line in lines))
        return lines

    def next_parquet_name(self) -> str:
        """A Parquet file name not yet in the staged folder (appends add a file, never rewrite one)."""
        n = len(list(self.stage.glob("*.parquet")))
        return "corpus.parquet" if n == 0 else f"corpus-{n:04d}.parquet"

    def publish(self) -> None:
        """Swap the staged folder in; the earlier target moves aside first and is deleted after."""
        old = self.out.with_name(f".{self.out.name}.{uuid.uuid4().hex[:12]}.old.tmp")
        if self.out.exists():
            self.out.rename(old)
        self.stage.rename(self.out)
        shutil.rmtree(old, ignore_errors=True)

    def discard(self) -> None:
        shutil.rmtree(self.stage, ignore_errors=True)


def _check(out: Path, fmt: str, mode: ImportMode) -> bool:
    """Whether ``out`` holds a corpus; refuses what ``mode`` may not touch, naming the option that would."""
    if out.name in ("", ".", ".."):
        raise MotionDataError(str(out), "--out needs a named folder (it is built beside it and swapped in)")
    if out.exists() and not out.is_dir():
        raise MotionDataError(str(out), "is a file; --out needs a folder")
    if not out.exists() or not any(out.iterdir()):
        return False
    if mode == "new":
        raise MotionDataError(
            str(out), "is not empty; pass --append to add to the corpus in it or --force to replace it"
        )
    try:
        found = detect_format(out)
    except MotionDataError:
        raise MotionDataError(
            str(out), f"is not empty and holds no corpus, so --{mode} will not touch it; choose another --out"
        ) from None
    if mode == "append" and found != fmt:
        raise MotionDataError(str(out), f"holds a {found} corpus; --append needs --format {found}")
    return True


def _corpus_ids(out: Path, fmt: str) -> set[str]:
    if fmt == "humanml3d":
        return {path.stem for path in (out / MOTION_DIR).glob("*.npy")}
    return {str(i) for file in parquet_files(out) for i in pq.read_table(file, columns=["id"]).column("id").to_pylist()}


def _link_or_copy(src: str, dst: str) -> None:
    """A hard link (cheap; the import replaces files by rename, never writes into one), else a copy."""
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)
