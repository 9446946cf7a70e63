"""Does an expansion help a text-to-motion model? The protocol's pieces (issue 22).

Three training sets are compared: (A) a base corpus that lacks some styles the way HumanML3D does
(``split_by_style``), (B) A expanded by a motionaug run (``motionaug export`` writes it) and (C) A plus
the true stylized clips (``true_stylized`` + ``merge_clips``), the upper bound. The same prior is pre-trained
on each and ``score_prior`` samples every held-out caption and judges the motion with evaluators (classifiers,
motion encoder) trained on a separate corpus, so no compared prior shaped its own judge.
"""

from __future__ import annotations

import re
import shutil
import uuid
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field

from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.corpus.humanml3d import ADDED_SPLIT, write_humanml3d
from motionaug.augment.diffusion import bind_model, ddim_sample
from motionaug.augment.eval.evaluation import Classifiers, load_classifiers
from motionaug.augment.eval.protocol import take_of
from motionaug.augment.io import atomic_save_npy, atomic_write_text
from motionaug.augment.metrics import diversity, frechet_distance, retrieval_r_at_k
from motionaug.augment.motion.features import Normalizer, compute_mean_std
from motionaug.augment.training.base_models import BaseModels
from motionaug.augment.training.data import MotionSet, build_motion_set, iter_batches, read_clips, split_ids
from motionaug.augment.training.evaluators import classifier_features, classifier_logits
from motionaug.augment.training.pretrain import joints_of, skeleton_for
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.styles import StyleWords

SPLIT_JSON = "split.json"
BASE_DIR, HELD_OUT_DIR, EXAMPLES_DIR = "base", "held_out", "examples"
EXPAND_SPLIT = "expand"  # split file of the base corpus: the clips an expansion run stylizes
GROUPS = ("neutral", "present", "style_prompted")
FMD_DIMS = 16  # FMD on the top principal components: a held-out set has fewer clips than the features' width
RETRIEVAL_POOL = 32


class StyleSplit(BaseModel):
    """What ``split_by_style`` wrote (``split.json``): which styles the base lacks and where everything is."""

    model_config = ConfigDict(extra="forbid")

    version: int = 1
    corpus: str
    neutral: str
    missing: list[str]
    present: list[str]
    examples: dict[str, dict[str, str]] = Field(description="style -> id, path (relative .npy), description")
    expand_ids: list[str]
    base_splits: dict[str, int]
    held_out: dict[str, int] = Field(description="held-out clips per group (neutral / present / style_prompted)")
    dropped_for_captions: int = 0
    judge_ids: list[str] = Field(
        default_factory=list,
        description="the missing styles' train clips set aside for the judge: neither C nor the examples use them",
    )

    @classmethod
    def read(cls, folder: str | Path) -> StyleSplit:
        path = Path(folder) / SPLIT_JSON
        if not path.is_file():
            raise MotionDataError(str(path), "file not found (make it with `motionaug expansion split`)")
        return cls.model_validate_json(path.read_text(encoding="utf-8"))


# ---- A: the base corpus ----------------------------------------------------------------------------------


def style_pattern(styles: Iterable[str], words: Mapping[str, StyleWords] | None = None) -> re.Pattern[str]:
    """Whole-word matcher for every way a caption can name these styles (their name when no words are known)."""
    forms: set[str] = set()
    for style in styles:
        known = (words or {}).get(style)
        forms.update(known.forms() if known else [style])
    alternatives = "|".join(re.escape(f) for f in sorted(forms, key=len, reverse=True))
    return re.compile(rf"\b(?:{alternatives})\b", re.IGNORECASE)


def group_of(style: str | None, neutral: str, missing: Sequence[str]) -> str:
    """The evaluation group of a held-out clip: its captions are neutral, name a kept style, or a missing one."""
    if style in missing:
        return "style_prompted"
    return "neutral" if style == neutral else "present"


