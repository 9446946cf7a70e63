"""Turn a folder of BVH files into a corpus: retarget to t2m, resample to 20 fps, extract features, caption.

Labels come from options, or from Bandai-style file names and JSON; captions are written from them. A file that
cannot be used becomes a reject with its reason. Options make the result training-ready the way the on-the-fly paper
prepares Bandai-2 (sec. 4.2): long takes cut into equal pieces (never padded, no frame dropped), whole takes given to
val/test per (content, style) pair before any BVH is read (so a take's split never depends on another file),
``Mean.npy``/``Std.npy`` from the train split only, clips under MDM's 40-frame minimum kept and listed in
``too_short_for_mdm.txt``, and the data licence carried into ``corpus.json``, ``NOTICE`` and a copy of ``LICENSE``.
``docs/bandai.md`` gives the exact rules.
"""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import time
from collections import defaultdict
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from motionaug.augment.corpus import REJECTS_FILE
from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.corpus.humanml3d import LABELS_FILE, MOTION_DIR, load_npy, span_id, write_humanml3d
from motionaug.augment.corpus.import_target import ImportMode, ImportTarget
from motionaug.augment.corpus.parquet import ParquetCorpusWriter, read_parquet_corpus
from motionaug.augment.corpus.rejects import Reject, write_rejects
from motionaug.augment.io import atomic_write_text
from motionaug.augment.motion.bvh import read_bvh
from motionaug.augment.motion.features import compute_mean_std, extract_features
from motionaug.augment.motion.retarget import (
    BUILTIN_MAPS,
    JointMap,
    labels_from_bandai,
    nominal_fps,
    resample,
    retarget_positions,
)
from motionaug.augment.text.label_captions import label_caption, label_captions
from motionaug.schemas.errors import MotionDataError

MIN_FRAMES = 10
MDM_MIN_FRAMES = 40  # MDM's Text2MotionDatasetV2 drops clips shorter than this (and of 200 frames or more)
BANDAI2_CLIP_FRAMES = 196  # the paper's Bandai-2 clip length (sec. 4.2), also MDM's max_motion_length
TOO_SHORT_FILE = "too_short_for_mdm.txt"
CORPUS_META_FILE = "corpus.json"
NOTICE_FILE = "NOTICE"
LICENSE_FILE = "LICENSE"
SPLITS = ("train", "val", "test")
__all__ = [
    "CorpusMeta",
    "ImportSummary",
    "corpus_licence",
    "cut_bounds",
    "cut_clip",
    "import_bvh",
    "iter_bvh_clips",
    "label_caption",
    "split_takes",
]

BANDAI_LICENCE = (
    "CC BY-NC 4.0, non-commercial use only; Bandai Namco Research Inc., Bandai-Namco-Research-Motiondataset"
)
BANDAI_ATTRIBUTION = (
    "Bandai Namco Research Inc., Bandai-Namco-Research-Motiondataset "
    "(https://github.com/BandaiNamcoResearchInc/Bandai-Namco-Research-Motiondataset)"
)
_BANDAI_NAME = re.compile(r"dataset-\d+_[^_]+_[^_]+_\d+")
_UNSAFE = re.compile(r"[^A-Za-z0-9_.-]+")
_TAKE_NUMBER = re.compile(r"(\d+)$")

CUT_RULE = "takes longer than {n} frames are cut into ceil(T/{n}) consecutive equal pieces (+-1 frame), never padded"
AUTO_FRACTION = 0.15
AUTO_SPLIT_RULE = (
    "per (content, style) pair in take-number order: the last round(15% of its takes) (at least 1) test, as many "
    "before them val, the rest train (at least one stays in train)"
)
SPLIT_RULE = (
    "per (content, style) pair in take-number order: the last {test} takes test, the {val} before them val, "
    "the rest train (fewer when a pair has under {need} takes; at least one stays in train)"
)


