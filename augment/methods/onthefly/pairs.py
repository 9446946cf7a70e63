"""Style-neutral pairs (paper sec. 3.2, Eqs. 3-5) and the channels every sampler of the method inpaints.

Noise the example to step G and denoise it with the *prior* (DDPM) conditioned on the neutral description,
inpainting the example's root trajectory at every step: the neutral twin m_sn does what the example m_s does, on
the same path, without the style.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor, nn

from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.corpus.style_examples import check_motion
from motionaug.augment.device import bf16_autocast
from motionaug.augment.diffusion import bind_model, ddpm_sample, start_step_for
from motionaug.augment.methods.common import (
    MotionBatch,
    caption_text,
    feet_channels,
    module_device,
    neutral_text,
    trajectory_channels,
)
from motionaug.augment.methods.onthefly.params import PAIR_GUIDANCE_SCALE, OnTheFlyRecipe
from motionaug.augment.training.base_models import BaseModels


def kept_channels(params: OnTheFlyRecipe) -> list[int]:
    """Channels every sampler of the method inpaints from its reference: the trajectory, and the feet if asked."""
    return trajectory_channels(params.trajectory) + (feet_channels() if params.inpaint_feet else [])


def neutral_twins(
    prior: nn.Module, batch: MotionBatch, text_embed: Tensor, params: OnTheFlyRecipe, generator: torch.Generator
) -> Tensor:
    """Eqs. 3-5: the prior's neutral version of each motion, same trajectory (inpainted exactly), (B, T, D).

    DDPM from G (``pair_noise_step``) conditioned on the neutral description; padding frames are left as noise.
    Runs on the prior's device (noise drawn on CPU from ``generator``); the twins stay there.
    """
    device = module_device(prior)
    batch = batch.to(device)
    model_fn = bind_model(prior, text_embed.to(device), batch.mask)
    start = start_step_for(params.pair_noise_step, params.pair_steps)
    with torch.no_grad(), bf16_autocast(params.bf16, device):
        return ddpm_sample(
            model_fn,
            batch.x.shape,
            steps=params.pair_steps,
            start_step=start,
            x_start=batch.x,
            inpaint=batch.inpaint(kept_channels(params)),
            guidance_scale=PAIR_GUIDANCE_SCALE,
            generator=generator,
            device=device,
        )


@dataclass
class StylePairs:
    """The examples (m_s) with their neutral twins (m_sn), padded together, and their descriptions' embeddings."""

    styled: MotionBatch
    neutral: Tensor
    text_embed: Tensor


def make_pairs(
    base: BaseModels,
    examples: Sequence[MotionClip],
    params: OnTheFlyRecipe,
    generator: torch.Generator,
    vocab: dict[str, Any],
) -> StylePairs:
    """Validate the examples and generate their neutral twins with the prior (all examples in one batch).

    The pairs live on the prior's device, where fine-tuning reads them.
    """
    device = module_device(base.prior)
    motions = [check_motion(e.motion, f"style example {e.id}", min_frames=params.min_frames) for e in examples]
    styled = MotionBatch.from_motions(motions, base).to(device)
    descriptions = [caption_text(e) for e in examples]
    neutral_embed = base.text_encoder.encode([neutral_text(d, vocab) for d in descriptions])
    neutral = neutral_twins(base.prior, styled, neutral_embed, params, generator)
    neutral = torch.where(styled.mask[..., None], neutral, styled.x)  # padding: keep finite, it is never read
    return StylePairs(styled, neutral, base.text_encoder.encode(descriptions).to(device))