def _check_styles(clips: Sequence[MotionClip], missing: Sequence[str], neutral: str, where: str) -> list[str]:
    styles = sorted({c.style for c in clips if c.style})
    unknown = [s for s in missing if s not in styles]
    if not missing or unknown or neutral in missing:
        reason = f"missing styles {list(missing)} must be labelled styles other than {neutral!r}; corpus has {styles}"
        raise MotionDataError(where, reason)
    if neutral not in styles:
        raise MotionDataError(where, f"no clip is labelled {neutral!r} (the neutral style); styles: {styles}")
    return [s for s in styles if s not in missing]


def _pick_examples(clips: Sequence[MotionClip], missing: Sequence[str], content: str | None) -> dict[str, MotionClip]:
    """One train clip per missing style (of ``content`` where the style has one): the run's only look at it."""
    picked: dict[str, MotionClip] = {}
    for style in missing:
        pool = [c for c in clips if c.style == style]
        preferred = [c for c in pool if c.content == content] or pool
        if not preferred:
            raise MotionDataError(f"style {style!r}", "no train-split clip to take the expansion's example from")
        picked[style] = min(preferred, key=lambda c: c.id)
    return picked


def judge_half(clips: Sequence[MotionClip], missing: Sequence[str]) -> set[str]:
    """The judge's half of the missing styles' train takes: per (style, content), the takes in id order go to C's
    half and the judge's in turn, so both halves hold every content and C's holds each first take (the example's).
    A cut take's pieces stay together (``take_of``)."""
    takes: dict[tuple[str, str | None], set[str]] = {}
    for clip in clips:
        if clip.style in missing:
            takes.setdefault((clip.style, clip.content), set()).add(take_of(clip.id))
    judge_takes = {t for group in takes.values() for t in sorted(group)[1::2]}
    return {c.id for c in clips if c.style in missing and take_of(c.id) in judge_takes}


def split_by_style(
    corpus: str | Path,
    out: str | Path,
    missing: Sequence[str],
    neutral: str = "neutral",
    n_expand: int | None = None,
    seed: int = 0,
    example_content: str | None = "walk",
    words: Mapping[str, StyleWords] | None = None,
    halves: bool = False,
) -> StyleSplit:
    """Split a labelled corpus into a base corpus lacking ``missing`` (motions and captions), a held-out set
    (the corpus's test split, every style) and one example clip per missing style (train split, outside the base).

    The base keeps the corpus's splits, adds an ``expand`` split (``n_expand`` of its neutral train clips, or all,
    for the expansion run to stylize) and gets Mean/Std from its own train split. With ``halves`` the missing
    styles' train takes are split in two (``judge_half``): C and the examples use one half, the judge trains on the
    other, so the judge never saw a clip C adds or an example B learnt from.
    """
    corpus, root = Path(corpus), Path(out)
    if root.exists() and any(root.iterdir()):
        raise MotionDataError(str(root), "folder is not empty; the split is written into a new or empty folder")
    split_of = {i: name for name in ("train", "val", "test") for i in split_ids(corpus, name)}
    clips = read_clips(corpus, list(split_of))
    present = _check_styles(clips, missing, neutral, str(corpus))
    named = style_pattern(missing, words)
    for clip in clips:
        clip.meta = {**clip.meta, "split": split_of[clip.id]}
    held = [c for c in clips if split_of[c.id] == "test"]
    train = [c for c in clips if split_of[c.id] == "train"]
    judge_ids = judge_half(train, missing) if halves else set()
    examples = _pick_examples([c for c in train if c.id not in judge_ids], missing, example_content)
    kept = [c for c in clips if c.style not in missing and split_of[c.id] != "test"]
    base = [c for c in kept if not any(named.search(cap.text) for cap in c.captions)]
    base += [c for c in held if c.style not in missing and not any(named.search(cap.text) for cap in c.captions)]
    splits = {s: [c.id for c in base if split_of[c.id] == s] for s in ("train", "val", "test")}
    neutral_train = [c.id for c in base if c.style == neutral and split_of[c.id] == "train"]
    expand = neutral_train
    if n_expand is not None and n_expand < len(neutral_train):
        chosen = np.random.default_rng([seed, 22]).choice(len(neutral_train), n_expand, replace=False)
        expand = [neutral_train[i] for i in sorted(chosen.tolist())]
    root.mkdir(parents=True, exist_ok=True)
    _write_corpus(base, root / BASE_DIR, {**splits, EXPAND_SPLIT: expand})
    write_humanml3d(held, root / HELD_OUT_DIR, splits={"test": [c.id for c in held]})
    result = StyleSplit(
        corpus=str(corpus),
        neutral=neutral,
        missing=list(missing),
        present=present,
        examples=_write_examples(examples, root / EXAMPLES_DIR),
        expand_ids=expand,
        base_splits={k: len(v) for k, v in splits.items()},
        held_out={g: sum(group_of(c.style, neutral, missing) == g for c in held) for g in GROUPS},
        dropped_for_captions=len(kept) + sum(c.style not in missing for c in held) - len(base),
        judge_ids=sorted(judge_ids),
    )
    atomic_write_text(root / SPLIT_JSON, result.model_dump_json(indent=1) + "\n")
    return result