class ImportSummary(BaseModel):
    clips: int
    frames: int
    rejects: list[Reject]
    out: str
    takes: int = 0
    cut_takes: int = 0
    pieces: int = Field(0, description="Clips cut from the takes in cut_takes.")
    too_short: list[str] = Field(default_factory=list, description=f"Clips under {MDM_MIN_FRAMES} frames.")
    skipped: list[str] = Field(default_factory=list, description="Clip ids the target already held (append).")
    splits: dict[str, int] = Field(default_factory=dict, description="Clips per split file.")
    missing_pairs: dict[str, list[str]] = Field(default_factory=dict, description="'content/style' absent per split.")
    licence: str | None = None
    seconds: float = 0.0
    notes: list[str] = Field(default_factory=list, description="What a default could not do, and why.")


class CorpusMeta(BaseModel):
    """``corpus.json``: where an imported corpus came from, how it was cut and split, and its licence."""

    model_config = ConfigDict(extra="forbid")

    version: int = 1
    source: str
    format: str
    fps: float = 20.0
    licence: str | None = None
    attribution: str | None = None
    commercial_use: bool | None = None
    cut_rule: str | None = None
    split_rule: str | None = None
    mean_std: str | None = Field(None, description="Which clips Mean.npy/Std.npy were computed from.")
    captions_per_clip: int = 1
    takes: int = 0
    clips: int = 0
    splits: dict[str, int] = Field(default_factory=dict)
    too_short_for_mdm: int = 0


def clip_id_from_path(path: Path) -> str:
    """A filename-safe id from a file stem; data never becomes a path unchecked."""
    stem = _UNSAFE.sub("_", path.stem).strip("._-")
    return stem[:200] or "clip"


def bvh_files(src: Path) -> list[Path]:
    """``src`` itself or every ``*.bvh`` under it, sorted."""
    files = [src] if src.is_file() else sorted(src.rglob("*.bvh"))
    if not files:
        raise MotionDataError(str(src), "no .bvh files found")
    return files


class LabelPattern:
    """Labels read from file names: ``{style}_{take}_{part}.bvh`` (fields ``style``, ``content``, ``take``; any other
    ``{name}`` matches a part of the name and is ignored). A field matches one or more characters other than ``/``;
    the pattern matches the whole file name (the stem when the pattern has no ``.bvh``)."""

    FIELDS = ("style", "content", "take")

    def __init__(self, pattern: str) -> None:
        self.pattern = pattern
        parts = re.split(r"\{([A-Za-z_][A-Za-z0-9_]*)\}", pattern)
        names = parts[1::2]
        if not names:
            raise MotionDataError(
                "--labels-from", f"{pattern!r} has no {{field}}; e.g. '{{style}}_{{take}}_{{part}}.bvh'"
            )
        if len(set(names)) != len(names):
            raise MotionDataError("--labels-from", f"{pattern!r} names a field twice")
        regex = "".join(re.escape(text) if i % 2 == 0 else f"(?P<{text}>[^/]+?)" for i, text in enumerate(parts))
        self.regex = re.compile(regex)
        self.names = set(names)

    def match(self, path: Path) -> dict[str, str]:
        """The fields of ``path``'s name; a name that does not fit is an error naming the pattern."""
        name = path.name if self.pattern.lower().endswith(".bvh") else path.stem
        found = self.regex.fullmatch(name)
        if not found:
            raise MotionDataError(str(path), f"name does not match --labels-from {self.pattern!r}")
        return {k: v for k, v in found.groupdict().items() if k in self.FIELDS}


