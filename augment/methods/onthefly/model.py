"""The loaded style (paper sec. 3.5.2): a fine-tuned transfer model stylizing batches of content clips.

A content clip is validated, retimed to the style's tempo, given style-revised captions, neutralised first when its
caption names a style, then noised to K and DDIM-denoised conditioned on its revised caption, its root trajectory
kept by inpainting (sec. 7.1).
"""

from __future__ import annotations

import zlib
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor, nn

from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.corpus.rejects import Reject
from motionaug.augment.corpus.style_examples import check_motion
from motionaug.augment.device import bf16_autocast
from motionaug.augment.diffusion import DenoiseFn, bind_model, contrast_guided, ddim_sample, start_step_for
from motionaug.augment.diffusion.samplers import X0Hook
from motionaug.augment.methods.common import (
    MotionBatch,
    caption_text,
    carries_style,
    clip_noise,
    longest_frames,
    module_device,
    neutral_text,
    output_motion,
    output_scores,
    retimed,
    revised_texts,
    seeded_generator,
    style_vocab,
)
from motionaug.augment.methods.hooks import SamplerStep, sampler_callbacks
from motionaug.augment.methods.onthefly.pairs import kept_channels, neutral_twins
from motionaug.augment.methods.onthefly.params import OnTheFlyRecipe
from motionaug.augment.motion.foot_lock import lock_feet
from motionaug.augment.motion.tempo import retime_captions
from motionaug.augment.outputs.shards import TransferOutput
from motionaug.augment.training.base_models import BaseModels
from motionaug.schemas.captions import Caption
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.styles import StyleSpec


@dataclass
class _Job:
    """One usable clip of a transfer batch: its position, validated motion, revised captions, whether it is styled."""

    index: int
    clip: MotionClip
    motion: np.ndarray
    captions: list[Caption]
    styled: bool