def _write_examples(examples: Mapping[str, MotionClip], folder: Path) -> dict[str, dict[str, str]]:
    """Each example's features as ``<style>.npy`` (a run's style example source) with its first caption."""
    folder.mkdir(parents=True, exist_ok=True)
    out = {}
    for style, clip in examples.items():
        atomic_save_npy(folder / f"{style}.npy", clip.motion.astype(np.float32))
        text = clip.captions[0].text if clip.captions else f"a person moves {clip.style}"
        out[style] = {"id": clip.id, "path": f"{folder.name}/{style}.npy", "description": text}
    return out


def _write_corpus(clips: Sequence[MotionClip], root: Path, splits: dict[str, list[str]]) -> None:
    """HumanML3D folder with Mean/Std of its train split, written beside ``root`` and renamed into place."""
    tmp = root.with_name(f".{root.name}.{uuid.uuid4().hex[:12]}.tmp")
    try:
        write_humanml3d(clips, tmp, splits=splits)
        train = set(splits.get("train", []))
        compute_mean_std([c.motion for c in clips if c.id in train]).save(tmp)
        if root.exists():
            shutil.rmtree(root)
        tmp.rename(root)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


# ---- C: the base plus the true stylized clips ---------------------------------------------------------------


def true_stylized(split_dir: str | Path, mode: Literal["auto", "rerender", "corpus"] = "auto") -> Iterator[MotionClip]:
    """The upper bound's extra clips, all in the train split.

    ``rerender`` (synthetic corpora, whose clips carry their render spec): each ``expand`` clip rendered in each
    missing style, so C holds the same (source, style) pairs an expansion run makes, only true.
    ``corpus``: the labelled corpus's own train clips of the missing styles (real data, e.g. Bandai-2's takes),
    without the judge's half where the split set one aside.
    """
    root = Path(split_dir)
    split = StyleSplit.read(root)
    sources = read_clips(root / BASE_DIR, split.expand_ids)
    if mode == "auto":
        mode = "rerender" if sources and "spec" in sources[0].meta else "corpus"
    if mode == "rerender":
        yield from _rerendered(sources, split.missing)
        return
    corpus = Path(split.corpus)
    train = read_clips(corpus, split_ids(corpus, "train"))
    judge = set(split.judge_ids)
    yield from (_as_train(c) for c in train if c.style in split.missing and c.id not in judge)


def judge_clips(split_dir: str | Path) -> list[MotionClip]:
    """The missing styles' train clips the split set aside for the judge (empty without ``halves``)."""
    split = StyleSplit.read(split_dir)
    return [_as_train(c) for c in read_clips(Path(split.corpus), split.judge_ids)]


def _as_train(clip: MotionClip) -> MotionClip:
    clip.meta = {**clip.meta, "split": "train"}
    return clip


def _rerendered(sources: Sequence[MotionClip], styles: Sequence[str]) -> Iterator[MotionClip]:
    from motionaug.augment.synth import restyled

    for clip in sources:
        for style in styles:
            out = restyled(clip, style)
            out.meta = {**out.meta, "split": "train", "source_id": clip.id}
            yield out