def clip_labels(
    path: Path, content: str | None = None, style: str | None = None, labels: LabelPattern | None = None
) -> tuple[str, str | None]:
    """(content, style): from ``labels`` (the file name) when given, the options when ``content`` is given, else the
    Bandai JSON/name; a ``style`` option overrides.

    ``style`` alone relabels the style of Bandai files; other files need ``content`` (the reject says so).
    """
    if labels is not None:
        fields = labels.match(path)
        c = fields.get("content") or content
        if not c:
            raise MotionDataError(str(path), f"--labels-from {labels.pattern!r} has no {{content}}; pass --content")
        return c, style or fields.get("style")
    if content:
        return content, style
    try:
        c, s = labels_from_bandai(path)
    except MotionDataError as err:
        raise MotionDataError(err.source, f"{err.reason}; {LABELS_HINT}") from None
    return c, style or s


LABELS_HINT = "pass --content (and --style) to label files not named like Bandai's"
JOINT_MAP_HINT = "pass --joint-map FILE for this rig (docs/joint-map.md)"


def load_joint_map(joint_map: JointMap | str | os.PathLike[str] | None) -> JointMap | None:
    """The map given as an option, read once: a bad map file is one error up front, not a reject per file."""
    if joint_map is None or isinstance(joint_map, JointMap):
        return joint_map
    try:
        return JointMap.from_file(joint_map)
    except MotionDataError as err:
        raise MotionDataError(err.source, f"{err.reason} (format: docs/joint-map.md)") from None


def t2m_joints(path: Path, joint_map: JointMap | None, fps: float) -> np.ndarray:
    """(T, 22, 3) t2m joints of a BVH at ``fps``; a skeleton no map fits is a reject naming ``--joint-map``."""
    motion = read_bvh(path)
    if joint_map is None:
        names = set(motion.names)
        joint_map = next((m for m in BUILTIN_MAPS if m.source_joints() <= names), None)
        if joint_map is None:
            raise MotionDataError(str(path), f"no built-in joint map fits its joints {motion.names}; {JOINT_MAP_HINT}")
    missing = sorted(joint_map.source_joints() - set(motion.names))
    if missing:
        reason = f"joint map {joint_map.name!r} needs joints the file lacks: {missing}; fix the --joint-map file"
        raise MotionDataError(str(path), reason)
    return resample(retarget_positions(motion, joint_map), nominal_fps(motion.frame_time), fps)


def iter_bvh_clips(
    src: Path,
    rejects: list[Reject],
    content: str | None = None,
    style: str | None = None,
    joint_map: JointMap | str | os.PathLike[str] | None = None,
    fps: float = 20.0,
    captions: int = 3,
    labels: LabelPattern | None = None,
) -> Iterator[MotionClip]:
    """Clips of every ``*.bvh`` under ``src`` (or ``src`` itself), in sorted order, with ``captions`` captions each.

    Labels are checked before the BVH is parsed (cheap); every reject's reason names the option that fixes it,
    where one does.
    """
    seen: set[str] = set()
    joint_map = load_joint_map(joint_map)
    for path in bvh_files(src):
        clip_id = clip_id_from_path(path)
        try:
            if clip_id in seen:
                raise MotionDataError(str(path), f"duplicate clip id {clip_id!r}; rename one of the files")
            c, s = clip_labels(path, content, style, labels)
            joints = t2m_joints(path, joint_map, fps)
            if len(joints) < MIN_FRAMES + 1:
                raise MotionDataError(str(path), f"{len(joints)} frames at {fps:g} fps; need at least {MIN_FRAMES + 1}")
            motion = extract_features(joints, source=str(path))
        except MotionDataError as err:
            rejects.append(Reject.from_error(clip_id, err))
            continue
        seen.add(clip_id)
        texts = label_captions(c, s, n=captions, seed=clip_id)
        meta = {"take": labels.match(path)["take"]} if labels is not None and "take" in labels.names else {}
        yield MotionClip(clip_id, motion, texts, fps=fps, content=c, style=s, source=str(path), meta=meta)


# ---- cutting ----------------------------------------------------------------------------------------------------


