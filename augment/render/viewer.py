"""An interactive 3D viewer of a run or a corpus: ``viewer.html`` plus classic-script data chunks beside it.

Hand-written WebGL (``viewer_assets/viewer.js``; no library, no network; key-pose strips on a 2D canvas without
WebGL): one viewport per panel (the content clip and each chosen style) under one orbiting camera. A ``file://``
page can neither ``fetch()`` nor load modules, so the data are plain scripts: ``viewer/index.js`` (ids, captions,
per-clip scores) loads with the page and ``viewer/chunks/cNNNNN.js`` (joints, ``encode_joints``) when a clip is
picked, so a 10,000-clip run opens as fast as a 10-clip one. Every panel plays on one clock in seconds; the default
sort, ``limb_agreement`` (worst first), is a content measure with no classifier. Design notes: docs/internals.md.
"""

from __future__ import annotations

import base64
import html
import json
import shutil
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from motionaug.augment.corpus import Corpus
from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.io import atomic_write_text
from motionaug.augment.metrics import foot_contacts_from_joints
from motionaug.augment.motion.features import features_to_joints
from motionaug.augment.outputs.run_dir import RunDir
from motionaug.augment.outputs.shards import iter_shard_rows, row_motion
from motionaug.augment.outputs.verify import verified_shards
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.skeleton import T2M, Skeleton

VIEWER_HTML = "viewer.html"
DATA_DIR = "viewer"
CLIPS_PER_CHUNK = 8
ASSETS = ("viewer.js", "viewer.css")
LIMB_JOINTS = (7, 8, 20, 21)  # t2m: left/right ankle, left/right wrist
# per-clip scores of ``scores.parquet`` shown as columns (name -> (label, higher is better))
EVALUATION_SCORES = {
    "content_score": ("content score", True),
    "style_prob": ("p(style)", True),
    "foot_skating": ("foot skating", False),
    "contact_agreement": ("contact agreement", True),
    "mpjpe": ("MPJPE (m)", False),
}
LIMB_AGREEMENT = "limb_agreement"


@dataclass
class ViewerSummary:
    """What ``write_viewer_*`` wrote: the page, how many clips and chunks, and their bytes on disk."""

    page: Path
    clips: int
    chunks: int
    bytes: int


def encode_joints(joints: np.ndarray) -> dict[str, str | int]:
    """(T, J, 3) metres -> base64 float32 root track and int16 millimetre offsets from the root."""
    joints = np.asarray(joints, dtype=np.float64)
    root = joints[:, 0, :].astype("<f4")
    rel_mm = np.round((joints - root[:, None, :].astype(np.float64)) * 1000.0)
    if np.abs(rel_mm).max(initial=0) > 32767:
        raise MotionDataError("joints", "a joint is more than 32 m from the root")
    return {
        "n": int(joints.shape[0]),
        "root": base64.b64encode(root.tobytes()).decode("ascii"),
        "rel": base64.b64encode(rel_mm.astype("<i2").tobytes()).decode("ascii"),
    }


def decode_joints(record: dict, n_joints: int) -> np.ndarray:
    """The inverse of ``encode_joints`` (what the page computes), (T, J, 3) float64 metres."""
    n = int(record["n"])
    root = np.frombuffer(base64.b64decode(record["root"]), dtype="<f4").reshape(n, 3).astype(np.float64)
    rel = np.frombuffer(base64.b64decode(record["rel"]), dtype="<i2").reshape(n, n_joints, 3) / 1000.0
    return root[:, None, :] + rel


def contact_digits(joints: np.ndarray, skeleton: Skeleton) -> str:
    """Foot contacts per frame as one hex digit (bits: l ankle, l toe, r ankle, r toe); the last frame repeats."""
    if len(joints) < 2:
        return "0" * len(joints)
    contacts = foot_contacts_from_joints(joints, skeleton)  # (T-1, 4)
    contacts = np.concatenate([contacts, contacts[-1:]], axis=0)
    bits = contacts.astype(np.int64) @ np.array([1, 2, 4, 8])
    return "".join(f"{b:x}" for b in bits)


def motion_record(features: np.ndarray, fps: float, captions: Sequence[str], source: str, skeleton: Skeleton) -> dict:
    """One clip as the page reads it: encoded joints, contacts, fps and captions."""
    joints = features_to_joints(features, skeleton, source=source)
    return {
        **encode_joints(joints),
        "fps": float(fps),
        "contacts": contact_digits(joints, skeleton),
        "captions": list(captions),
    }


