"""``generate_corpus``: the synthetic style corpus written in the HumanML3D layout, plus labels.

Output folder: ``new_joint_vecs/``, ``texts/``, ``train/val/test/all.txt``, ``Mean.npy``/``Std.npy``
(from the train split) and ``labels.jsonl`` (id, split, content, style, intensity, spec) so any clip
can be re-rendered, or rendered again in another style, later. The same seed gives the same bytes.
"""

from __future__ import annotations

import json
import time
from collections import Counter
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict

from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.synth.animator import ClipSpec, render, sample_spec
from motionaug.augment.synth.captions import make_captions
from motionaug.augment.synth.contents import CONTENTS
from motionaug.augment.synth.styles import STYLES
from motionaug.schemas.errors import MotionDataError

SPLIT_FRACTIONS = (("train", 0.8), ("val", 0.1), ("test", 0.1))
SOURCE = "synth"


class CorpusSummary(BaseModel):
    """What ``generate_corpus`` wrote. ``seconds`` is wall time (not written to disk)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    out_dir: str
    n_clips: int
    seed: int
    splits: dict[str, int]
    styles: dict[str, int]
    contents: dict[str, int]
    frames: int
    seconds: float


def _check_names(names: Sequence[str] | None, known: dict, what: str) -> list[str]:
    chosen = list(known) if names is None else list(names)
    unknown = [n for n in chosen if n not in known]
    if unknown or not chosen:
        reason = f"unknown or empty: {unknown or chosen}; known: {sorted(known)}"
        raise MotionDataError(f"synthetic corpus {what}", reason)
    return chosen


def plan_specs(
    n_clips: int,
    seed: int,
    styles: Sequence[str] | None = None,
    contents: Sequence[str] | None = None,
    neutral_fraction: float = 0.4,
) -> list[ClipSpec]:
    """Balanced, shuffled (content, style) mix: ``neutral_fraction`` neutral, the rest spread evenly.

    Contents and styles are each balanced and paired by independent shuffles, so every pair occurs.
    """
    if n_clips < 1:
        raise MotionDataError("synthetic corpus", f"n_clips must be >= 1, got {n_clips}")
    if not 0.0 <= neutral_fraction <= 1.0:
        raise MotionDataError("synthetic corpus", f"neutral_fraction {neutral_fraction} outside [0, 1]")
    style_names = _check_names(styles, STYLES, "styles")
    content_names = _check_names(contents, CONTENTS, "contents")
    styled = [s for s in style_names if s != "neutral"]
    n_neutral = n_clips if not styled else (round(n_clips * neutral_fraction) if "neutral" in style_names else 0)
    style_list = ["neutral"] * n_neutral + [styled[i % len(styled)] for i in range(n_clips - n_neutral)]
    content_list = [content_names[i % len(content_names)] for i in range(n_clips)]
    rng = np.random.default_rng(seed)
    style_order = rng.permutation(n_clips)
    content_order = rng.permutation(n_clips)
    return [
        sample_spec(rng, content_list[int(c)], style_list[int(s)], seed=int(seed) * 1_000_003 + i)
        for i, (c, s) in enumerate(zip(content_order, style_order))
    ]


def assign_splits(ids: list[str], seed: int) -> dict[str, list[str]]:
    """Deterministic ~80/10/10 train/val/test split of ids (each list kept in id order)."""
    order = np.random.default_rng([seed, 1]).permutation(len(ids))
    n_train = round(len(ids) * SPLIT_FRACTIONS[0][1])
    n_val = round(len(ids) * SPLIT_FRACTIONS[1][1])
    bounds = {"train": order[:n_train], "val": order[n_train : n_train + n_val], "test": order[n_train + n_val :]}
    return {name: [ids[i] for i in sorted(idx.tolist())] for name, idx in bounds.items()}


def clip_id(index: int) -> str:
    return f"{index:06d}"


def spec_to_clip(spec: ClipSpec, clip_id_: str) -> MotionClip:
    """Render one spec and extract its HumanML3D features; the spec goes in ``meta['spec']``."""
    from motionaug.augment.motion.features import extract_features

    rendered = render(spec)
    motion = extract_features(rendered.joints, source=f"synthetic clip {clip_id_}")
    return MotionClip(
        id=clip_id_,
        motion=motion,
        captions=make_captions(spec),
        fps=spec.fps,
        content=spec.content,
        style=spec.style,
        source=SOURCE,
        meta={"spec": spec.to_json()},
    )


def restyled(clip: MotionClip, style: str) -> MotionClip:
    """The clip's synthetic motion (its ``meta['spec']``) rendered in ``style``: the same content, path, duration,
    bones and phase frame for frame, so the pair is ground truth for a transfer. Id ``<id>_<style>``."""
    raw = (clip.meta or {}).get("spec")
    if not isinstance(raw, str) or not raw:
        raise MotionDataError(f"clip {clip.id}", "no synthetic motion spec (meta 'spec') to render in another style")
    try:
        spec = ClipSpec.from_json(raw).with_style(style)
    except (MotionDataError, ValueError) as err:
        raise MotionDataError(f"clip {clip.id}", f"cannot render in style {style!r}: {err}".splitlines()[0]) from None
    return spec_to_clip(spec, f"{clip.id}_{style}")


def generate_corpus(
    out_dir: str | Path,
    n_clips: int,
    seed: int = 0,
    styles: Sequence[str] | None = None,
    contents: Sequence[str] | None = None,
    neutral_fraction: float = 0.4,
) -> CorpusSummary:
    """Render ``n_clips`` synthetic clips into a HumanML3D folder with Mean/Std and labels.jsonl."""
    from motionaug.augment.corpus.humanml3d import write_humanml3d
    from motionaug.augment.motion.features import compute_mean_std

    start = time.perf_counter()
    root = Path(out_dir)
    if root.exists() and any(root.iterdir()):
        raise MotionDataError(str(root), "folder is not empty; a corpus is written into a new or empty folder")
    specs = plan_specs(n_clips, seed, styles, contents, neutral_fraction)
    ids = [clip_id(i) for i in range(len(specs))]
    splits = assign_splits(ids, seed)
    split_of = {cid: name for name, members in splits.items() for cid in members}
    train_features: list[np.ndarray] = []
    frames = 0

    def clips() -> Iterator[MotionClip]:
        nonlocal frames
        for cid, spec in zip(ids, specs):
            clip = spec_to_clip(spec, cid)
            clip.meta["split"] = split_of[cid]
            frames += clip.n_frames
            if split_of[cid] == "train":
                train_features.append(clip.motion)
            yield clip

    write_humanml3d(clips(), root, splits=splits)
    compute_mean_std(train_features).save(root)
    return CorpusSummary(
        out_dir=str(root),
        n_clips=len(specs),
        seed=seed,
        splits={k: len(v) for k, v in splits.items()},
        styles=dict(Counter(s.style for s in specs)),
        contents=dict(Counter(s.content for s in specs)),
        frames=frames,
        seconds=time.perf_counter() - start,
    )


def read_labels(root: str | Path) -> list[dict]:
    """Per clip: id, split, content, style, intensity and spec (dict), from the corpus's labels sidecar."""
    from motionaug.augment.corpus.humanml3d import LABELS_FILE
    from motionaug.augment.corpus.humanml3d import read_labels as read_sidecar

    records = read_sidecar(Path(root))
    if not records:
        raise MotionDataError(str(Path(root) / LABELS_FILE), "file not found (not a synthetic corpus?)")
    out = []
    for clip_id_, record in records.items():
        spec = json.loads(record["meta"]["spec"])
        out.append(
            {
                "id": clip_id_,
                "split": record["meta"].get("split"),
                "content": record["content"],
                "style": record["style"],
                "intensity": spec["intensity"],
                "spec": spec,
            }
        )
    return out