def cut_bounds(n_frames: int, max_frames: int) -> list[tuple[int, int]]:
    """[start, stop) of each piece: ``ceil(n / max)`` consecutive pieces whose lengths differ by at most one.

    Equal pieces rather than full ``max_frames`` windows plus a remainder: no piece is a short leftover (each
    is at least half of ``max_frames`` once a take is cut), nothing is dropped and nothing needs padding.
    """
    if max_frames < 1:
        raise ValueError(f"max_frames must be >= 1, got {max_frames}")
    pieces = max(1, math.ceil(n_frames / max_frames))
    base, extra = divmod(n_frames, pieces)
    bounds, start = [], 0
    for k in range(pieces):
        stop = start + base + (1 if k < extra else 0)
        bounds.append((start, stop))
        start = stop
    return bounds


def cut_clip(clip: MotionClip, max_frames: int, captions: int = 3) -> list[MotionClip]:
    """The clip itself when it fits, else its pieces (``cut_bounds``), each with its own whole-clip captions."""
    bounds = cut_bounds(clip.n_frames, max_frames)
    if len(bounds) == 1:
        return [clip]
    pieces = []
    for k, (start, stop) in enumerate(bounds, 1):
        piece_id = span_id(clip.id, start / clip.fps, stop / clip.fps)
        texts = label_captions(clip.content, clip.style, n=captions, seed=piece_id) if clip.content else clip.captions
        meta = {**clip.meta, "take": clip.id, "piece": f"{k}/{len(bounds)}", "frames": f"{start}-{stop}"}
        pieces.append(
            MotionClip(
                piece_id,
                clip.motion[start:stop].copy(),
                [c.model_copy(update={"start": 0.0, "end": 0.0}) for c in texts],
                fps=clip.fps,
                content=clip.content,
                style=clip.style,
                source=clip.source,
                meta=meta,
            )
        )
    return pieces


# ---- splits -----------------------------------------------------------------------------------------------------


def take_number(take_id: str) -> int | None:
    """The trailing number of a take id ('dataset-2_walk_elderly_017' -> 17), None without one."""
    match = _TAKE_NUMBER.search(take_id)
    return int(match.group(1)) if match else None


def auto_takes(n_takes: int) -> int:
    """Val (and test) takes of a pair with ``n_takes`` takes when none are given: ``AUTO_FRACTION`` of them, at
    least one; on Bandai-2 this is the paper's protocol (docs/bandai.md)."""
    return max(1, round(AUTO_FRACTION * n_takes))


def split_takes(
    takes: Iterable[tuple[str, tuple[str, str | None]]], val_takes: int | None, test_takes: int | None
) -> dict[str, str]:
    """Split of each take id, given (take id, (content, style)) pairs; see ``SPLIT_RULE``.

    Per pair, takes are ordered by take number (then id); the last ``test_takes`` go to test and the ``val_takes``
    before them to val (None: ``auto_takes`` of the pair's takes). A pair with fewer than ``val_takes + test_takes
    + 1`` takes keeps at least one take in train and shares the rest between test and val (test first).
    """
    if (val_takes or 0) < 0 or (test_takes or 0) < 0:
        raise ValueError(f"val_takes and test_takes must be >= 0, got {val_takes} and {test_takes}")
    by_pair: dict[tuple[str, str | None], list[str]] = defaultdict(list)
    for take_id, pair in takes:
        if take_id not in by_pair[pair]:
            by_pair[pair].append(take_id)
    split_of: dict[str, str] = {}
    for ids in by_pair.values():
        ids.sort(key=lambda t: (take_number(t) is None, take_number(t) or 0, t))
        test_takes_here = auto_takes(len(ids)) if test_takes is None else test_takes
        val_takes_here = auto_takes(len(ids)) if val_takes is None else val_takes
        spare = len(ids) - 1
        n_test = min(test_takes_here, math.ceil(spare / 2) if val_takes_here else spare)
        n_val = min(val_takes_here, spare - n_test)
        n_train = len(ids) - n_test - n_val
        for i, take_id in enumerate(ids):
            split_of[take_id] = "train" if i < n_train else "val" if i < n_train + n_val else "test"
    return split_of


