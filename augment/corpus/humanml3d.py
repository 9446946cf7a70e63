"""The HumanML3D folder layout, read lazily clip by clip and written atomically file by file.

Layout: ``new_joint_vecs/<id>.npy`` (T, D) float32, ``texts/<id>.txt`` caption lines, split files ``<split>.txt``
(an ``M`` prefix marks a mirrored copy), ``Mean.npy``/``Std.npy``, and motionaug's optional ``labels.jsonl`` (id,
content, style, meta per clip), which reference loaders ignore, so labels survive the layout. Conventions follow
MDM's ``Text2MotionDatasetV2``: a caption with a non-zero (start, end) span becomes its own clip, frames
``[int(start*fps), int(end*fps))``, and the length filter applies to the whole file, then to each cut. Unlike the
reference, a cut gets a deterministic id (:func:`span_id`) and captions sharing a span share one cut.
"""

from __future__ import annotations

import json
import math
import os
import re
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Literal

import numpy as np

from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.corpus.rejects import Reject
from motionaug.augment.io import atomic_open, atomic_save_npy, atomic_write_text
from motionaug.augment.text.tokens import format_caption_line, parse_caption_line
from motionaug.schemas.captions import Caption
from motionaug.schemas.errors import MotionDataError

MOTION_DIR = "new_joint_vecs"
TEXT_DIR = "texts"
LABELS_FILE = "labels.jsonl"
ADDED_SPLIT = "added"  # split file of an expanded corpus: the train clips the expansion added
SAFE_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,199}")
HUMANML3D_FPS = 20.0

OnError = Literal["skip", "raise"]


def check_id(clip_id: str, source: str) -> str:
    """Ids come from data and become file names: a plain name of at most 200 characters, no '/' or '..'."""
    if not SAFE_ID.fullmatch(clip_id) or ".." in clip_id:
        raise MotionDataError(source, f"unsafe id {clip_id!r}: ids must match {SAFE_ID.pattern} without '..'")
    return clip_id


def span_id(clip_id: str, start: float, end: float) -> str:
    """Id of the cut for a caption span: ``<id>_<start centiseconds:04d>_<end centiseconds:04d>``."""
    return f"{clip_id}_{round(start * 100):04d}_{round(end * 100):04d}"


SPAN_ID = re.compile(r"^(?P<parent>.+)_\d{4,}_\d{4,}$")


def span_parent(clip_id: str) -> str | None:
    """The source id a caption-span id (:func:`span_id`) was cut from, or None for a whole-file id."""
    match = SPAN_ID.match(clip_id)
    return match.group("parent") if match else None


def check_motion(motion: np.ndarray, feature_dim: int | None, source: str) -> None:
    """A usable clip: (T, D) with T > 0, the expected width and finite values everywhere."""
    if motion.ndim != 2:
        raise MotionDataError(source, f"motion has shape {motion.shape}, expected (frames, {feature_dim or 'D'})")
    if feature_dim is not None and motion.shape[1] != feature_dim:
        raise MotionDataError(source, f"feature width {motion.shape[1]}, expected {feature_dim}")
    if motion.shape[0] == 0:
        raise MotionDataError(source, "motion has no frames")
    finite = np.isfinite(motion).all(axis=1)
    if not finite.all():
        first = int(np.argmin(finite))
        raise MotionDataError(source, f"NaN/Inf values from frame {first} ({int((~finite).sum())} bad frames)")


MAX_CLIP_FRAMES = 20_000
"""The most frames any clip may have (1,000 s at 20 fps; HumanML3D's are under 200): a longer one is refused from its
header, before a byte of it is read, so one huge file cannot take the memory of a run, a preview or an export."""


