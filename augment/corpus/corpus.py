"""One door to a corpus on disk, in either format: stream it, look clips up by id, know their splits.

Every caller (the run's plan and tasks, evaluation, export, previews) opens a corpus through ``Corpus`` so the
format branches, the reading of split files and the parsing of caption-span ids live here only.

A clip's *source file* is what a task reads to get it back cheaply: a HumanML3D source id (the ``.npy`` a
caption-span cut comes from) or a Parquet file name.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Literal

import pyarrow as pa
import pyarrow.parquet as pq

from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.corpus.humanml3d import MOTION_DIR, HumanML3DReader, span_parent
from motionaug.augment.corpus.parquet import parquet_files, table_to_clips
from motionaug.augment.corpus.rejects import Reject
from motionaug.schemas.errors import MotionDataError

CorpusFormat = Literal["humanml3d", "parquet"]
SPLITS = ("train", "val", "test")


def detect_format(path: str | os.PathLike[str]) -> CorpusFormat:
    """A folder with new_joint_vecs/ is HumanML3D; a .parquet file or a folder of them is Parquet."""
    path = Path(path)
    if path.is_dir() and (path / MOTION_DIR).is_dir():
        return "humanml3d"
    if (path.is_file() and path.suffix == ".parquet") or (path.is_dir() and any(path.glob("*.parquet"))):
        return "parquet"
    raise MotionDataError(
        str(path), f"not a corpus: expected a folder with {MOTION_DIR}/, a .parquet file or a folder of them"
    )


def split_of_ids(root: Path) -> dict[str, str]:
    """Id -> train/val/test from a HumanML3D folder's split files (first listing wins)."""
    split_of: dict[str, str] = {}
    for name in SPLITS:
        path = Path(root) / f"{name}.txt"
        if path.is_file():
            for line in path.read_text(encoding="utf-8").splitlines():
                if line.strip():
                    split_of.setdefault(line.strip(), name)
    return split_of


class Corpus:
    """A HumanML3D folder or a Parquet corpus, opened by path.

    Iterating streams clips (one source file in memory at a time); ``rejects`` lists what the last pass
    skipped. ``options`` go to the HumanML3D reader (``feature_dim``, frame limits, ``split_spans``...).
    ``split`` names a HumanML3D split file; None reads ``all.txt`` when present, else every ``.npy``.
    """

    def __init__(self, path: str | os.PathLike[str], split: str | None = None, **options: object) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise MotionDataError(str(self.path), "corpus not found")
        self.format: CorpusFormat = detect_format(self.path)
        self.split = split
        self.options = options
        self.rejects: list[Reject] = []
        if self.format == "parquet":
            parquet_files(self.path)  # fail now, not at the first clip, when there is no corpus

    def __iter__(self) -> Iterator[MotionClip]:
        for clip, _ in self.with_files():
            yield clip

    def with_files(self) -> Iterator[tuple[MotionClip, str]]:
        """(clip, its source file) for every readable clip, streamed."""
        self.rejects = []
        if self.format == "parquet":
            for file in parquet_files(self.path):
                for batch in pq.ParquetFile(file).iter_batches(batch_size=64):
                    for clip in table_to_clips(pa.Table.from_batches([batch]), source=str(file)):
                        yield clip, file.name
            return
        reader = self._reader(split=self._split())
        for clip in reader:
            yield clip, clip.meta.get("parent", clip.id)
        self.rejects = list(reader.rejects)

    def by_style(self) -> dict[str, list[MotionClip]]:
        """The clips (of this view's split) grouped by their style label, in corpus order; unlabelled ones left out."""
        out: dict[str, list[MotionClip]] = {}
        for clip in self:
            if clip.style:
                out.setdefault(clip.style, []).append(clip)
        return out

    def load(self, ids: Sequence[str], files: Iterable[str] | None = None) -> tuple[list[MotionClip], list[Reject]]:
        """The clips ``ids`` in that order, read from their source ``files`` (found from the ids when None).

        An id that cannot be read becomes a Reject with the reader's reason, or "not found".
        """
        wanted = set(ids)
        files = sorted(set(files)) if files is not None else self._files_of(ids)
        found: dict[str, MotionClip] = {}
        rejects: list[Reject] = []
        if self.format == "parquet":
            folder = self.path if self.path.is_dir() else self.path.parent
            for name in files:
                table = pq.read_table(folder / name, filters=[("id", "in", sorted(wanted))])
                found.update((c.id, c) for c in table_to_clips(table, source=str(folder / name)))
        else:
            reader = self._reader(split=None, files=files)
            found.update((c.id, c) for c in reader if c.id in wanted)
            rejects.extend(r for r in reader.rejects if r.id in wanted)
        rejected = {r.id for r in rejects}
        for clip_id in ids:
            if clip_id not in found and clip_id not in rejected:
                rejects.append(Reject(id=clip_id, source=str(self.path), reason="clip not found in the corpus"))
        return [found[i] for i in ids if i in found], rejects

    def get(self, clip_id: str) -> MotionClip | None:
        """One clip by id (a caption-span id ``<parent>_<start>_<end>`` too), or None."""
        clips, _ = self.load([clip_id])
        return clips[0] if clips else None

    def file_splits(self) -> dict[str, str]:
        """Source file id -> train/val/test from a HumanML3D folder's split files (empty for Parquet)."""
        return split_of_ids(self.path) if self.format == "humanml3d" else {}

    @staticmethod
    def split_of(clip: MotionClip, file_splits: dict[str, str]) -> str | None:
        """A clip's split: train/val/test as its own (Parquet rows, split readers) or its source file's; a clip read
        through another split file (a run's ``corpus.split: subset``) keeps that name only when no standard
        split lists it, so exports of such runs still sort rows into train/val/test."""
        own = clip.meta.get("split")
        if own in SPLITS:
            return own
        return file_splits.get(clip.meta.get("parent", clip.id)) or own

    def _split(self) -> str | None:
        if self.split is not None:
            return self.split
        return "all" if (self.path / "all.txt").is_file() else None

    def _reader(self, split: str | None, files: Iterable[str] | None = None) -> HumanML3DReader:
        return HumanML3DReader(self.path, split=split, files=files, **self.options)  # type: ignore[arg-type]

    def _files_of(self, ids: Sequence[str]) -> list[str]:
        if self.format == "parquet":
            return [f.name for f in parquet_files(self.path)]
        candidates = {c for i in ids for c in (i, span_parent(i)) if c is not None}
        return sorted(f for f in candidates if (self.path / MOTION_DIR / f"{f}.npy").is_file())
