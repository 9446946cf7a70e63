"""Output shaping: the run's output shapers (``method.shapers``) applied to every method's outputs alike.

A shaper is a post-process, so it belongs to no method: the workflow's prepare stage stores, beside a style's
artefact, the style's examples and (when a shaper reads one) each example's reference, a plain pool clip whose root
moves like the example's, standing in for the example's content performed without the style (``nearest_root_motion``).
The transfer stage wraps the method's model in ``ShapedModel``, which shapes each output in the corpus's feature
space with the example the clip's id picks. The same shapers applied to the content clip without the network are the
control row that every shipped post-process gets in the leave-style-out protocol.
"""

from __future__ import annotations

import json
import zlib
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
from safetensors.numpy import load_file, save_file

from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.corpus.rejects import Reject
from motionaug.augment.methods.base import StyleModel
from motionaug.augment.methods.hooks import HookSpec, OutputShaper, ShapeContext, needs_reference
from motionaug.augment.motion.features import feature_slices
from motionaug.augment.motion.tempo import retime_captions
from motionaug.augment.motion.travel import travels
from motionaug.augment.outputs.shards import TransferOutput
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.skeleton import T2M

SHAPING_FILE = "_shaping.safetensors"
REFERENCE_POOL = 64  # plain pool clips the plan hands the prepare stage to pick references from
MIN_REFERENCE_FRAMES = 8


def pool_size(specs: Sequence[HookSpec]) -> int:
    """How many pool clips the shapers need (0 when none reads a reference)."""
    return REFERENCE_POOL if needs_reference(specs) else 0


def root_motion(motion: np.ndarray) -> np.ndarray:
    """What a clip's root does, a summary that style changes little: the log of its mean ground speed (slow and
    fast styles move a walk's speed by a factor, far less than a walk differs from standing), the direction of its
    mean velocity in the facing frame (sideways, either side, and forwards: a walk is not a sidestep or a backward
    walk), its turning rate (per frame) and the spread of the root height. Not the share of frames with a foot
    down: slow styles raise it as much as standing still does."""
    slices = feature_slices(T2M)
    velocity = motion[:, slices["root_lin_vel"]]
    speed = np.linalg.norm(velocity, axis=1).mean()
    sideways, forwards = velocity.mean(axis=0) / (speed + 1e-6)
    turning = np.abs(motion[:, slices["root_rot_vel"]]).mean()
    return np.array([np.log(speed + 1e-3), abs(sideways), forwards, turning, motion[:, slices["root_y"]].std()])


def nearest_root_motion(example: np.ndarray, candidates: dict[str, np.ndarray]) -> tuple[str, np.ndarray]:
    """The candidate whose ``root_motion`` is nearest the example's, each summary entry scaled by its spread over
    the candidates (ties: the smallest id). A stand-in for the example's content performed without its style."""
    ids = sorted(candidates)
    summaries = np.stack([root_motion(candidates[i]) for i in ids])
    scale = summaries.std(axis=0) + 1e-6
    distance = np.linalg.norm((summaries - root_motion(example)) / scale, axis=1)
    best = ids[int(np.argmin(distance))]
    return best, candidates[best]


def usable(clip: MotionClip, width: int) -> bool:
    """A pool clip a reference may be: finite, of the examples' width, long enough to have moments."""
    m = clip.motion
    return m.ndim == 2 and m.shape[1] == width and m.shape[0] >= MIN_REFERENCE_FRAMES and bool(np.isfinite(m).all())


def write_shaping(
    folder: Path,
    style: str,
    examples: Sequence[MotionClip],
    pool: Sequence[MotionClip],
    specs: Sequence[HookSpec],
    named: Sequence[MotionClip | None] = (),
) -> None:
    """The style's examples and, when a shaper reads one, each example's reference into ``folder``: the clip the
    user named for it (``named[i]``, the example's motion performed plainly), else the pool's nearest by root
    motion."""
    tensors = {f"example.{i}": np.ascontiguousarray(e.motion, dtype=np.float32) for i, e in enumerate(examples)}
    references: list[str] = []
    if needs_reference(specs):
        width = examples[0].motion.shape[1]
        candidates = {c.id: c.motion for c in pool if usable(c, width)}
        if named and len(named) != len(examples):
            raise ValueError(f"{len(named)} named references for {len(examples)} examples")
        for clip in named:
            if clip is not None and not usable(clip, width):
                raise MotionDataError(f"reference {clip.id!r}", "is not a usable reference (width, length, NaN)")
        if not candidates and (not named or any(clip is None for clip in named)):
            raise MotionDataError(
                f"style {style!r}", "the output shapers need usable plain pool clips to pick the references from"
            )
        for i, example in enumerate(examples):
            given = named[i] if named else None
            reference_id, reference = (
                (given.id, given.motion) if given is not None else nearest_root_motion(example.motion, candidates)
            )
            references.append(reference_id)
            tensors[f"reference.{i}"] = np.ascontiguousarray(reference, dtype=np.float32)
    metadata = {"examples": json.dumps([e.id for e in examples]), "references": json.dumps(references)}
    save_file(tensors, str(Path(folder) / SHAPING_FILE), metadata=metadata)