def limb_tracks(features: np.ndarray) -> np.ndarray:
    """Root-relative, heading-aligned positions (T, 4, 3) of the ankles and wrists, from the ``ric`` features."""
    ric = np.asarray(features, dtype=np.float64)[:, 4 : 4 + 21 * 3].reshape(len(features), 21, 3)
    return ric[:, [j - 1 for j in LIMB_JOINTS], :]


def limb_agreement(content: np.ndarray, stylized: np.ndarray) -> float | None:
    """Mean Pearson correlation of the two clips' limb tracks (T, 4, 3), ``stylized`` resampled to the content's
    length; None when no coordinate moves in both."""
    if len(content) < 3 or len(stylized) < 3:
        return None
    t_src = np.linspace(0.0, 1.0, len(stylized))
    t_dst = np.linspace(0.0, 1.0, len(content))
    flat = stylized.reshape(len(stylized), -1)
    resampled = np.stack([np.interp(t_dst, t_src, flat[:, k]) for k in range(flat.shape[1])], axis=1)
    a, b = content.reshape(len(content), -1), resampled
    a, b = a - a.mean(axis=0), b - b.mean(axis=0)
    na, nb = np.sqrt((a * a).sum(axis=0)), np.sqrt((b * b).sum(axis=0))
    moving = (na > 1e-6) & (nb > 1e-6)
    if not moving.any():
        return None
    return float(((a * b).sum(axis=0)[moving] / (na[moving] * nb[moving])).mean())


# ---- writing the page and its chunks ------------------------------------------------------------------


class ChunkWriter:
    """Motion records into ``viewer/chunks/cNNNNN.js``, ``per_chunk`` at a time; returns each record's chunk."""

    def __init__(self, folder: Path, per_chunk: int) -> None:
        self.folder = folder
        self.per_chunk = per_chunk
        self.pending: dict[str, dict] = {}
        self.count = 0
        self.bytes = 0
        folder.mkdir(parents=True, exist_ok=True)

    def add(self, key: str, record: dict) -> int:
        self.pending[key] = record
        chunk = self.count
        if len(self.pending) >= self.per_chunk:
            self.flush()
        return chunk

    def flush(self) -> None:
        if not self.pending:
            return
        text = f"motionaugChunk({self.count}, {json.dumps(self.pending, separators=(',', ':'))});\n"
        atomic_write_text(self.folder / f"c{self.count:05d}.js", text)
        self.bytes += len(text)
        self.count += 1
        self.pending = {}


@dataclass
class ViewerEntry:
    """One row of the clip list: a stylized clip (with its content clip) or a corpus clip."""

    id: str
    source: str
    style: str
    content: str
    n_frames: int
    caption: str
    before: str = ""
    scores: dict[str, float | None] = field(default_factory=dict)
    chunk: int = -1


def start_folder(out_dir: Path) -> Path:
    data = out_dir / DATA_DIR
    if data.exists():
        shutil.rmtree(data)  # a rebuilt viewer never mixes chunks of two builds
    (data / "chunks").mkdir(parents=True)
    assets = resources.files("motionaug.augment.render") / "viewer_assets"
    for name in ASSETS:
        (data / name).write_text(assets.joinpath(name).read_text(encoding="utf-8"), encoding="utf-8")
    return data


def write_index(out_dir: Path, index: dict, title: str, chunks: ChunkWriter) -> ViewerSummary:
    data = out_dir / DATA_DIR
    text = f"motionaugIndex({json.dumps(index, separators=(',', ':'))});\n"
    atomic_write_text(data / "index.js", text)
    template = resources.files("motionaug.augment.render") / "viewer_assets" / "viewer.html"
    page = template.read_text(encoding="utf-8").replace("{{TITLE}}", html.escape(title))
    atomic_write_text(out_dir / VIEWER_HTML, page)
    total = sum(f.stat().st_size for f in data.rglob("*") if f.is_file())
    return ViewerSummary(out_dir / VIEWER_HTML, len(index["clips"]["id"]), chunks.count, total)


def make_index(
    kind: str, title: str, entries: Sequence[ViewerEntry], score_names: dict, default_sort: str, skeleton
) -> dict:
    return {
        "version": 1,
        "kind": kind,
        "title": title,
        "skeleton": {"parents": skeleton.parents, "feet": [*skeleton.feet_left, *skeleton.feet_right]},
        "scores": [{"name": n, "label": label, "higher_better": hb} for n, (label, hb) in score_names.items()],
        "default_sort": default_sort,
        "clips": {
            "id": [e.id for e in entries],
            "source": [e.source for e in entries],
            "style": [e.style for e in entries],
            "content": [e.content for e in entries],
            "frames": [e.n_frames for e in entries],
            "caption": [e.caption for e in entries],
            "before": [e.before for e in entries],
            "chunk": [e.chunk for e in entries],
            "scores": {n: [_finite(e.scores.get(n)) for e in entries] for n in score_names},
        },
    }


