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
from typing import ClassVar

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field
from safetensors.numpy import load_file, save_file

from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.corpus.rejects import Reject
from motionaug.augment.methods.base import (
    ARTIFACT_JSON,
    ARTIFACT_WEIGHTS,
    CostRates,
    Prepared,
    Progress,
    StyleTransferMethod,
    TransferOutput,
)
from motionaug.augment.motion.features import feature_slices, recover_from_ric
from motionaug.augment.synth.styles import STYLE_WORDS
from motionaug.augment.text.caption_revision import revised_captions
from motionaug.schemas.captions import Caption
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.skeleton import T2M
from motionaug.schemas.styles import StyleSpec, StyleWords

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


def revise(captions: Sequence[Caption], words: StyleWords, n_variants: int, seed: int) -> list[Caption]:
    return list(revised_captions(list(captions), words, n_variants, seed, vocab=STYLE_WORDS))


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
        from motionaug.augment.metrics import foot_skating_ratio

        scores = {"foot_skating": foot_skating_ratio(joints, T2M, clip.fps)}
        captions = revise(clip.captions, self.words, self.n_variants, seed)
        return TransferOutput(source_id=clip.id, style=self.style, motion=out, captions=captions, scores=scores)


class StatsParams(BaseModel):
    model_config = ConfigDict(extra="forbid")

    strength: float = Field(1.0, ge=0.0, le=1.0, description="0 keeps the content clip, 1 the style's statistics.")
    n_variants: int = Field(1, ge=1, description="Revised captions per output clip.")


class StatsBaselineMethod(StyleTransferMethod):
    """AdaIN-like re-normalisation of pose channels to the style examples' temporal statistics."""

    name: ClassVar[str] = "stats"
    Params: ClassVar[type[BaseModel]] = StatsParams
    params: StatsParams
    cost_rates: ClassVar[CostRates] = CostRates(prepare_s=0.02, transfer_clips_per_s=380.0, artefact_bytes=8_000)

    def prepare_style(
        self,
        style: StyleSpec,
        examples: Sequence[MotionClip],
        trained: Path | None,
        content: Sequence[MotionClip],
        out: Path,
        seed: int | None,
        progress: Progress | None,
    ) -> Prepared:
        motions = [check_clip(clip) for clip in examples]
        pose = np.concatenate(motions)[:, pose_channels()].astype(np.float64)
        out_dir = Path(out)
        out_dir.mkdir(parents=True, exist_ok=True)
        save_file(
            {"mean": pose.mean(axis=0).astype(np.float32), "std": pose.std(axis=0).astype(np.float32)},
            str(out_dir / ARTIFACT_WEIGHTS),
        )
        meta = {
            "method": self.name,
            "version": 1,
            "style": style.name,
            "words": style.words.model_dump(mode="json"),
            "params": self.params.model_dump(),
            "examples": [clip.id for clip in examples],
            "frames": int(pose.shape[0]),
            "blocks": list(POSE_BLOCKS),
        }
        (out_dir / ARTIFACT_JSON).write_text(json.dumps(meta, indent=1, sort_keys=True) + "\n", encoding="utf-8")
        if progress is not None:
            progress(1, 1, {})
        return Prepared(out_dir)

    def load(self, artifact: Path, trained: Path | None = None) -> StatsStyleModel:
        folder = Path(artifact)
        meta_path, weights_path = folder / ARTIFACT_JSON, folder / ARTIFACT_WEIGHTS
        if not meta_path.is_file() or not weights_path.is_file():
            raise MotionDataError(str(folder), f"not a stats artefact: needs {ARTIFACT_JSON} and {ARTIFACT_WEIGHTS}")
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
        if meta.get("method") != self.name:
            raise MotionDataError(str(folder), f"artefact of method {meta.get('method')!r}, not {self.name!r}")
        weights = load_file(str(weights_path))
        return StatsStyleModel(
            meta["style"],
            StyleWords.model_validate(meta["words"]),
            weights["mean"],
            weights["std"],
            float(meta["params"]["strength"]),
            int(meta["params"]["n_variants"]),
        )