def _take_ids(
    files: list[Path], content: str | None, style: str | None, labels: LabelPattern | None
) -> dict[str, tuple[str, tuple[str, str | None]]]:
    """clip id -> (take id, (content, style)) from names and labels only; the take is the file unless ``labels``
    reads a ``{take}`` (then the files of one take share it)."""
    takes = {}
    for path in files:
        try:
            pair = clip_labels(path, content, style, labels)
            take = labels.match(path)["take"] if labels is not None and "take" in labels.names else None
        except MotionDataError:
            continue  # rejected with its reason when the clip is read
        clip_id = clip_id_from_path(path)
        takes[clip_id] = (f"{pair[0]}/{pair[1]}/{take}" if take is not None else clip_id, pair)
    return takes


def carry_take_ids(takes: dict[str, tuple[str, tuple[str, str | None]]]) -> bool:
    """Every file names a numbered take (Bandai's ``..._017``, or a ``{take}`` field ending in a number)."""
    return bool(takes) and all(take_number(take) is not None for take, _ in takes.values())


def _planned_splits(
    takes: dict[str, tuple[str, tuple[str, str | None]]], val_takes: int | None, test_takes: int | None
) -> dict[str, str]:
    """Splits from names and labels only, so a take's split never depends on whether another take imports."""
    split_of_take = split_takes(takes.values(), val_takes, test_takes)
    return {clip_id: split_of_take[take] for clip_id, (take, _) in takes.items()}


# ---- licence ----------------------------------------------------------------------------------------------------


def is_bandai_name(path: Path) -> bool:
    """A Bandai Namco Research file name: ``dataset-N_{content}_{style}_{id}``."""
    return bool(_BANDAI_NAME.fullmatch(path.stem))


def _licence_file(src: Path, files: list[Path]) -> Path | None:
    """The source's LICENSE: in ``src``, else beside a Bandai dataset (its root, or the folder above it)."""
    candidates = [src / LICENSE_FILE] if src.is_dir() else [src.parent / LICENSE_FILE]
    for path in files[:1]:
        root = path.parent.parent
        candidates += [root / LICENSE_FILE, root.parent / LICENSE_FILE]
    return next((c for c in candidates if c.is_file()), None)


def corpus_licence(root: str | os.PathLike[str]) -> str | None:
    """The licence recorded with a corpus (``corpus.json``'s ``licence``, else ``NOTICE``'s first line), or None.

    ``root`` is the corpus folder or a file in it (a ``.parquet``); carry the string into manifests and exports.
    """
    root = Path(root)
    folder = root if root.is_dir() else root.parent
    meta = folder / CORPUS_META_FILE
    if meta.is_file():
        try:
            record = json.loads(meta.read_text(encoding="utf-8"))
        except (ValueError, UnicodeDecodeError) as err:
            raise MotionDataError(str(meta), f"not a JSON corpus record ({err})") from None
        if isinstance(record, dict) and record.get("licence"):
            return str(record["licence"])
    notice = folder / NOTICE_FILE
    if notice.is_file():
        first = next((ln.strip() for ln in notice.read_text(encoding="utf-8").splitlines() if ln.strip()), "")
        return first.removeprefix("Licence:").strip() or None
    return None


def _write_licence(out: Path, licence: str, bandai: bool, licence_file: Path | None) -> None:
    lines = [f"Licence: {licence}"]
    if bandai:
        lines += [
            f"Attribution: {BANDAI_ATTRIBUTION}.",
            "Motion data derived from the Bandai Namco Research motion datasets (retargeted to the t2m skeleton,",
            "resampled to 20 fps, cut into clips, captioned from the labels). Creative Commons",
            "Attribution-NonCommercial 4.0 International: https://creativecommons.org/licenses/by-nc/4.0/.",
            "Do not use this corpus, or models and data made from it, for commercial purposes.",
        ]
    if licence_file is not None:
        lines.append(f"The source's licence text is in {LICENSE_FILE}.")
        (out / LICENSE_FILE).unlink(missing_ok=True)  # may be a hard link into the corpus being appended to
        shutil.copyfile(licence_file, out / LICENSE_FILE)
    atomic_write_text(out / NOTICE_FILE, "\n".join(lines) + "\n")