def _finite(value: float | None) -> float | None:
    return None if value is None or not np.isfinite(value) else round(float(value), 5)


def _first_text(captions: Sequence[dict] | None) -> str:
    return captions[0]["text"] if captions else ""


# ---- a run ------------------------------------------------------------------------------------------


def _evaluation_scores(run_dir: Path) -> dict[str, dict[str, float | None]]:
    """output_id -> the per-clip scores of ``scores.parquet`` (empty when the run has not been evaluated)."""
    path = run_dir / "scores.parquet"
    if not path.is_file():
        return {}
    table = pq.read_table(path)
    names = [n for n in EVALUATION_SCORES if n in table.column_names]
    rows = table.select(["output_id", *names]).to_pylist()
    return {r["output_id"]: {n: r[n] for n in names} for r in rows}


def _source_tracks(corpus: Corpus, ids: set[str]) -> dict[str, np.ndarray]:
    return {c.id: limb_tracks(c.motion) for c in _clips_of(corpus, ids)}


def _clips_of(corpus: Corpus, ids: set[str]) -> Iterator[MotionClip]:
    seen: set[str] = set()
    for clip in corpus:
        if clip.id in ids and clip.id not in seen:
            seen.add(clip.id)
            yield clip


def run_entries(run_dir: Path, skeleton: Skeleton = T2M) -> list[ViewerEntry]:
    """Every stylized clip of a run as a clip-list row, with its limb agreement and evaluation scores."""
    run = RunDir(run_dir)
    shards = verified_shards(run, complete=False)
    columns = ["output_id", "source_id", "style", "content", "n_frames", "captions", "original_captions"]
    rows = list(iter_shard_rows(run_dir, columns, files=shards))  # no motion: the list's rows only
    if not rows:
        raise MotionDataError(str(run_dir), "run has no stylized clips yet")
    corpus = Corpus(Path(run.config()["corpus"]["path"]), feature_dim=skeleton.feature_dim)
    tracks = _source_tracks(corpus, {r["source_id"] for r in rows})
    agreement: dict[str, float | None] = {}
    for row in iter_shard_rows(run_dir, ["output_id", "source_id", "n_frames", "n_feats", "motion"], files=shards):
        source = tracks.get(row["source_id"])
        agreement[row["output_id"]] = (
            limb_agreement(source, limb_tracks(row_motion(row))) if source is not None else None
        )
    evaluated = _evaluation_scores(run_dir)
    return [
        ViewerEntry(
            id=r["output_id"],
            source=r["source_id"],
            style=str(r["style"]),
            content=r["content"] or "",
            n_frames=int(r["n_frames"]),
            caption=_first_text(r["captions"]),
            before=_first_text(r["original_captions"]),
            scores={LIMB_AGREEMENT: agreement.get(r["output_id"]), **evaluated.get(r["output_id"], {})},
        )
        for r in sorted(rows, key=lambda r: r["output_id"])
    ]


def choose(
    entries: Sequence[ViewerEntry],
    ids: Iterable[str] | None = None,
    worst: int | None = None,
    by: str = LIMB_AGREEMENT,
) -> list[ViewerEntry]:
    """The entries named by ``ids`` (output ids or source ids), then the ``worst`` N by the score ``by`` (lowest
    first, highest for a score where lower is better), else all; clips without that score are left out."""
    chosen = list(entries)
    if ids is not None:
        wanted = set(ids)
        chosen = [e for e in entries if e.id in wanted or e.source in wanted]
        missing = wanted - {e.id for e in chosen} - {e.source for e in chosen}
        if missing:
            raise MotionDataError("--ids", f"no clip with id {sorted(missing)[0]!r}")
    if worst is not None:
        higher_better = {LIMB_AGREEMENT: True} | {n: hb for n, (_, hb) in EVALUATION_SCORES.items()}
        if by not in higher_better:
            raise MotionDataError("--by", f"unknown score {by!r}; one of {sorted(higher_better)}")
        scored = [e for e in chosen if e.scores.get(by) is not None]
        sign = 1 if higher_better[by] else -1
        chosen = sorted(scored, key=lambda e: (sign * e.scores[by], e.id))[:worst]
    return chosen