def read_shaping(folder: Path) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """(examples, references) as ``write_shaping`` stored them; references empty when no shaper read one."""
    path = Path(folder) / SHAPING_FILE
    if not path.is_file():
        raise MotionDataError(str(folder), f"no {SHAPING_FILE}: the artefact was prepared without output shapers")
    tensors = load_file(str(path))
    examples = [tensors[f"example.{i}"] for i in range(sum(k.startswith("example.") for k in tensors))]
    references = [tensors[f"reference.{i}"] for i in range(sum(k.startswith("reference.") for k in tensors))]
    return examples, references


def alike_examples(clip_travels: bool, examples_travel: Sequence[bool]) -> list[int]:
    """The examples that move as the clip does (travelling or in place; all of them where none does)."""
    return [i for i, t in enumerate(examples_travel) if t == clip_travels] or list(range(len(examples_travel)))


def example_index(clip_id: str, clip_travels: bool, examples_travel: Sequence[bool]) -> int:
    """Which example a clip is transferred and shaped with: of the examples that move as the clip does
    (``alike_examples``), the one its id picks (batch-independent). Why: a style's change to a walk says little of
    its change to a wave, so a user who gives one of each gets each where it applies."""
    alike = alike_examples(clip_travels, examples_travel)
    return alike[zlib.crc32(clip_id.encode("utf-8")) % len(alike)]


def shape(
    output: np.ndarray,
    content: MotionClip,
    shapers: Sequence[OutputShaper],
    examples: Sequence[np.ndarray],
    references: Sequence[np.ndarray] = (),
) -> np.ndarray:
    """``output`` through the shapers in order, against the content clip and the example (with its reference) that
    the content's id picks."""
    clip_travels, examples_travel = travels(content.motion, content.fps), [travels(e, content.fps) for e in examples]
    picked = example_index(content.id, clip_travels, examples_travel)
    reference = references[picked] if references else None
    alike = tuple(
        (examples[i], references[i] if references else None) for i in alike_examples(clip_travels, examples_travel)
    )
    context = ShapeContext(content.motion.astype(np.float32), examples[picked], reference, content.fps, alike)
    for shaper in shapers:
        output = shaper(output, context)
        context = shaper.context_after(context)
    return output


class ShapedModel:
    """A style model whose every output goes through the shapers; a non-finite shaped output is a ``Reject``."""

    def __init__(
        self,
        model: StyleModel,
        shapers: Sequence[OutputShaper],
        examples: Sequence[np.ndarray],
        references: Sequence[np.ndarray] = (),
    ) -> None:
        if any(s.needs_reference for s in shapers) and len(references) != len(examples):
            raise MotionDataError("config method.shapers", "the artefact has no references; prepare it again")
        self.model, self.shapers = model, list(shapers)
        self.examples, self.references = list(examples), list(references)
        self.style = model.style

    def transfer(self, clips: Sequence[MotionClip], seed: int = 0) -> list[TransferOutput | Reject]:
        by_id = {c.id: c for c in clips}
        shaped: list[TransferOutput | Reject] = []
        for out in self.model.transfer(clips, seed):
            if isinstance(out, Reject):
                shaped.append(out)
                continue
            clip = by_id[out.source_id]
            motion = shape(out.motion, clip, self.shapers, self.examples, self.references)
            if not np.isfinite(motion).all():
                shaped.append(Reject(id=clip.id, source=f"clip {clip.id}", reason="non-finite shaped output"))
                continue
            captions = out.captions
            if len(motion) != len(out.motion):  # a step played it at the style's clock: the segments move with it
                captions = retime_captions(captions, len(out.motion) / len(motion), len(motion) / clip.fps)
            shaped.append(replace(out, motion=motion.astype(np.float32), captions=captions))
        return shaped
