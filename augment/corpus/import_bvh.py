"""Turn a folder of BVH files into a corpus: retarget to t2m, resample to 20 fps, extract features.

Labels come from options, or from Bandai-style file names and JSON. Every file that cannot be used
becomes a reject with its reason; the others are written.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Literal

from pydantic import BaseModel

from augment.clip import MotionClip
from augment.corpus import REJECTS_FILE
from augment.corpus.humanml3d import write_humanml3d
from augment.corpus.parquet import ParquetCorpusWriter
from augment.corpus.rejects import Reject, write_rejects
from schemas.errors import MotionDataError
from augment.features import extract_features
from augment.retarget import load_bvh_as_t2m_joints, labels_from_bandai
from schemas.captions import Caption

MIN_FRAMES = 10
_UNSAFE = re.compile(r"[^A-Za-z0-9_.-]+")


class ImportSummary(BaseModel):
    clips: int
    frames: int
    rejects: list[Reject]
    out: str


def label_caption(content: str, style: str | None) -> Caption:
    """A plain caption with valid lemma/POS tokens for a (content, style) label pair."""
    action = content.replace("-", " ").replace("_", " ")
    words = [("a", "DET"), ("person", "NOUN"), ("perform", "VERB")]
    words += [(w, "NOUN") for w in action.split()]
    if style and style != "normal" and style != "neutral":
        words += [("in", "ADP"), ("a", "DET")] + [(w, "ADJ") for w in style.replace("-", " ").split()] + [("way", "NOUN")]
    text = " ".join("performs" if (w, p) == ("perform", "VERB") else w for w, p in words)
    return Caption(text=text, tokens=[f"{w}/{p}" for w, p in words])


def clip_id_from_path(path: Path) -> str:
    """A filename-safe id from a file stem; data never becomes a path unchecked."""
    stem = _UNSAFE.sub("_", path.stem).strip("._-")
    return stem[:200] or "clip"


def iter_bvh_clips(
    src: Path,
    rejects: list[Reject],
    content: str | None = None,
    style: str | None = None,
    joint_map: str | os.PathLike[str] | None = None,
    fps: float = 20.0,
) -> Iterator[MotionClip]:
    """Clips of every ``*.bvh`` under ``src`` (or ``src`` itself), in sorted order."""
    files = [src] if src.is_file() else sorted(src.rglob("*.bvh"))
    if not files:
        raise MotionDataError(str(src), "no .bvh files found")
    seen: set[str] = set()
    for path in files:
        clip_id = clip_id_from_path(path)
        try:
            if clip_id in seen:
                raise MotionDataError(str(path), f"duplicate clip id {clip_id!r}")
            joints, _ = load_bvh_as_t2m_joints(path, joint_map=joint_map, fps=fps)
            if len(joints) < MIN_FRAMES + 1:
                raise MotionDataError(str(path), f"{len(joints)} frames at {fps:g} fps; need at least {MIN_FRAMES + 1}")
            c, s = (content, style) if content else labels_from_bandai(path)
            s = style or s
            motion = extract_features(joints, source=str(path))
        except MotionDataError as err:
            rejects.append(Reject.from_error(clip_id, err))
            continue
        seen.add(clip_id)
        yield MotionClip(clip_id, motion, [label_caption(c, s)], fps=fps, content=c, style=s, source=str(path))


def import_bvh(
    src: str | os.PathLike[str],
    out: str | os.PathLike[str],
    fmt: Literal["humanml3d", "parquet"] = "humanml3d",
    content: str | None = None,
    style: str | None = None,
    joint_map: str | os.PathLike[str] | None = None,
) -> ImportSummary:
    """Write every usable BVH under ``src`` to ``out``; rejects go to ``out/rejects.jsonl``."""
    src, out = Path(src), Path(out)
    if not src.exists():
        raise MotionDataError(str(src), "does not exist")
    rejects: list[Reject] = []
    frames = 0

    def counted() -> Iterator[MotionClip]:
        nonlocal frames
        for clip in iter_bvh_clips(src, rejects, content, style, joint_map):
            frames += clip.n_frames
            yield clip

    if fmt == "humanml3d":
        ids = write_humanml3d(counted(), out)
    else:
        out.mkdir(parents=True, exist_ok=True)
        ids = []
        with ParquetCorpusWriter(out / "corpus.parquet") as writer:
            for clip in counted():
                writer.write(clip)
                ids.append(clip.id)
    write_rejects(rejects, out / REJECTS_FILE)
    return ImportSummary(clips=len(ids), frames=frames, rejects=rejects, out=str(out))