def pooled_descriptor(features: np.ndarray) -> np.ndarray:
    """Fixed-length clip summary for quick classifiers: mean, std and mean |x| over time per channel."""
    x = np.asarray(features, dtype=np.float64)
    return np.concatenate([x.mean(axis=0), x.std(axis=0), np.abs(x).mean(axis=0)])


def linear_probe_predict(
    x_train: np.ndarray, y_train: Sequence[str], x_test: np.ndarray, ridge: float = 10.0
) -> np.ndarray:
    """Labels a ridge classifier (least squares onto one-hot labels, z-scored inputs) gives ``x_test``.

    A deliberately simple linear probe: if it separates the styles, a learned model can.
    """
    mean, std = x_train.mean(axis=0), x_train.std(axis=0) + 1e-6
    a = np.hstack([(x_train - mean) / std, np.ones((len(x_train), 1))])
    b = np.hstack([(x_test - mean) / std, np.ones((len(x_test), 1))])
    classes = np.asarray(sorted(set(y_train)))
    onehot = (np.asarray(y_train)[:, None] == classes[None, :]).astype(np.float64)
    dual = np.linalg.solve(a @ a.T + ridge * np.eye(len(a)), onehot)  # (n_train, classes), dual form
    return classes[np.argmax(b @ (a.T @ dual), axis=1)]