def load_npy(path: Path, ndim: int, width: int | None) -> np.ndarray:
    """Read a float .npy of ``ndim`` dims (last one ``width``) as float32, header first.

    The header alone settles shape, dtype, truncation and the ``MAX_CLIP_FRAMES`` ceiling, so a bad file costs no
    more than its header.
    """
    source = str(path)
    try:
        with open(path, "rb") as handle:
            shape, fortran, dtype = _read_npy_header(handle, source)
            if len(shape) != ndim:
                raise MotionDataError(source, f"shape {shape}, expected {ndim} dimensions")
            if width is not None and shape[-1] != width:
                raise MotionDataError(source, f"feature width {shape[-1]}, expected {width}")
            if dtype.kind != "f":
                raise MotionDataError(source, f"dtype {dtype}, expected floating point")
            _check_data_size(handle, shape, dtype, source)
            if ndim == 2 and shape[0] > MAX_CLIP_FRAMES:
                reason = f"{shape[0]} frames, over the ceiling of {MAX_CLIP_FRAMES} a clip may have; cut it into clips"
                raise MotionDataError(source, reason)
            flat = np.empty(math.prod(shape), dtype=dtype)
            got = handle.readinto(flat.view(np.uint8))
    except OSError as err:
        raise MotionDataError(source, f"unreadable ({err.strerror or err})") from None
    if got < flat.nbytes:
        raise MotionDataError(source, f"truncated .npy: {got} of {flat.nbytes} data bytes")
    array = flat.reshape(shape, order="F" if fortran else "C")
    return np.ascontiguousarray(array, dtype=np.float32)  # a no-op for the usual C-order float32


def _check_data_size(handle, shape: tuple[int, ...], dtype: np.dtype, source: str) -> None:
    """Compare the header's claim with the bytes on disk before allocating: a lying header is a reject, not a
    MemoryError (a 192-byte file can claim 10^9 frames)."""
    size = os.fstat(handle.fileno()).st_size
    if math.prod(shape) * dtype.itemsize > size - handle.tell():
        claim = f"{shape[0]} frames" if len(shape) == 2 else f"shape {shape}"
        raise MotionDataError(source, f"truncated .npy: header says {claim} but file has {size} bytes")