class OnTheFlyModel:
    """A fine-tuned transfer model serving batches (``StyleModel``). Bad clips come back as ``Reject``s.

    Batches run on the transfer model's device; outputs come back as CPU numpy arrays.
    """

    def __init__(
        self,
        style: StyleSpec,
        base: BaseModels,
        model: nn.Module,
        params: OnTheFlyRecipe,
        batch_size: int | None = None,
        tempo: float = 1.0,
    ) -> None:
        self.style = style.name
        self.tempo = tempo  # content clips are retimed to it before the transfer (1.0: their own clock)
        self.spec = style
        self.base = base
        self.model = model.eval().requires_grad_(False)
        self.device = module_device(self.model)
        self.params = params
        self.batch_size = batch_size or params.batch_size
        self.vocab = style_vocab(style.words, style.name)
        self.callbacks = sampler_callbacks.create_all(params.callbacks, "config method.params.callbacks")

    def _job(self, index: int, clip: MotionClip, seed: int) -> _Job:
        """Validate a clip and revise its captions; any ``MotionDataError`` here rejects just this clip."""
        source = f"clip {clip.id}"
        motion = check_motion(
            clip.motion, source, feature_dim=self.base.normalizer.dim, min_frames=self.params.min_frames
        )
        longest = longest_frames(self.model, self.base)
        if motion.shape[0] > longest:
            raise MotionDataError(source, f"{motion.shape[0]} frames exceed the models' {longest}")
        motion = retimed(motion, self.tempo, self.base, longest)
        clip_seed = seed + zlib.crc32(clip.id.encode("utf-8"))
        captions = revised_texts(clip, self.spec.words, self.params.caption_variants, clip_seed, self.vocab)
        captions = retime_captions(captions, self.tempo, motion.shape[0] / clip.fps)
        if not captions:
            raise MotionDataError(source, f"no caption segment left after retiming to tempo {self.tempo:.3f}")
        styled = carries_style(caption_text(clip), self.vocab)
        return _Job(index, clip, motion, captions, styled)

    def transfer(self, clips: Sequence[MotionClip], seed: int = 0) -> list[TransferOutput | Reject]:
        """Stylize a batch; a clip that cannot be used (NaN, wrong width, too short) is a ``Reject`` in its place."""
        results: list[TransferOutput | Reject | None] = [None] * len(clips)
        jobs: list[_Job] = []
        for i, clip in enumerate(clips):
            try:
                jobs.append(self._job(i, clip, seed))
            except MotionDataError as err:
                results[i] = Reject.from_error(clip.id, err)
        for start in range(0, len(jobs), self.batch_size):
            chunk = jobs[start : start + self.batch_size]
            for job, output in zip(chunk, self._transfer_batch(chunk, seed)):
                results[job.index] = output
        return [r for r in results if r is not None]

    def _content(self, jobs: Sequence[_Job], seed: int) -> MotionBatch:
        """The batch to stylize: clips whose captions name a style are replaced by their neutral twins first."""
        batch = MotionBatch.from_motions([j.motion for j in jobs], self.base).to(self.device)
        if not any(j.styled for j in jobs):
            return batch
        embed = self.base.text_encoder.encode([neutral_text(caption_text(j.clip), self.vocab) for j in jobs])
        twins = neutral_twins(self.base.prior, batch, embed, self.params, seeded_generator(seed))
        keep = torch.tensor([j.styled for j in jobs], device=self.device)[:, None, None] & batch.mask[..., None]
        return MotionBatch(torch.where(keep, twins, batch.x), batch.mask, batch.lengths)

    def _denoiser(self, jobs: Sequence[_Job], cond: Tensor, mask: Tensor) -> DenoiseFn:
        """The tuned model on the revised captions; with ``style_guidance`` w, contrasted with the base prior on
        the content's neutral captions: w > 1 extrapolates the style the fine-tune added."""
        tuned = bind_model(self.model, cond, mask)
        w = self.params.style_guidance
        if w is None or w == 1.0:
            return tuned
        neutral = [neutral_text(caption_text(j.clip), self.vocab) for j in jobs]
        reference_cond = self.base.text_encoder.encode(neutral).to(self.device)
        return contrast_guided(tuned, bind_model(self.base.prior, reference_cond, mask), w)

    def _transfer_batch(self, jobs: Sequence[_Job], seed: int) -> list[TransferOutput]:
        content = self._content(jobs, seed)
        cond = self.base.text_encoder.encode([j.captions[0].text for j in jobs]).to(self.device)
        n_run = start_step_for(self.params.transfer_noise_step, self.params.ddim_steps)
        noise = clip_noise(content.x.shape, [j.clip.id for j in jobs], seed)  # CPU: the same on every device
        with torch.no_grad(), bf16_autocast(self.params.bf16, self.device):
            out = ddim_sample(
                self._denoiser(jobs, cond, content.mask),
                content.x.shape,
                steps=self.params.ddim_steps,
                start_step=n_run,
                x_start=content.x,
                noise=noise,
                inpaint=content.inpaint(kept_channels(self.params)),
                guidance_scale=None,
                device=self.device,
                x0_hook=self._x0_hook(content.mask) if self.callbacks else None,
            ).float()
        scores = self._scores(out, content.mask, cond, jobs)
        out = out.cpu()
        return [self._output(j, out[i, : j.motion.shape[0]], scores[i]) for i, j in enumerate(jobs)]

    def _x0_hook(self, mask: Tensor) -> X0Hook:
        """Every sampling step's x0 prediction through the configured sampler callbacks, in order."""

        def hook(t: int, x0: Tensor, x_t: Tensor) -> Tensor:
            for callback in self.callbacks:
                x0 = callback(SamplerStep(t, x0, x_t, mask))
            return x0

        return hook

    def _scores(self, out: Tensor, mask: Tensor, style_embed: Tensor, jobs: Sequence[_Job]) -> list[dict[str, float]]:
        """Per clip: cosine to the revised caption (style), to the original caption (content), foot skating."""
        return output_scores(self.base, out, mask, style_embed, [j.clip for j in jobs])

    def _output(self, job: _Job, out: Tensor, scores: dict[str, float]) -> TransferOutput:
        motion = output_motion(self.base, out, job.motion, kept_channels(self.params))
        if self.params.foot_lock:
            motion = lock_feet(motion)
        return TransferOutput(
            source_id=job.clip.id, style=self.style, motion=motion, captions=job.captions, scores=scores
        )