def write_run_viewer(
    run_dir: Path,
    out_dir: Path | None = None,
    ids: Iterable[str] | None = None,
    worst: int | None = None,
    per_chunk: int = CLIPS_PER_CHUNK,
    skeleton: Skeleton = T2M,
    by: str = LIMB_AGREEMENT,
) -> ViewerSummary:
    """``viewer.html`` + ``viewer/`` of a run's stylized clips (all, ``ids``, or the ``worst`` N by ``by``) into
    ``out_dir`` (default: the run folder)."""
    run_dir = Path(run_dir)
    out_dir = Path(out_dir) if out_dir is not None else run_dir
    entries = choose(run_entries(run_dir, skeleton), ids, worst, by)
    if not entries:
        raise MotionDataError(str(run_dir), "no stylized clip to show")
    chunks = ChunkWriter(start_folder(out_dir) / "chunks", per_chunk)
    corpus = Corpus(Path(RunDir(run_dir).config()["corpus"]["path"]), feature_dim=skeleton.feature_dim)
    source_chunk: dict[str, int] = {}
    for clip in _clips_of(corpus, {e.source for e in entries}):
        record = motion_record(clip.motion, clip.fps, [c.text for c in clip.captions], f"clip {clip.id}", skeleton)
        source_chunk[clip.id] = chunks.add(f"src:{clip.id}", record)
    by_id = {e.id: e for e in entries}
    shards = verified_shards(RunDir(run_dir), complete=False)
    columns = ["output_id", "n_frames", "n_feats", "fps", "motion", "captions", "original_captions"]
    for row in iter_shard_rows(run_dir, columns, files=shards):
        entry = by_id.get(row["output_id"])
        if entry is None:
            continue
        captions = [c["text"] for c in row["captions"]]
        record = motion_record(row_motion(row), float(np.float32(row["fps"])), captions, entry.id, skeleton)
        record["before"] = [c["text"] for c in row["original_captions"]]
        record["source_chunk"] = source_chunk.get(entry.source, -1)
        entry.chunk = chunks.add(entry.id, record)
    chunks.flush()
    names = {LIMB_AGREEMENT: ("limb agreement", True)} | {
        n: v for n, v in EVALUATION_SCORES.items() if any(e.scores.get(n) is not None for e in entries)
    }
    shown = [e for e in entries if e.chunk >= 0]
    title = f"run {RunDir(run_dir).recorded_run_id()}"
    index = make_index("run", title, shown, names, LIMB_AGREEMENT, skeleton)
    index["source_chunks"] = {s: c for s, c in source_chunk.items()}
    return write_index(out_dir, index, title, chunks)


def viewer_beside_report(run_dir: Path) -> tuple[ViewerSummary | None, str | None]:
    """The run's viewer for ``motionaug evaluate``: (summary, None), or (None, why) when the run's data cannot give
    one (its corpus gone, say); the evaluation stands without it."""
    try:
        return write_run_viewer(run_dir), None
    except MotionDataError as err:
        return None, str(err).splitlines()[0]


# ---- a corpus --------------------------------------------------------------------------------------


def write_corpus_viewer(
    corpus_path: Path,
    out_dir: Path,
    ids: Iterable[str] | None = None,
    per_chunk: int = CLIPS_PER_CHUNK,
    skeleton: Skeleton = T2M,
) -> ViewerSummary:
    """``viewer.html`` + ``viewer/`` of a corpus's clips (all, or ``ids``) into ``out_dir``."""
    corpus = Corpus(Path(corpus_path), feature_dim=skeleton.feature_dim)
    clips: Iterable[MotionClip] = corpus
    if ids is not None:  # read only those, and refuse an unknown id before writing anything
        clips, rejects = corpus.load(list(dict.fromkeys(ids)))
        if rejects:
            raise MotionDataError("--ids", f"no clip with id {rejects[0].id!r} in {corpus_path} ({rejects[0].reason})")
    chunks = ChunkWriter(start_folder(Path(out_dir)) / "chunks", per_chunk)
    entries: list[ViewerEntry] = []
    seen: set[str] = set()
    for clip in clips:
        if clip.id in seen:
            continue
        seen.add(clip.id)
        captions = [c.text for c in clip.captions]
        record = motion_record(clip.motion, clip.fps, captions, f"clip {clip.id}", skeleton)
        entry = ViewerEntry(
            clip.id, clip.id, clip.style or "", clip.content or "", clip.n_frames, _first_text_of(captions)
        )
        entry.scores = {"seconds": clip.n_frames / clip.fps}
        entry.chunk = chunks.add(f"src:{clip.id}", record)
        entries.append(entry)
    chunks.flush()
    if not entries:
        raise MotionDataError(str(corpus_path), "corpus has no clips")
    title = f"corpus {Path(corpus_path).name}"
    index = make_index("corpus", title, entries, {"seconds": ("seconds", True)}, "", skeleton)
    return write_index(Path(out_dir), index, title, chunks)


def _first_text_of(captions: Sequence[str]) -> str:
    return captions[0] if captions else ""
