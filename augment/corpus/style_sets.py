"""Styles that are one way of moving under several names, and removing a style from a corpus through them.

A style held out of training must be absent from every corpus a model trains on, under any of its names: Bandai
dataset-1's ``old`` is dataset-2's ``elderly`` and the synthetic corpus's ``old``. The table is written once here
and every filter goes through it.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.corpus.corpus import Corpus, split_of_ids
from motionaug.augment.corpus.humanml3d import write_humanml3d
from motionaug.augment.motion.features import compute_mean_std
from motionaug.schemas.errors import MotionDataError

COUNTERPARTS: tuple[frozenset[str], ...] = (
    frozenset({"old", "elderly"}),  # Bandai-1 old, Bandai-2 elderly, synthetic old
    frozenset({"tired", "exhausted"}),
    frozenset({"masculinity", "masculine"}),
    frozenset({"childish", "youthful", "childlike"}),  # Bandai-1 "children", Bandai-2, synthetic
    frozenset({"active"}),
    frozenset({"feminine"}),
    frozenset({"angry"}),  # Bandai-1 and synthetic
    frozenset({"proud"}),  # Bandai-1 and synthetic
)
"""Groups of style labels that name one way of moving across the corpora this project reads."""


def with_counterparts(styles: Iterable[str]) -> frozenset[str]:
    """``styles`` and every label the table says means the same way of moving."""
    out = set(styles)
    for group in COUNTERPARTS:
        if group & out:
            out |= group
    return frozenset(out)


def without_styles(clips: Iterable[MotionClip], styles: Iterable[str]) -> list[MotionClip]:
    """The clips whose style is neither one of ``styles`` nor a counterpart of one."""
    drop = with_counterparts(styles)
    return [c for c in clips if c.style not in drop]


def write_without_styles(corpus: Path, out: Path, styles: Sequence[str]) -> Path:
    """A HumanML3D copy of ``corpus`` without ``styles`` and their counterparts, for training a fold's models.

    Split files keep their remaining ids; Mean/Std come from the remaining train split (a normaliser is a trained
    part too), or from every remaining clip when the corpus has no train split.
    """
    if out.exists() and any(out.iterdir()):
        raise MotionDataError(str(out), "folder is not empty; a filtered corpus is written into a new folder")
    clips = without_styles(Corpus(corpus), styles)
    if not clips:
        raise MotionDataError(str(corpus), f"no clip is left without the styles {sorted(with_counterparts(styles))}")
    kept = {c.id for c in clips}
    splits = {name: [i for i in ids if i in kept] for name, ids in _split_lists(corpus).items()}
    train_ids = set(splits.get("train", [])) or kept
    mean_std = compute_mean_std(np.asarray(c.motion) for c in clips if c.id in train_ids)
    write_humanml3d(clips, out, splits=splits, mean_std=(mean_std.mean, mean_std.std), fps=clips[0].fps)
    return out


def _split_lists(corpus: Path) -> dict[str, list[str]]:
    """Each split file's ids, in file order."""
    by_split: dict[str, list[str]] = {}
    for clip_id, split in split_of_ids(corpus).items():
        by_split.setdefault(split, []).append(clip_id)
    return by_split