def run_clips(run_dir: str | Path) -> Iterator[MotionClip]:
    """Every stylized clip of a finished run (shards verified against its manifest), as train clips: the run read
    only A's ``expand`` clips, which are train clips."""
    from motionaug.augment.outputs.run_dir import RunDir
    from motionaug.augment.outputs.shards import iter_shard_rows, row_clip
    from motionaug.augment.outputs.verify import verified_shards

    run = Path(run_dir)
    for row in iter_shard_rows(run, files=verified_shards(RunDir(run))):
        yield row_clip(row, f"motionaug run {run.name}", {})


def merge_clips(base: str | Path, extra: Iterable[MotionClip], out: str | Path) -> dict[str, int]:
    """``base`` (all its splits) plus ``extra`` clips in its train split, as a new HumanML3D folder; returns the
    split sizes. Mean/Std come from the merged train split, and ``added.txt`` lists the extra clips, as
    ``motionaug export`` does for an expanded corpus."""
    base, root = Path(base), Path(out)
    if root.exists() and any(root.iterdir()):
        raise MotionDataError(str(root), "folder is not empty; the merged corpus is written into a new folder")
    splits = {s: split_ids(base, s) for s in ("train", "val", "test") if (base / f"{s}.txt").is_file()}
    clips = read_clips(base, [i for ids in splits.values() for i in ids])
    added = list(extra)
    if not added:
        raise MotionDataError(str(base), "nothing to merge: no extra clips")
    splits["train"] = splits.get("train", []) + [c.id for c in added]
    splits[ADDED_SPLIT] = [c.id for c in added]
    _write_corpus([*clips, *added], root, splits)
    return {k: len(v) for k, v in splits.items()}


# ---- scoring ------------------------------------------------------------------------------------------------


@torch.no_grad()
def generate(
    models: BaseModels, data: MotionSet, scale: float | None, steps: int, batch_size: int, seed: int
) -> MotionSet:
    """A MotionSet of generated (normalised) motions for each clip's first caption at its length."""
    generator = torch.Generator().manual_seed(seed)
    out: list[torch.Tensor] = []
    for batch in iter_batches(data, batch_size, models.info.max_frames):
        model_fn = bind_model(models.prior, batch.text_embed, batch.mask)
        with torch.autocast("cpu", dtype=torch.bfloat16):
            sample = ddim_sample(model_fn, batch.motion.shape, steps=steps, guidance_scale=scale, generator=generator)
        out.extend(sample[i, : int(batch.mask[i].sum())].float() for i in range(sample.shape[0]))
    return _with_motions(data, out, [[c[0]] for c in data.captions])


def _with_motions(data: MotionSet, motions: list[torch.Tensor], captions: list[list[int]] | None = None) -> MotionSet:
    return MotionSet(
        ids=data.ids,
        motions=motions,
        captions=captions or data.captions,
        texts=data.texts,
        text_embed=data.text_embed,
        content=data.content,
        style=data.style,
        content_labels=data.content_labels,
        style_labels=data.style_labels,
    )


def one_row_per_caption(data: MotionSet, repeats: int = 1) -> MotionSet:
    """Every (clip, caption) pair as its own entry, ``repeats`` times: about three samples per held-out clip instead
    of one, times ``repeats`` draws of the sampler's noise (a recognition rate on few captions is noisy)."""
    rows = [(i, c) for i, caps in enumerate(data.captions) for c in caps for _ in range(repeats)]
    index = torch.tensor([i for i, _ in rows])
    return MotionSet(
        ids=[f"{data.ids[i]}#{c}" for i, c in rows],
        motions=[data.motions[i] for i, _ in rows],
        captions=[[c] for _, c in rows],
        texts=data.texts,
        text_embed=data.text_embed,
        content=data.content[index],
        style=data.style[index],
        content_labels=data.content_labels,
        style_labels=data.style_labels,
    )


