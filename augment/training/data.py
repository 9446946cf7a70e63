"""A corpus split held in memory as normalised float32 tensors, drawn into padded training batches.

Pretraining corpora are small enough to keep whole (1000 synthetic clips are ~100 MB), and holding
them avoids re-reading .npy files every step. Caption embeddings are computed once for the distinct
captions (they repeat across clips). Batches are drawn with an explicit ``torch.Generator`` so a
resumed run draws exactly the batches an uninterrupted one would.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.corpus.corpus import Corpus
from motionaug.augment.corpus.humanml3d import HumanML3DReader
from motionaug.augment.motion.batch import pad_batch
from motionaug.augment.motion.features import Normalizer
from motionaug.models.text_encoder import TextEncoder
from motionaug.schemas.errors import MotionDataError

NO_LABEL = -1
HELD_OUT_FRACTION = 0.2  # used only when a corpus has no train/test split files


@dataclass(frozen=True)
class MotionSet:
    """A split in memory: normalised motions, caption indices into ``text_embed``, label indices (-1 = none)."""

    ids: list[str]
    motions: list[Tensor]  # each (T_i, D), normalised float32
    captions: list[list[int]]  # per clip: rows of text_embed / texts
    texts: list[str]  # distinct captions
    text_embed: Tensor  # (n_texts, E)
    content: Tensor  # (N,) long, NO_LABEL where unknown
    style: Tensor  # (N,) long
    content_labels: list[str]
    style_labels: list[str]

    def __len__(self) -> int:
        return len(self.motions)

    @property
    def lengths(self) -> Tensor:
        return torch.tensor([m.shape[0] for m in self.motions])


@dataclass(frozen=True)
class Batch:
    """Padded motions ``(B, T, D)``, frame mask ``(B, T)`` (True = real), text embeddings ``(B, E)``, labels."""

    motion: Tensor
    mask: Tensor
    text_embed: Tensor
    content: Tensor
    style: Tensor
    index: Tensor  # (B,) rows of the MotionSet

    def to(self, device: torch.device) -> Batch:
        """The batch on ``device`` (itself when already there): drawn on CPU, trained on where the model is."""
        return Batch(*(getattr(self, f.name).to(device) for f in fields(self)))


def split_ids(corpus_dir: str | Path, split: str) -> list[str]:
    """Ids of ``train`` or ``test`` (or any split file). Without train/test files, a stable hash split of all ids."""
    root = Path(corpus_dir)
    if (root / f"{split}.txt").is_file():
        return HumanML3DReader(root, split=split, feature_dim=None).ids()
    if split not in ("train", "test"):
        raise MotionDataError(str(root / f"{split}.txt"), "split file is missing")
    every = HumanML3DReader(root, split="all" if (root / "all.txt").is_file() else None, feature_dim=None).ids()
    return [i for i in every if _held_out(i) == (split == "test")]


def _held_out(clip_id: str) -> bool:
    """A clip's side of the fallback split, from a hash of its id: stable across runs and machines."""
    digest = hashlib.sha256(clip_id.encode("utf-8")).digest()
    return int.from_bytes(digest[:4], "big") / 2**32 < HELD_OUT_FRACTION


def read_clips(corpus_dir: str | Path, ids: Sequence[str]) -> list[MotionClip]:
    """The clips with these ids, in that order (HumanML3D folder; captions with spans are not cut)."""
    clips, missing = Corpus(corpus_dir, split_spans=False).load(ids, files=ids)
    if missing:
        reason = f"{len(missing)} listed clips unreadable or missing, e.g. {missing[0].id!r} ({missing[0].reason})"
        raise MotionDataError(str(corpus_dir), reason)
    return clips


def label_lists(clips: Sequence[MotionClip]) -> tuple[list[str], list[str]]:
    """Sorted distinct content and style labels present in ``clips``."""
    contents = sorted({c.content for c in clips if c.content})
    styles = sorted({c.style for c in clips if c.style})
    return contents, styles


def _indices(values: Sequence[str | None], labels: Sequence[str]) -> Tensor:
    lookup = {name: i for i, name in enumerate(labels)}
    return torch.tensor([lookup.get(v, NO_LABEL) if v else NO_LABEL for v in values], dtype=torch.long)


