"""The held-out protocol every quality figure goes through: what a method may see, and what it may not.

A method learns from the train split only (``TrainView``, which raises on any scored clip or another piece of its
take), its style examples are drawn before any test run by a seeded rule (``draw_examples``), and the clips it
transfers reach it without their labels (``blind``). A fold holds styles out of every trained part through the
written table of ``augment.corpus.style_sets``. Usable on any labelled corpus in the HumanML3D layout.
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field

from motionaug.augment.corpus import Corpus
from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.corpus.style_sets import with_counterparts
from motionaug.augment.io import atomic_write_text
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.run_config import RunConfig

_PIECE = re.compile(r"^(?P<take>.+?)(_\d{4,}_\d{4,})?$")


class ProtocolLeak(MotionDataError):
    """A scored clip, or a piece of its take, was about to reach a method."""


def take_of(clip_id: str) -> str:
    """The take a clip id belongs to: a cut take's pieces (``<take>_0000_0196``) share it."""
    match = _PIECE.match(clip_id)
    return match.group("take") if match else clip_id


class TrainView:
    """The clips a method may learn from: a split of a corpus that holds no scored take, and refuses to hand one out.

    Built with the ids that will be scored; iterating or asking for a clip of a scored take raises
    ``ProtocolLeak``, so a leaking pool or reference fails loudly instead of inflating a figure.
    """

    def __init__(self, corpus: Path, scored: Iterable[str], split: str = "train") -> None:
        self.corpus, self.split = Path(corpus), split
        self.scored_takes = frozenset(take_of(i) for i in scored)
        self._clips = {c.id: c for c in Corpus(self.corpus, split=split)}
        leaked = sorted(i for i in self._clips if take_of(i) in self.scored_takes)
        if leaked:
            raise ProtocolLeak(f"split {split}", f"holds scored takes ({', '.join(leaked[:3])})")

    def check(self, clip_id: str) -> None:
        if take_of(clip_id) in self.scored_takes:
            raise ProtocolLeak(f"clip {clip_id}", "is a scored take; no method may learn from it")

    def get(self, clip_id: str) -> MotionClip:
        self.check(clip_id)
        if clip_id not in self._clips:
            raise MotionDataError(f"clip {clip_id}", f"not in the {self.split} split")
        return self._clips[clip_id]

    def __iter__(self) -> Iterator[MotionClip]:
        return iter(self._clips.values())

    def ids(self) -> list[str]:
        return list(self._clips)

    def without_styles(self, styles: Iterable[str]) -> list[MotionClip]:
        drop = with_counterparts(styles)
        return [c for c in self if c.style not in drop]


def blind(clips: Sequence[MotionClip]) -> list[MotionClip]:
    """The clips as a method receives them when they are scored: motion and captions, no content or style label."""
    return [replace(c, content=None, style=None, meta={}) for c in clips]


def guarded(pool: Sequence[MotionClip], scored: Iterable[str]) -> list[MotionClip]:
    """``pool`` unchanged, after checking that it holds no scored take (the check every pool and reference passes)."""
    takes = {take_of(i) for i in scored}
    leaked = [c.id for c in pool if take_of(c.id) in takes]
    if leaked:
        raise ProtocolLeak("pool", f"holds scored takes ({', '.join(leaked[:3])})")
    return list(pool)


# ---- example draws ---------------------------------------------------------------------------------------------


class ExampleDraws(BaseModel):
    """Which takes teach each style, fixed before any test run: ``draws[style][d]`` is draw ``d``'s k example ids."""

    model_config = ConfigDict(extra="forbid")
    version: int = 1
    k: int
    seed: int
    prefer_content: str | None
    draws: dict[str, list[list[str]]] = Field(description="style -> draw -> example clip ids (takes disjoint)")

    def takes(self) -> set[str]:
        """Every take any draw uses (the judges train without them)."""
        return {take_of(i) for per_style in self.draws.values() for draw in per_style for i in draw}

    def write(self, path: Path) -> Path:
        atomic_write_text(path, self.model_dump_json(indent=1) + "\n")
        return path


def _rank(seed: int, style: str, take: str) -> str:
    return hashlib.sha256(f"{seed}:{style}:{take}".encode()).hexdigest()


