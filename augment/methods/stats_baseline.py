"""Feature-statistics style transfer: a cheap, training-free reference row and the workflow's fast test method.

In the spirit of AdaIN on motion features (Aberman et al. 2020, "Unpaired Motion Style Transfer from Video
to Animation"): a style is summarised by the per-channel temporal mean and std of its example clips'
pose blocks (``ric``, ``rot``, ``local_vel``); a content clip's pose channels are re-normalised over time
to those statistics. Root trajectory (rotation/linear velocity), root height and foot contacts are kept,
so the clip still goes where it went. It changes posture and amplitude, not timing or gait, which is
exactly why it is a baseline.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import torch
from safetensors.numpy import load_file, save_file

from augment.clip import MotionClip
from augment.corpus.rejects import Reject
from schemas.errors import MotionDataError
from augment.features import feature_slices, recover_from_ric
from augment.methods.base import ARTIFACT_JSON, ARTIFACT_WEIGHTS, Progress, StyleTransferMethod, TransferOutput
from schemas.captions import Caption
from schemas.skeleton import T2M
from schemas.styles import StyleSpec, StyleWords

POSE_BLOCKS = ("ric", "rot", "local_vel")
STD_FLOOR = 1e-4  # channels flatter than this in the content clip are only shifted, never amplified
MIN_FRAMES = 2


def pose_channels() -> np.ndarray:
    """Indices of the pose-block channels in the t2m feature vector."""
    slices = feature_slices(T2M)
    return np.concatenate([np.arange(slices[b].start, slices[b].stop) for b in POSE_BLOCKS])


def check_clip(clip: MotionClip) -> np.ndarray:
    """The clip's motion as float32 (T, 263), or a MotionDataError naming it."""
    motion = np.asarray(clip.motion)
    if motion.ndim != 2 or motion.shape[1] != T2M.feature_dim:
        raise MotionDataError(f"clip {clip.id}", f"motion shape {motion.shape}, expected (frames, {T2M.feature_dim})")
    if motion.shape[0] < MIN_FRAMES:
        raise MotionDataError(f"clip {clip.id}", f"{motion.shape[0]} frames, need at least {MIN_FRAMES}")
    if not np.isfinite(motion).all():
        raise MotionDataError(f"clip {clip.id}", "motion contains NaN or Inf")
    return motion.astype(np.float32, copy=False)


def fallback_revision(captions: Sequence[Caption], words: StyleWords) -> list[Caption]:
    """'<caption> in a <adjective> way', with tokens, for when the caption-revision module is absent."""
    from augment.corpus.tokens import default_tokens

    extra_tokens = ["in/ADP", "a/DET", f"{words.adjective}/ADJ", "way/NOUN"]
    revised = []
    for caption in captions:
        text = f"{caption.text.rstrip(' .')} in a {words.adjective} way"
        tokens = list(caption.tokens or default_tokens(caption.text)) + extra_tokens
        revised.append(Caption(text=text, tokens=tokens, start=caption.start, end=caption.end))
    return revised


def revise(captions: Sequence[Caption], words: StyleWords, n_variants: int, seed: int) -> list[Caption]:
    try:
        from augment.caption_revision import revised_captions
    except ModuleNotFoundError as err:
        if err.name != "augment.caption_revision":
            raise
        return fallback_revision(captions, words)
    return list(revised_captions(list(captions), words, n_variants, seed))