# ---- import -----------------------------------------------------------------------------------------------------

MERGED_FILES = ("all.txt", "labels.jsonl", REJECTS_FILE, TOO_SHORT_FILE, *(f"{n}.txt" for n in (*SPLITS, "train_val")))


def import_bvh(
    src: str | os.PathLike[str],
    out: str | os.PathLike[str],
    fmt: Literal["humanml3d", "parquet"] = "humanml3d",
    content: str | None = None,
    style: str | None = None,
    joint_map: str | os.PathLike[str] | None = None,
    *,
    max_frames: int | None = None,
    val_takes: int | None = 0,
    test_takes: int | None = 0,
    mean_std: bool | None = False,
    licence: str | None = None,
    captions: int = 3,
    mode: ImportMode = "new",
    labels_from: str | None = None,
    progress: Callable[[str, int, int, dict[str, float]], None] | None = None,
) -> ImportSummary:
    """Write every usable BVH under ``src`` to ``out``; rejects go to ``out/rejects.jsonl``.

    ``mode``: ``new`` needs ``out`` absent or empty, ``append`` adds clips to the corpus in ``out`` (ids it holds
    are skipped, never overwritten), ``force`` replaces the corpus in ``out``. The corpus is built in a staging
    sibling and swapped in at the end, so a failed import leaves ``out`` as it was; nothing imported is an error.
    ``max_frames`` cuts long takes (``cut_bounds``); ``val_takes``/``test_takes`` > 0 split takes per (content,
    style) pair (``split_takes``) into ``train.txt``/``val.txt``/``test.txt``/``train_val.txt`` beside ``all.txt``
    (HumanML3D) or the ``split`` column (Parquet); ``mean_std`` writes ``Mean.npy``/``Std.npy`` from the train
    split (every clip without splits; None: when the clips allow, else a note in ``notes``).
    ``val_takes``/``test_takes`` None: ``auto_takes`` per pair when the files carry take ids (``carry_take_ids``),
    else no splits. ``labels_from`` reads labels from file names (``LabelPattern``). ``licence`` names the data's
    licence; Bandai file names imply theirs.
    ``progress(stage, files done, files, {})`` hears of each file read.
    """
    started = time.perf_counter()
    src, out = Path(src), Path(out)
    if not src.exists():
        raise MotionDataError(str(src), "does not exist")
    if max_frames is not None and max_frames < MIN_FRAMES:
        raise MotionDataError("--max-frames", f"must be at least {MIN_FRAMES}, got {max_frames}")
    if captions < 1 or (val_takes or 0) < 0 or (test_takes or 0) < 0:
        raise MotionDataError("options", "captions must be >= 1 and val/test takes >= 0")
    files = bvh_files(src)
    the_map = load_joint_map(joint_map)
    labels = LabelPattern(labels_from) if labels_from else None
    target = ImportTarget.open(out, fmt, mode)
    try:
        options = ImportOptions(
            fmt, content, style, the_map, max_frames, val_takes, test_takes, mean_std, licence, captions, labels
        )
        summary = _import_into(target, src, files, options, progress)
        if summary.clips == 0:
            first = f"; first: {summary.rejects[0]}" if summary.rejects else ""
            reason = (
                f"nothing imported ({len(summary.rejects)} rejected, {len(summary.skipped)} already in {out}){first}"
            )
            raise MotionDataError(str(src), reason)
        target.publish()
    finally:
        target.discard()
    summary.seconds = time.perf_counter() - started
    return summary