def _read_npy_header(handle, source: str) -> tuple[tuple[int, ...], bool, np.dtype]:
    try:
        version = np.lib.format.read_magic(handle)
        if version == (1, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_1_0(handle)
        else:
            shape, fortran, dtype = np.lib.format.read_array_header_2_0(handle)
    except (ValueError, EOFError) as err:
        raise MotionDataError(source, f"not a readable .npy file ({err})") from None
    if dtype.hasobject:
        raise MotionDataError(source, "holds Python objects, not numbers")
    return tuple(shape), bool(fortran), dtype


def read_captions(path: Path) -> list[Caption]:
    """Every caption line of a texts/<id>.txt file; blank lines are ignored, an empty file is an error."""
    if not path.is_file():
        raise MotionDataError(str(path), "caption file is missing")
    try:
        lines = path.read_text(encoding="utf-8").split("\n")  # universal newlines, like the reference's readlines
    except UnicodeDecodeError as err:
        raise MotionDataError(str(path), f"not UTF-8 text ({err.reason} at byte {err.start})") from None
    captions = [parse_caption_line(line, f"{path}:{n}") for n, line in enumerate(lines, 1) if line.strip()]
    if not captions:
        raise MotionDataError(str(path), "caption file has no captions")
    return captions


class HumanML3DReader:
    """Stream the clips of a HumanML3D folder; holds one source clip in memory at a time.

    ``split`` names a split file (``"all"``, ``"train"``, ...) or ``None`` for every .npy; ``files`` reads only
    these source ids instead (the split file is not needed then). Frame limits
    are inclusive; the reference training filter (40 <= T < 200) is ``min_frames=40, max_frames=199``.
    Skipped clips collect in ``rejects`` (reset on each iteration) unless ``on_error="raise"``.
    """

    def __init__(
        self,
        root: str | os.PathLike[str],
        split: str | None = "all",
        feature_dim: int | None = 263,
        fps: float = HUMANML3D_FPS,
        min_frames: int | None = None,
        max_frames: int | None = None,
        split_spans: bool = True,
        on_error: OnError = "skip",
        files: Iterable[str] | None = None,
    ) -> None:
        if on_error not in ("skip", "raise"):
            raise ValueError(f"on_error must be 'skip' or 'raise', got {on_error!r}")
        self.root = Path(root)
        self.split = None if split is None else check_id(split, f"split name for {self.root}")
        self.feature_dim = feature_dim
        self.fps = fps
        self.min_frames = min_frames
        self.max_frames = max_frames
        self.split_spans = split_spans
        self.on_error = on_error
        self.files = None if files is None else list(files)
        self.rejects: list[Reject] = []
        if not (self.root / MOTION_DIR).is_dir():
            raise MotionDataError(str(self.root), f"not a HumanML3D folder: no {MOTION_DIR}/")
        if self.files is None and self.split is not None and not self.split_file.is_file():
            raise MotionDataError(str(self.split_file), "split file is missing")

    @property
    def split_file(self) -> Path:
        return self.root / f"{self.split}.txt"

    def ids(self) -> list[str]:
        """Ids as listed (split file order, or sorted .npy names), before any checks."""
        return [clip_id for clip_id, _ in self._entries()]

    def mean_std(self) -> tuple[np.ndarray, np.ndarray]:
        """The dataset's ``Mean.npy`` and ``Std.npy`` as float32 (D,) vectors."""
        mean, std = (load_npy(self.root / name, 1, self.feature_dim) for name in ("Mean.npy", "Std.npy"))
        return mean, std

    def __iter__(self) -> Iterator[MotionClip]:
        self.rejects = []
        seen: set[str] = set()
        labels = read_labels(self.root)
        for clip_id, where in self._entries():
            try:
                check_id(clip_id, where)
                if clip_id in seen:
                    raise MotionDataError(where, f"duplicate id {clip_id!r}")
                seen.add(clip_id)
                npy = self.root / MOTION_DIR / f"{clip_id}.npy"
                if not npy.is_file():
                    raise MotionDataError(str(npy), f"missing, though {where} lists {clip_id!r}")
                motion = load_npy(npy, 2, self.feature_dim)
                check_motion(motion, self.feature_dim, str(npy))
                self._check_length(len(motion), str(npy))
                captions = read_captions(self.root / TEXT_DIR / f"{clip_id}.txt")
            except MotionDataError as err:
                self._reject(clip_id, err)
                continue
            for clip in self._cut(clip_id, motion, captions, str(npy), seen):
                yield self._labelled(clip, labels.get(clip.meta.get("parent", clip.id)))

    def _entries(self) -> Iterator[tuple[str, str]]:
        """(id, where it was listed), streamed from ``files``, the split file or the motion folder."""
        if self.files is not None:
            for file_id in self.files:
                yield file_id, str(self.root / MOTION_DIR / f"{file_id}.npy")
            return
        if self.split is None:
            for path in sorted((self.root / MOTION_DIR).glob("*.npy")):
                yield path.stem, str(path)
            return
        with open(self.split_file, encoding="utf-8") as handle:
            try:
                for n, line in enumerate(handle, 1):
                    if line.strip():
                        yield line.strip(), f"{self.split_file}:{n}"
            except UnicodeDecodeError as err:
                raise MotionDataError(str(self.split_file), f"not UTF-8 text ({err.reason})") from None

    def _check_length(self, n_frames: int, source: str) -> None:
        if self.min_frames is not None and n_frames < self.min_frames:
            raise MotionDataError(source, f"{n_frames} frames, fewer than min_frames={self.min_frames}")
        if self.max_frames is not None and n_frames > self.max_frames:
            raise MotionDataError(source, f"{n_frames} frames, more than max_frames={self.max_frames}")

    def _reject(self, clip_id: str, err: MotionDataError) -> None:
        if self.on_error == "raise":
            raise err
        self.rejects.append(Reject.from_error(clip_id, err))

    @staticmethod
    def _labelled(clip: MotionClip, record: dict | None) -> MotionClip:
        if record is not None:
            clip.content, clip.style = record.get("content"), record.get("style")
            clip.meta = {**record.get("meta", {}), **clip.meta}
        return clip

    def _meta(self) -> dict[str, str]:
        return {"split": self.split} if self.split not in (None, "all") else {}

    def _cut(
        self, clip_id: str, motion: np.ndarray, captions: list[Caption], source: str, seen: set[str]
    ) -> Iterator[MotionClip]:
        """The clip with its whole-clip captions, then one cut per distinct caption span (ids added to ``seen``)."""
        whole = captions if not self.split_spans else [c for c in captions if c.whole_clip]
        if whole:
            yield MotionClip(clip_id, motion, whole, fps=self.fps, source=source, meta=self._meta())
        if not self.split_spans:
            return
        spans: dict[tuple[float, float], list[Caption]] = {}
        for caption in captions:
            if not caption.whole_clip:
                spans.setdefault((caption.start, caption.end), []).append(caption)
        for (start, end), group in spans.items():
            cut_id = span_id(clip_id, start, end)
            first, stop = int(start * self.fps), int(end * self.fps)
            cut = motion[first:stop]
            try:
                if cut_id in seen:
                    raise MotionDataError(source, f"caption span {start}-{end} s gives the duplicate id {cut_id!r}")
                if len(cut) == 0:
                    raise MotionDataError(source, f"caption span {start}-{end} s is empty in {len(motion)} frames")
                self._check_length(len(cut), f"{source} [{first}:{stop}]")
            except MotionDataError as err:
                self._reject(cut_id, err)
                continue
            seen.add(cut_id)
            whole_captions = [c.model_copy(update={"start": 0.0, "end": 0.0}) for c in group]
            meta = {**self._meta(), "parent": clip_id, "span": f"{start!r}-{end!r}"}
            yield MotionClip(cut_id, cut.copy(), whole_captions, fps=self.fps, source=source, meta=meta)


def write_humanml3d(
    clips: Iterable[MotionClip],
    root: str | os.PathLike[str],
    splits: dict[str, list[str]] | None = None,
    mean_std: tuple[np.ndarray, np.ndarray] | None = None,
    fps: float = HUMANML3D_FPS,
) -> list[str]:
    """Write clips in the HumanML3D layout, one atomic file at a time; returns the ids written.

    The same clips always give the same bytes. ``all.txt`` lists every clip unless ``splits`` has
    an "all". Content/style labels and meta go to the ``labels.jsonl`` sidecar.
    """
    root = Path(root)
    written: list[str] = []
    seen: set[str] = set()
    labels: list[str] = []
    width: int | None = None
    for clip in clips:
        source = f"clip {clip.id!r}"
        check_id(clip.id, source)
        if clip.id in seen:
            raise MotionDataError(source, "duplicate id")
        if clip.fps != fps:
            raise MotionDataError(source, f"fps {clip.fps}, but this HumanML3D folder is {fps} fps")
        check_motion(clip.motion, width, source)
        width = clip.motion.shape[1]
        _write_clip(clip, root, source)
        seen.add(clip.id)
        written.append(clip.id)
        if clip.content or clip.style or clip.meta:
            labels.append(_labels_line(clip))
    _write_splits(root, {"all": written, **(splits or {})}, seen)
    if labels:
        atomic_write_text(root / LABELS_FILE, "".join(labels))
    if mean_std is not None:
        for name, vector in zip(("Mean.npy", "Std.npy"), mean_std):
            atomic_save_npy(root / name, np.asarray(vector, dtype=np.float32))
    return written


def _write_clip(clip: MotionClip, root: Path, source: str) -> None:
    if not clip.captions:
        raise MotionDataError(source, "no captions; a HumanML3D clip needs at least one")
    lines = [format_caption_line(caption, source) + "\n" for caption in clip.captions]
    atomic_save_npy(root / MOTION_DIR / f"{clip.id}.npy", np.ascontiguousarray(clip.motion, dtype=np.float32))
    atomic_write_text(root / TEXT_DIR / f"{clip.id}.txt", "".join(lines))


def _write_splits(root: Path, splits: dict[str, list[str]], written: set[str]) -> None:
    for name, ids in splits.items():
        source = f"split {name!r}"
        check_id(name, source)
        missing = [clip_id for clip_id in ids if clip_id not in written]
        if missing:
            raise MotionDataError(source, f"{len(missing)} ids were not written, e.g. {missing[0]!r}")
        with atomic_open(root / f"{name}.txt", "w") as handle:
            handle.writelines(f"{clip_id}\n" for clip_id in ids)


def _labels_line(clip: MotionClip) -> str:
    record = {"id": clip.id, "content": clip.content, "style": clip.style, "meta": clip.meta}
    return json.dumps(record, sort_keys=True) + "\n"


def read_labels(root: Path) -> dict[str, dict]:
    """The ``labels.jsonl`` sidecar by id (empty when the folder has none)."""
    path = Path(root) / LABELS_FILE
    if not path.is_file():
        return {}
    records: dict[str, dict] = {}
    with open(path, encoding="utf-8") as handle:
        for n, line in enumerate(handle, 1):
            if not line.strip():
                continue
            try:
                record = json.loads(line)
                records[str(record["id"])] = record
            except (ValueError, KeyError, TypeError) as err:
                raise MotionDataError(f"{path}:{n}", f"not a labels record ({type(err).__name__}: {err})") from None
    return records