class StatsStyleModel:
    """Loaded statistics of one style; ``transfer`` is pure numpy plus one joint recovery for scores."""

    def __init__(
        self, style: str, words: StyleWords, mean: np.ndarray, std: np.ndarray, strength: float, n_variants: int
    ) -> None:
        self.style = style
        self.words = words
        self.mean, self.std = mean, std
        self.strength = strength
        self.n_variants = n_variants
        self.channels = pose_channels()

    def transfer(self, clips: Sequence[MotionClip], seed: int = 0) -> list[TransferOutput | Reject]:
        results: list[TransferOutput | Reject] = []
        for i, clip in enumerate(clips):
            try:
                results.append(self._one(clip, seed + i))
            except MotionDataError as err:
                results.append(Reject.from_error(clip.id, err))
        return results

    def _one(self, clip: MotionClip, seed: int) -> TransferOutput:
        motion = check_clip(clip)
        out = motion.copy()
        pose = motion[:, self.channels]  # (T, C)
        mu, sd = pose.mean(axis=0), pose.std(axis=0)
        scale = np.where(sd > STD_FLOOR, self.std / np.maximum(sd, STD_FLOOR), 1.0)
        styled = (pose - mu) * scale + self.mean
        out[:, self.channels] = (1.0 - self.strength) * pose + self.strength * styled
        joints = recover_from_ric(torch.from_numpy(out), T2M.n_joints).numpy()
        from augment.metrics import foot_skating_ratio

        scores = {"foot_skating": foot_skating_ratio(joints, T2M, clip.fps)}
        captions = revise(clip.captions, self.words, self.n_variants, seed)
        return TransferOutput(source_id=clip.id, style=self.style, motion=out, captions=captions, scores=scores)


class StatsBaselineMethod(StyleTransferMethod):
    """AdaIN-like re-normalisation of pose channels to the style examples' temporal statistics."""

    name: ClassVar[str] = "stats"
    needs_base_models: ClassVar[bool] = False

    def __init__(self, strength: float = 1.0, n_variants: int = 1) -> None:
        self.strength = strength
        self.n_variants = n_variants

    @classmethod
    def validate_params(cls, params: dict[str, Any]) -> dict[str, Any]:
        unknown = sorted(set(params) - {"strength", "n_variants"})
        if unknown:
            raise ValueError(f"unknown parameter(s) {unknown}; known: ['n_variants', 'strength']")
        strength = float(params.get("strength", 1.0))
        n_variants = int(params.get("n_variants", 1))
        if not 0.0 <= strength <= 1.0:
            raise ValueError(f"strength {strength} outside [0, 1]")
        if n_variants < 1:
            raise ValueError(f"n_variants {n_variants} < 1")
        return {"strength": strength, "n_variants": n_variants}

    def prepare(
        self,
        style: StyleSpec,
        examples: Sequence[MotionClip],
        base_dir: Path | None,
        corpus: Sequence[MotionClip],
        out_dir: Path,
        seed: int | None = None,
        progress: Progress | None = None,
    ) -> Path:
        motions = [check_clip(clip) for clip in examples]
        if not motions:
            raise MotionDataError(f"style {style.name!r}", "no example clips")
        pose = np.concatenate(motions)[:, pose_channels()].astype(np.float64)
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        save_file(
            {"mean": pose.mean(axis=0).astype(np.float32), "std": pose.std(axis=0).astype(np.float32)},
            str(out_dir / ARTIFACT_WEIGHTS),
        )
        meta = {
            "method": self.name, "version": 1, "style": style.name, "words": style.words.model_dump(mode="json"),
            "params": {"strength": self.strength, "n_variants": self.n_variants},
            "examples": [clip.id for clip in examples], "frames": int(pose.shape[0]), "blocks": list(POSE_BLOCKS),
        }  # fmt: skip
        (out_dir / ARTIFACT_JSON).write_text(json.dumps(meta, indent=1, sort_keys=True) + "\n", encoding="utf-8")
        if progress is not None:
            progress(1, 1, {})
        return out_dir

    def load(self, artifact_dir: Path, base_dir: Path | None = None, **options: Any) -> StatsStyleModel:
        folder = Path(artifact_dir)
        meta_path, weights_path = folder / ARTIFACT_JSON, folder / ARTIFACT_WEIGHTS
        if not meta_path.is_file() or not weights_path.is_file():
            raise MotionDataError(str(folder), f"not a stats artefact: needs {ARTIFACT_JSON} and {ARTIFACT_WEIGHTS}")
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
        if meta.get("method") != self.name:
            raise MotionDataError(str(folder), f"artefact of method {meta.get('method')!r}, not {self.name!r}")
        weights = load_file(str(weights_path))
        return StatsStyleModel(
            meta["style"], StyleWords.model_validate(meta["words"]), weights["mean"], weights["std"],
            float(meta["params"]["strength"]), int(meta["params"]["n_variants"]),
        )  # fmt: skip