@dataclass(frozen=True)
class ImportOptions:
    """What ``import_bvh`` was asked to do (its arguments, the joint map read)."""

    fmt: str
    content: str | None
    style: str | None
    joint_map: JointMap | None
    max_frames: int | None
    val_takes: int | None
    test_takes: int | None
    mean_std: bool | None
    licence: str | None
    captions: int
    labels: LabelPattern | None = None


def _import_into(
    target: ImportTarget,
    src: Path,
    files: list[Path],
    o: ImportOptions,
    progress: Callable[[str, int, int, dict[str, float]], None] | None = None,
) -> ImportSummary:
    """The import proper, into ``target.stage``; files the import rewrites are merged with the target's."""
    stage = target.stage
    takes = _take_ids(files, o.content, o.style, o.labels)
    auto = o.val_takes is None or o.test_takes is None
    splitting = carry_take_ids(takes) if auto else (o.val_takes or 0) > 0 or (o.test_takes or 0) > 0
    split_of = _planned_splits(takes, o.val_takes, o.test_takes) if splitting else {}
    bandai = any(is_bandai_name(path) for path in files)
    licence = o.licence or (BANDAI_LICENCE if bandai else None)

    rejects: list[Reject] = []
    summary = ImportSummary(clips=0, frames=0, rejects=rejects, out=str(target.out), licence=licence)
    split_ids: dict[str, list[str]] = {name: [] for name in SPLITS}
    pairs: dict[str, set[str]] = {name: set() for name in (*SPLITS, "all")}

    read = 0

    def counted() -> Iterator[MotionClip]:
        nonlocal read
        for take in iter_bvh_clips(src, rejects, o.content, o.style, o.joint_map, captions=o.captions, labels=o.labels):
            read += 1
            if progress is not None:
                progress("read", min(read + len(rejects), len(files)), len(files), {})
            split = split_of.get(take.id)
            if split:
                take.meta["split"] = split
            pieces = cut_clip(take, o.max_frames, o.captions) if o.max_frames else [take]
            summary.skipped += [clip.id for clip in pieces if clip.id in target.existing]
            pieces = [clip for clip in pieces if clip.id not in target.existing]
            if not pieces:
                continue
            summary.takes += 1
            if len(pieces) > 1:
                summary.cut_takes += 1
                summary.pieces += len(pieces)
            for clip in pieces:
                summary.frames += clip.n_frames
                pair = f"{clip.content}/{clip.style}"
                pairs["all"].add(pair)
                if split:
                    split_ids[split].append(clip.id)
                    pairs[split].add(pair)
                if clip.n_frames < MDM_MIN_FRAMES:
                    summary.too_short.append(clip.id)
                yield clip

    target.take_over(*MERGED_FILES)
    if o.fmt == "humanml3d":
        ids = write_humanml3d(counted(), stage)
    else:
        ids = []
        with ParquetCorpusWriter(stage / target.next_parquet_name()) as writer:
            for clip in counted():
                writer.write(clip)
                ids.append(clip.id)
    summary.clips = len(ids)
    summary.rejects = rejects  # the model holds a copy of the list it was given
    new_ids = set(ids)
    old_rejects = [r for r in _old_rejects(target) if r.id not in new_ids]  # a re-import may fix an old reject
    write_rejects([*old_rejects, *rejects], stage / REJECTS_FILE)
    atomic_write_text(stage / TOO_SHORT_FILE, "".join(f"{clip_id}\n" for clip_id in summary.too_short))
    too_short = target.merge_lines(TOO_SHORT_FILE)
    if o.fmt == "humanml3d":
        target.merge_lines("all.txt")
        target.merge_lines(LABELS_FILE)
    if splitting:
        split_ids["train_val"] = split_ids["train"] + split_ids["val"]
        if o.fmt == "humanml3d":
            for name, members in split_ids.items():
                atomic_write_text(stage / f"{name}.txt", "".join(f"{clip_id}\n" for clip_id in members))
        missing = {name: sorted(pairs["all"] - pairs[name]) for name in SPLITS}
        summary.missing_pairs = {name: absent for name, absent in missing.items() if absent}
    if o.fmt == "humanml3d":
        for name in (*SPLITS, "train_val"):
            target.merge_lines(f"{name}.txt")
    summary.splits = {name: len(members) for name, members in split_ids.items()} if splitting else {}
    wrote_stats = False
    # never leave stale statistics; with no clip there are none (the caller says why)
    if ids and (o.mean_std is not False or (target.appending and (stage / "Mean.npy").is_file())):
        try:
            compute_mean_std(_train_motions(stage, o.fmt)).save(stage)
            wrote_stats = True
        except MotionDataError as err:
            if o.mean_std:  # asked for: an error; by default: a note
                raise
            (stage / "Mean.npy").unlink(missing_ok=True)
            (stage / "Std.npy").unlink(missing_ok=True)
            summary.notes.append(f"no Mean/Std written: {err.reason} (too few or too similar train clips)")
    if licence:
        _write_licence(stage, licence, bandai, _licence_file(src, files))
    meta = CorpusMeta(
        source=src.name or str(src),
        format=o.fmt,
        licence=licence,
        attribution=BANDAI_ATTRIBUTION if bandai else None,
        commercial_use=False if bandai else None,
        cut_rule=CUT_RULE.format(n=o.max_frames) if o.max_frames else None,
        split_rule=_split_rule(o) if splitting else None,
        mean_std=("train split" if splitting else "all clips") if wrote_stats else None,
        captions_per_clip=o.captions,
        takes=summary.takes,
        clips=summary.clips,
        splits=summary.splits,
        too_short_for_mdm=len(too_short),
    )
    atomic_write_text(stage / CORPUS_META_FILE, _merged_meta(target, meta).model_dump_json(indent=2) + "\n")
    return summary