def draw_examples(
    view: TrainView, styles: Sequence[str], k: int, n_draws: int = 3, seed: int = 0, prefer: str | None = "walk"
) -> ExampleDraws:
    """``n_draws`` draws of ``k`` example takes per style from the train view, takes disjoint across draws.

    Takes are ordered by a hash of (seed, style, take), the ``prefer`` content's takes first; a style with too few
    of them takes other contents next. One piece (the first) of each take is the example.
    """
    draws: dict[str, list[list[str]]] = {}
    for style in styles:
        first_piece: dict[str, MotionClip] = {}
        for clip in view:
            if clip.style == style:
                first_piece.setdefault(take_of(clip.id), clip)
        order = sorted(first_piece, key=lambda t: (first_piece[t].content != prefer, _rank(seed, style, t)))
        if len(order) < k * n_draws:
            raise MotionDataError(f"style {style}", f"{len(order)} train takes, {k * n_draws} needed for the draws")
        draws[style] = [[first_piece[t].id for t in order[d * k : (d + 1) * k]] for d in range(n_draws)]
    return ExampleDraws(k=k, seed=seed, prefer_content=prefer, draws=draws)


# ---- folds -----------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Fold:
    """A set of styles held out of every trained part; their counterparts in other corpora go with them."""

    name: str
    held_out: tuple[str, ...]

    def removed(self) -> frozenset[str]:
        return with_counterparts(self.held_out)


LSO_FOLDS: dict[str, tuple[Fold, ...]] = {
    "bandai2": (
        Fold("fold1", ("active", "elderly", "feminine")),
        Fold("fold2", ("exhausted", "masculine", "youthful")),
    ),
    "synthetic": (
        Fold("fold1", ("angry", "old", "sneaky", "strutting")),
        Fold("fold2", ("childlike", "depressed", "proud")),
    ),
}
"""The leave-style-out folds of the headline benchmark."""


def fold_of(corpus_kind: str, name: str) -> Fold:
    for fold in LSO_FOLDS.get(corpus_kind, ()):
        if fold.name == name:
            return fold
    raise MotionDataError(f"fold {name}", f"unknown for {corpus_kind!r}; known: {sorted(LSO_FOLDS)}")


def scored_overlap(pool_ids: Iterable[str], scored_ids: Iterable[str]) -> list[str]:
    """The scored clips whose take is in the pool (empty: the run is held out)."""
    pool_takes = {take_of(i) for i in pool_ids}
    return sorted(i for i in scored_ids if take_of(i) in pool_takes)


def split_members(corpus: Path, split: str | None) -> list[str]:
    """The ids a HumanML3D split file lists (``all.txt`` when None), without reading any motion."""
    path = Path(corpus) / f"{split or 'all'}.txt"
    if not path.is_file():
        raise MotionDataError(str(path), "split file not found")
    return [line.strip() for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]


def held_out_leaks(config: RunConfig) -> list[str]:
    """Why a run's figures would not be held out: each way a scored clip can reach its method (empty: none).

    The scored clips are the run's own (``corpus.split``); the method learns from its pool (``corpus.pool_split``,
    the run's own clips when unset), its style examples and their named references and, for methods that train,
    ``base_models.corpus``.
    """
    corpus = config.corpus.path
    scored = split_members(corpus, config.corpus.split)
    reasons = []
    if config.corpus.pool_split is None:
        reasons.append("corpus.pool_split is unset, so the method's pool is the scored clips themselves")
    else:
        overlap = scored_overlap(split_members(corpus, config.corpus.pool_split), scored)
        if overlap:
            reasons.append(f"the pool split {config.corpus.pool_split!r} holds {len(overlap)} scored takes")
    examples = [e.source for s in config.styles for e in s.examples]
    overlap = scored_overlap(examples, scored)
    if overlap:
        reasons.append(f"style examples are scored takes ({', '.join(overlap[:3])})")
    named = [e.reference for s in config.styles for e in s.examples if e.reference]
    overlap = scored_overlap(named, scored)
    if overlap:
        reasons.append(f"the examples' named references are scored takes ({', '.join(overlap[:3])})")
    trained_on = config.base_models.corpus or corpus
    if Path(trained_on).resolve() == Path(corpus).resolve() and scored_overlap(split_members(corpus, "train"), scored):
        reasons.append("the train split the method trains on holds scored takes")
    return reasons


def check_held_out(config: RunConfig) -> None:
    """Raise ``ProtocolLeak`` naming the first way a scored clip would reach the run's method."""
    reasons = held_out_leaks(config)
    if reasons:
        raise ProtocolLeak(f"run {config.output}", reasons[0])