class Judge:
    """Evaluators trained apart from every compared prior: classifiers and the motion encoder of one base folder."""

    def __init__(self, folder: str | Path) -> None:
        self.models = BaseModels.load(folder)
        self.classifiers: Classifiers = load_classifiers(folder)
        if self.classifiers.content is None or self.classifiers.style is None:
            raise MotionDataError(str(folder), "the judge needs both a content and a style classifier")

    def renormalise(self, motions: Sequence[torch.Tensor], own: Normalizer) -> list[torch.Tensor]:
        """Motions normalised with ``own`` statistics, re-expressed in the judge's."""
        mean, std = torch.from_numpy(own.mean), torch.from_numpy(own.std)
        j_mean, j_std = torch.from_numpy(self.models.normalizer.mean), torch.from_numpy(self.models.normalizer.std)
        return [((m * std + mean) - j_mean) / j_std for m in motions]

    @torch.no_grad()
    def embed(self, data: MotionSet) -> np.ndarray:
        """Motion-encoder embeddings (N, E) of judge-normalised motions."""
        out = [
            self.models.motion_encoder(b.motion, b.mask) for b in iter_batches(data, 64, self.models.info.max_frames)
        ]
        return torch.cat(out).float().numpy()


def _recognised(judge: Judge, joints: torch.Tensor, mask: torch.Tensor, data: MotionSet) -> dict[str, np.ndarray]:
    """Per row: content / style correct (NaN where the label is unknown to the judge) and style features."""
    out: dict[str, np.ndarray] = {}
    for name, model, labels in (
        ("content", judge.classifiers.content, data.content),
        ("style", judge.classifiers.style, data.style),
    ):
        pred = classifier_logits(model, joints, mask).argmax(dim=1)
        correct = (pred == labels).double().numpy()
        correct[(labels < 0).numpy()] = np.nan
        out[name] = correct
    out["features"] = classifier_features(judge.classifiers.style, joints, mask).double().numpy()
    return out


def _fmd(generated: np.ndarray, real: np.ndarray, basis: np.ndarray, mean: np.ndarray) -> float | None:
    """FMD in the leading components, as many as the smaller set allows (covariances need more samples than dims)."""
    dims = min(basis.shape[1], min(len(generated), len(real)) - 1)
    if dims < 2:
        return None
    return frechet_distance((generated - mean) @ basis[:, :dims], (real - mean) @ basis[:, :dims])


def _pca(feats: np.ndarray, dims: int) -> tuple[np.ndarray, np.ndarray]:
    mean = feats.mean(axis=0)
    _, _, vt = np.linalg.svd(feats - mean, full_matrices=False)
    return vt[: min(dims, len(vt))].T, mean


def _mean(values: np.ndarray) -> float | None:
    values = values[~np.isnan(values)]
    return float(values.mean()) if len(values) else None


def _summary(rows: np.ndarray, rec: dict, real_rows: np.ndarray, real: dict, emb: tuple, pca: tuple) -> dict:
    """Figures of one group: recognition, FMD against the group's real clips, retrieval, diversity."""
    feats = rec["features"][rows]
    motion_emb, text_emb = emb
    out: dict[str, float | int | None] = {
        "samples": int(rows.sum()),
        "content": _mean(rec["content"][rows]),
        "style": _mean(rec["style"][rows]),
        "fmd": _fmd(feats, real["features"][real_rows], *pca),
        "diversity": diversity(feats, n_pairs=min(300, len(feats)), seed=0) if len(feats) >= 2 else None,
        "real_content": _mean(real["content"][real_rows]),
        "real_style": _mean(real["style"][real_rows]),
    }
    for k in (1, 3):
        enough = len(feats) >= RETRIEVAL_POOL
        out[f"r{k}"] = (
            retrieval_r_at_k(motion_emb[rows], text_emb[rows], k=k, pool=RETRIEVAL_POOL, seed=0) if enough else None
        )
    return out