def _split_rule(o: ImportOptions) -> str:
    if o.val_takes is None or o.test_takes is None:
        return AUTO_SPLIT_RULE
    return SPLIT_RULE.format(val=o.val_takes, test=o.test_takes, need=o.val_takes + o.test_takes + 1)


def _old_rejects(target: ImportTarget) -> list[Reject]:
    return [Reject.model_validate_json(line) for line in target.old_lines(REJECTS_FILE)]


def _train_motions(root: Path, fmt: str) -> Iterator[np.ndarray]:
    """Motion of the train split (every clip when the corpus has no splits), read back from the staged corpus."""
    if fmt == "humanml3d":
        listed = root / "train.txt" if (root / "train.txt").is_file() else root / "all.txt"
        for clip_id in listed.read_text(encoding="utf-8").split():
            yield load_npy(root / MOTION_DIR / f"{clip_id}.npy", 2, None)
        return
    clips = list(read_parquet_corpus(root))
    splitting = any(clip.meta.get("split") for clip in clips)
    yield from (clip.motion for clip in clips if not splitting or clip.meta.get("split") == "train")


def _merged_meta(target: ImportTarget, meta: CorpusMeta) -> CorpusMeta:
    """``corpus.json`` of an append: the counts of what was there plus what was added."""
    path = target.out / CORPUS_META_FILE
    if not target.appending or not path.is_file():
        return meta
    try:
        old = CorpusMeta.model_validate_json(path.read_text(encoding="utf-8"))
    except ValueError:
        return meta
    splits = {k: old.splits.get(k, 0) + meta.splits.get(k, 0) for k in {*old.splits, *meta.splits}}
    source = old.source if old.source == meta.source else f"{old.source} + {meta.source}"
    return meta.model_copy(
        update={"source": source, "takes": old.takes + meta.takes, "clips": old.clips + meta.clips, "splits": splits}
    )