def build_motion_set(
    clips: Sequence[MotionClip],
    normalizer: Normalizer,
    text_encoder: TextEncoder | None,
    content_labels: Sequence[str] | None = None,
    style_labels: Sequence[str] | None = None,
) -> MotionSet:
    """Normalise every clip and embed each distinct caption once (no encoder: empty (0, 0) embeddings).

    The set stays in CPU memory whatever device the text encoder runs on; batches move to the model's device.
    """
    if not clips:
        raise MotionDataError("training data", "no clips in the split")
    where: dict[str, int] = {}
    captions: list[list[int]] = []
    for clip in clips:
        if not clip.captions:
            raise MotionDataError(clip.source or clip.id, "clip has no captions")
        captions.append([where.setdefault(c.text, len(where)) for c in clip.captions])
    texts = list(where)
    embed = text_encoder.encode(texts).float().cpu() if text_encoder is not None else torch.zeros(len(texts), 0)
    if content_labels is None or style_labels is None:
        content_labels, style_labels = label_lists(clips)
    motions = [torch.from_numpy(np.ascontiguousarray(normalizer.normalize(c.motion), dtype=np.float32)) for c in clips]
    return MotionSet(
        ids=[c.id for c in clips],
        motions=motions,
        captions=captions,
        texts=texts,
        text_embed=embed,
        content=_indices([c.content for c in clips], content_labels),
        style=_indices([c.style for c in clips], style_labels),
        content_labels=list(content_labels),
        style_labels=list(style_labels),
    )


def _crop(motion: Tensor, max_frames: int, generator: torch.Generator | None) -> Tensor:
    """A random window of at most ``max_frames`` (the first one when no generator is given)."""
    extra = motion.shape[0] - max_frames
    if extra <= 0:
        return motion
    start = 0 if generator is None else int(torch.randint(0, extra + 1, (1,), generator=generator))
    return motion[start : start + max_frames]


def collate(data: MotionSet, index: Tensor, max_frames: int, generator: torch.Generator | None = None) -> Batch:
    """Crop, pad and caption the clips at ``index``; with a generator the crop and caption are random,
    without one they are the first window and the first caption (evaluation)."""
    motion, mask = pad_batch([_crop(data.motions[int(i)], max_frames, generator) for i in index])
    picks = []
    for i in index:
        options = data.captions[int(i)]
        choice = 0 if generator is None else int(torch.randint(0, len(options), (1,), generator=generator))
        picks.append(options[choice])
    text = data.text_embed[torch.tensor(picks, dtype=torch.long)]
    return Batch(motion, mask, text, data.content[index], data.style[index], index)


def sample_batch(
    data: MotionSet,
    batch_size: int,
    max_frames: int,
    generator: torch.Generator,
    bucket: int | None = None,
    weights: Tensor | None = None,
) -> Batch:
    """``batch_size`` clips drawn with replacement, each randomly cropped and captioned.

    ``bucket``: draw them from ``bucket`` clips of neighbouring length (around a drawn one), so a batch wastes
    little compute on padding. Near-uniform per clip; clips at the length extremes come up a little more often,
    as windows are shifted to fit inside the length ranking. ``weights`` (one per clip, any scale): draw clips in
    proportion to them instead of uniformly (:func:`share_weights`), the anchor too; with ``bucket`` that holds
    where the weights are spread over lengths (an expansion's clips keep their sources' lengths). None keeps the
    uniform draws bit for bit.
    """
    if weights is None:
        return _sample_uniform(data, batch_size, max_frames, generator, bucket)
    if bucket is None or bucket >= len(data):
        index = torch.multinomial(weights, batch_size, replacement=True, generator=generator)
    else:
        by_length = torch.argsort(data.lengths, stable=True)
        rank = int(torch.argsort(by_length)[torch.multinomial(weights, 1, generator=generator)])
        first = min(max(rank - bucket // 2, 0), len(data) - bucket)
        window = by_length[first : first + bucket]
        index = window[torch.multinomial(weights[window], batch_size, replacement=True, generator=generator)]
    return collate(data, index, max_frames, generator)


def _sample_uniform(
    data: MotionSet, batch_size: int, max_frames: int, generator: torch.Generator, bucket: int | None
) -> Batch:
    if bucket is None or bucket >= len(data):
        index = torch.randint(0, len(data), (batch_size,), generator=generator)
    else:
        by_length = torch.argsort(data.lengths, stable=True)
        anchor = int(torch.randint(0, len(data), (1,), generator=generator))
        first = min(max(anchor - bucket // 2, 0), len(data) - bucket)
        index = by_length[first + torch.randint(0, bucket, (batch_size,), generator=generator)]
    return collate(data, index, max_frames, generator)


def share_weights(ids: Sequence[str], added: Iterable[str], share: float) -> Tensor:
    """Per-clip draw weights giving the ``added`` clips ``share`` of the draws and the others the rest, each
    group uniform within itself. Why: an expansion adds several stylized clips per original, so uniform draws
    would dilute the original clips (and their content) by that factor."""
    added = set(added)
    is_added = torch.tensor([i in added for i in ids], dtype=torch.bool)
    n_added = int(is_added.sum())
    if n_added in (0, len(ids)):
        raise MotionDataError("added_share", f"needs both added and original train clips ({n_added} of {len(ids)})")
    return torch.where(is_added, share / n_added, (1 - share) / (len(ids) - n_added)).double()


def iter_batches(data: MotionSet, batch_size: int, max_frames: int) -> Iterator[Batch]:
    """Every clip once, in order, first window and first caption: for evaluation."""
    for start in range(0, len(data), batch_size):
        yield collate(data, torch.arange(start, min(start + batch_size, len(data))), max_frames)