def score_prior(
    prior_dir: str | Path,
    held_out: str | Path,
    judge: Judge | str | Path,
    missing: Sequence[str],
    neutral: str = "neutral",
    guidance: float = 3.0,
    steps: int = 20,
    seed: int = 0,
    batch_size: int = 50,
    samples: int = 1,
    groups: Sequence[str] | None = None,
) -> dict[str, dict]:
    """Sample every caption of every held-out clip ``samples`` times with the prior at ``prior_dir`` and judge the
    motion.

    Returns figures per group (``neutral`` captions, captions naming a ``present`` style, ``style_prompted``
    captions naming a missing style) and ``all``: content and style recognition by the judge's classifiers
    (``real_*``: the same on the real clips, the judge's ceiling), FMD (on the judge's style features, top
    principal components of the real held-out clips) against the group's real clips, text-to-motion R@1/R@3 of
    the judge's motion encoder in pools of 32, and diversity. ``groups`` scores only the held-out clips of those
    groups: a group's recognition figures do not depend on the others (FMD's basis does), so a target on one group
    can be measured with many ``samples`` at the cost of one full scoring.
    """
    judge = judge if isinstance(judge, Judge) else Judge(judge)
    models = BaseModels.load(prior_dir, text_encoder=judge.models.text_encoder)
    if models.info.text_encoder != judge.models.info.text_encoder:
        reason = f"text encoder {models.info.text_encoder!r}, the judge's is {judge.models.info.text_encoder!r}"
        raise MotionDataError(str(prior_dir), reason)
    labels = (judge.classifiers.content_labels, judge.classifiers.style_labels)
    clips = read_clips(held_out, split_ids(held_out, "test"))
    if groups is not None:
        clips = [c for c in clips if group_of(c.style, neutral, missing) in groups]
    data = build_motion_set(clips, models.normalizer, models.text_encoder, *labels)
    rows = one_row_per_caption(data, samples)
    generated = generate(models, rows, guidance or None, steps, batch_size, seed)
    skeleton = skeleton_for(models.normalizer.dim)
    frames = models.info.max_frames
    rec = _recognised(judge, *joints_of(generated, models.normalizer, skeleton, frames), generated)
    real = _recognised(judge, *joints_of(data, models.normalizer, skeleton, frames), data)
    in_judge = _with_motions(generated, judge.renormalise(generated.motions, models.normalizer))
    text_emb = generated.text_embed[[c[0] for c in generated.captions]].float().numpy()
    emb = (judge.embed(in_judge), text_emb)
    pca = _pca(real["features"], FMD_DIMS)
    clip_group = np.array([group_of(c.style, neutral, missing) for c in clips])
    owner = {cid: k for k, cid in enumerate(data.ids)}
    row_group = np.array([clip_group[owner[r.rsplit("#", 1)[0]]] for r in rows.ids])
    figures: dict[str, dict] = {}
    for group in (*GROUPS, "all") if groups is None else groups:
        sel = row_group == group if group != "all" else np.ones(len(row_group), bool)
        real_sel = clip_group == group if group != "all" else np.ones(len(clip_group), bool)
        if sel.any():
            figures[group] = _summary(sel, rec, real_sel, real, emb, pca)
    return figures


def gain_share(a: float | None, b: float | None, c: float | None) -> float | None:
    """B's gain over A as a share of C's gain over A (1 = as good as the true clips); None when C gains nothing."""
    if a is None or b is None or c is None or abs(c - a) < 1e-9:
        return None
    return (b - a) / (c - a)


def mean_figures(runs: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """The mean of ``score_prior``'s figures over priors trained with different seeds, key by key (nested dicts
    alike); a figure missing (None) from any run is None. One prior's figures on ~100 captions move by several
    points with its training seed, more than the protocol's 3-point content target, so its figures are means."""
    out: dict[str, Any] = {}
    for key, first in runs[0].items():
        values = [run[key] for run in runs]
        if isinstance(first, Mapping):
            out[key] = mean_figures(values)
        elif isinstance(first, int | float) and not isinstance(first, bool):
            out[key] = None if any(v is None for v in values) else float(np.mean(values))
        else:
            out[key] = None if any(v is None for v in values) else first
    return out
