"""Style examples as users give them, turned into validated ``MotionClip``s before any training starts.

An example (``schemas.styles.StyleExample``) names a corpus clip id, a features ``.npy`` (T, 263) or a ``.bvh``
file (retargeted onto t2m by ``augment.motion.retarget`` and featurised by ``augment.motion.features``). Everything a
fine-tune would trip over later (too short, NaN/Inf, wrong width, unknown id, a skeleton with no joint map, a
description that never names the style) is raised here as one ``MotionDataError`` naming the example.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np

from motionaug.augment.corpus.clip import MotionClip
from motionaug.schemas.captions import Caption
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.skeleton import T2M
from motionaug.schemas.styles import StyleExample, StyleSpec, StyleWords

MIN_EXAMPLE_FRAMES = 20
EXAMPLE_SOURCE = "style-example"

CorpusLookup = Callable[[str], MotionClip | None] | Mapping[str, MotionClip] | None
"""How clip ids are resolved: a mapping id -> clip, a function returning the clip or None, or None (no corpus)."""


def check_motion(
    motion: np.ndarray, source: str, feature_dim: int = T2M.feature_dim, min_frames: int = MIN_EXAMPLE_FRAMES
) -> np.ndarray:
    """The motion as (T, D) float32, or a ``MotionDataError`` saying why it cannot be used."""
    array = np.asarray(motion)
    if array.ndim != 2:
        raise MotionDataError(source, f"motion must be (frames, {feature_dim}) features, got shape {array.shape}")
    if array.shape[1] != feature_dim:
        raise MotionDataError(source, f"motion width {array.shape[1]} != {feature_dim} features")
    if array.shape[0] < min_frames:
        raise MotionDataError(source, f"too short: {array.shape[0]} frames < {min_frames}")
    if not np.issubdtype(array.dtype, np.number):
        raise MotionDataError(source, f"motion has non-numeric dtype {array.dtype}")
    if not np.isfinite(array).all():
        raise MotionDataError(source, "motion contains NaN or Inf")
    return array.astype(np.float32, copy=False)


def describes_style(description: str, words: StyleWords) -> bool:
    """Whether a description names the style (so the neutral/stylised caption pair is meaningful)."""
    from motionaug.augment.text.caption_revision import style_word_in

    return style_word_in(description, words) is not None


def _lookup(corpus_lookup: CorpusLookup, clip_id: str) -> MotionClip | None:
    if corpus_lookup is None:
        return None
    if isinstance(corpus_lookup, Mapping):
        return corpus_lookup.get(clip_id)
    return corpus_lookup(clip_id)


def _resolve_path(source: str, root: Path | None) -> Path:
    path = Path(source).expanduser()
    return path if path.is_absolute() or root is None else root / path


def _load_npy(path: Path, label: str) -> np.ndarray:
    if not path.is_file():
        raise MotionDataError(label, f"features file {path} not found")
    try:
        return np.load(path, allow_pickle=False)
    except (ValueError, OSError) as err:
        raise MotionDataError(label, f"not a readable .npy array ({str(err).splitlines()[0]})") from None


def _load_bvh(path: Path, joint_map: str | None, root: Path | None, label: str) -> np.ndarray:
    """Retarget a BVH onto t2m joints at 20 fps and extract features; errors are re-labelled with the example."""
    from motionaug.augment.motion.features import extract_features
    from motionaug.augment.motion.retarget import load_bvh_as_t2m_joints

    if not path.is_file():
        raise MotionDataError(label, f"BVH file {path} not found")
    map_path = None if joint_map is None else _resolve_path(joint_map, root)
    try:
        joints, _ = load_bvh_as_t2m_joints(path, map_path)
        return extract_features(joints, source=label)
    except MotionDataError as err:
        if err.source == label:
            raise
        raise MotionDataError(label, f"{err.reason} ({err.source})") from None


def _example_motion(
    example: StyleExample, index: int, style: StyleSpec, corpus_lookup: CorpusLookup, root: Path | None
) -> tuple[np.ndarray, MotionClip | None]:
    """(raw motion, the corpus clip when the source is a clip id)."""
    label = f"style {style.name!r} example {index} ({example.source})"
    suffix = Path(example.source).suffix.lower()
    if suffix == ".npy":
        return _load_npy(_resolve_path(example.source, root), label), None
    if suffix == ".bvh":
        return _load_bvh(_resolve_path(example.source, root), example.joint_map, root, label), None
    clip = _lookup(corpus_lookup, example.source)
    if clip is None:
        reason = "unknown clip id (not in the corpus)" if corpus_lookup is not None else "clip id given but no corpus"
        raise MotionDataError(label, f"{reason}; give a corpus clip id, a .npy or a .bvh")
    return clip.motion, clip


def load_style_example(
    example: StyleExample,
    index: int,
    style: StyleSpec,
    corpus_lookup: CorpusLookup = None,
    root: str | Path | None = None,
    min_frames: int = MIN_EXAMPLE_FRAMES,
) -> MotionClip:
    """One validated example clip whose single caption is the example's description."""
    label = f"style {style.name!r} example {index} ({example.source})"
    if not describes_style(example.description, style.words):
        forms = ", ".join(repr(f) for f in style.words.forms())
        raise MotionDataError(label, f"description {example.description!r} names no style word (one of {forms})")
    folder = None if root is None else Path(root)
    raw, corpus_clip = _example_motion(example, index, style, corpus_lookup, folder)
    motion = check_motion(raw, label, min_frames=min_frames)
    fps = corpus_clip.fps if corpus_clip is not None else 20.0
    meta = dict(corpus_clip.meta) if corpus_clip is not None else {}
    return MotionClip(
        id=f"{style.name}-example-{index}",
        motion=motion,
        captions=[Caption(text=example.description)],
        fps=fps,
        content=corpus_clip.content if corpus_clip is not None else None,
        style=style.name,
        source=f"{EXAMPLE_SOURCE}:{example.source}",
        meta=meta,
    )


def load_style_examples(
    style: StyleSpec,
    corpus_lookup: CorpusLookup = None,
    root: str | Path | None = None,
    min_frames: int = MIN_EXAMPLE_FRAMES,
) -> list[MotionClip]:
    """Every example of ``style`` as a validated clip (relative file paths resolve against ``root``).

    Raises on the first bad example, before any training, so a long fine-tune never starts on bad input.
    """
    return [load_style_example(ex, i, style, corpus_lookup, root, min_frames) for i, ex in enumerate(style.examples)]
