"""Fine-tuning the transfer model (paper secs. 3.3-3.5): lambda_rec L_rec + lambda_s L_s on a copy of the prior.

L_rec teaches the copy m_sn -> m_s along the deterministic DDIM path from step K; L_s keeps corpus motions it
transfers close to their style-revised captions in the motion-text space (motion and text encoders frozen). The
copy is trained whole, or only through LoRA adapters (and optionally biases), with an optional weight average.
Also here: the L_s pool of corpus clips, and the tempo the pool and the transfer are retimed to.
"""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.corpus.style_examples import check_motion
from motionaug.augment.device import bf16_autocast
from motionaug.augment.diffusion import NoiseSchedule, bind_model, ddim_path, masked_mse, q_sample, start_step_for
from motionaug.augment.methods.base import Progress
from motionaug.augment.methods.common import (
    MotionBatch,
    caption_text,
    carries_style,
    longest_frames,
    module_device,
    neutral_text,
    retimed,
    revised_texts,
    seeded_generator,
    style_vocab,
    tempo_setting,
)
from motionaug.augment.methods.hooks import LossBatch, LossTerm, loss_terms, split_spec
from motionaug.augment.methods.onthefly.pairs import StylePairs, kept_channels, neutral_twins
from motionaug.augment.methods.onthefly.params import OnTheFlyRecipe
from motionaug.augment.motion.features import recover_from_ric
from motionaug.augment.training.base_models import BaseModels
from motionaug.models.lora import adapted_biases, apply_lora
from motionaug.models.motion_encoder import semantic_loss
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.skeleton import T2M
from motionaug.schemas.styles import StyleSpec

LORA_OUTPUT_LAYERS = ("output_process.poseFinal",)  # biased with ``lora_biases``: the direct pose offset


@dataclass
class ContentPool:
    """Corpus clips for L_s: normalised motions and each clip's revised captions (several phrasings)."""

    motions: list[np.ndarray]
    captions: list[list[str]]

    def __len__(self) -> int:
        return len(self.motions)


@dataclass
class FitResult:
    """What fine-tuning produced: the transfer model, its loss curve and timings."""

    model: nn.Module
    curve: list[dict[str, float]]
    timings: dict[str, float]
    tempo_note: str = ""


# ---- the losses -------------------------------------------------------------------------------------------


def _schedule_index(params: OnTheFlyRecipe) -> tuple[NoiseSchedule, int]:
    """The respaced DDIM schedule and the number of steps from K to 0."""
    return NoiseSchedule.cosine().respace(params.ddim_steps), start_step_for(
        params.transfer_noise_step, params.ddim_steps
    )


def reconstruction_loss(
    model: nn.Module, pairs: StylePairs, params: OnTheFlyRecipe, generator: torch.Generator
) -> tuple[Tensor, Tensor]:
    """L_rec: mean over the DDIM path from K of ||m_s - y0_hat(t)||^2, starting from q_sample(m_sn, K); and the
    path's last x0 (what the loss terms read).

    Runs where the pairs are (the model's device); the noise is drawn on CPU from ``generator``.
    """
    sched, n_run = _schedule_index(params)
    styled = pairs.styled
    device = styled.x.device
    noise = torch.randn(styled.x.shape, generator=generator).to(device)
    t = torch.full((styled.x.shape[0],), n_run - 1, dtype=torch.long)
    y_k = q_sample(sched, pairs.neutral, t, noise)
    with bf16_autocast(params.bf16, device):
        preds = ddim_path(
            bind_model(model, pairs.text_embed, styled.mask),
            y_k,
            n_run,
            steps=params.ddim_steps,
            inpaint=styled.inpaint(kept_channels(params)),
        )
    return torch.stack([masked_mse(p.float(), styled.x, styled.mask).mean() for p in preds]).mean(), preds[-1].float()


def extra_terms(
    terms: Sequence[tuple[str, LossTerm]], base: BaseModels, x0: Tensor, pairs: StylePairs
) -> dict[str, Tensor]:
    """The loss terms (``params.loss_terms``) on the path's last x0 against the style example, global joints."""
    joints = [recover_from_ric(base.normalizer.denormalize(x), T2M.n_joints) for x in (x0, pairs.styled.x)]
    step = LossBatch(joints[0], joints[1], pairs.styled.mask.bool(), base.info.fps)
    return {name: term(step) for name, term in terms}


def transferred_path_end(
    model: nn.Module, batch: MotionBatch, text_embed: Tensor, params: OnTheFlyRecipe, noise: Tensor
) -> Tensor:
    """The differentiable DDIM transfer of ``batch`` from K (trajectory inpainted), the last x0 of the path."""
    sched, n_run = _schedule_index(params)
    device = batch.x.device
    t = torch.full((batch.x.shape[0],), n_run - 1, dtype=torch.long)
    with bf16_autocast(params.bf16, device):
        preds = ddim_path(
            bind_model(model, text_embed.to(device), batch.mask),
            q_sample(sched, batch.x, t, noise.to(device)),
            n_run,
            steps=params.ddim_steps,
            inpaint=batch.inpaint(kept_channels(params)),
        )
    return preds[-1].float()


def semantic_guidance_loss(
    model: nn.Module,
    base: BaseModels,
    pool: ContentPool,
    indices: Sequence[int],
    params: OnTheFlyRecipe,
    generator: torch.Generator,
) -> Tensor:
    """L_s (Eq. 8): 1 - cos(motion_encoder(transferred corpus motions), text_encoder(revised captions))."""
    device = module_device(model)
    batch = MotionBatch.from_motions([pool.motions[i] for i in indices], None).to(device)
    picks = torch.randint(0, 1 << 30, (len(indices),), generator=generator).tolist()
    texts = [pool.captions[i][p % len(pool.captions[i])] for i, p in zip(indices, picks)]
    text_embed = base.text_encoder.encode(texts).to(device)
    noise = torch.randn(batch.x.shape, generator=generator).to(device)
    transferred = transferred_path_end(model, batch, text_embed, params, noise)
    return semantic_loss(base.motion_encoder(transferred, batch.mask), text_embed)


# ---- what is trained --------------------------------------------------------------------------------------


def lora_bias_parameters(model: nn.Module, params: OnTheFlyRecipe) -> dict[str, nn.Parameter]:
    """The biases trained beside LoRA adapters (``lora_biases``): adapted layers' and the output layer's."""
    return adapted_biases(model, LORA_OUTPUT_LAYERS) if params.lora_biases else {}


def _trainable(model: nn.Module, params: OnTheFlyRecipe) -> list[nn.Parameter]:
    """Full fine-tune: every prior weight. LoRA: only the adapters (the copied prior is frozen first)."""
    if params.lora_rank == 0:
        model.requires_grad_(True)
    else:
        model.requires_grad_(False)
        alpha = params.lora_alpha or float(params.lora_rank)
        apply_lora(model, params.lora_rank, alpha, params.lora_targets, generator=seeded_generator(params.seed))
        for bias in lora_bias_parameters(model, params).values():
            bias.requires_grad_(True)
    trainable = [p for p in model.parameters() if p.requires_grad]
    if not trainable:
        raise MotionDataError("onthefly fine-tune", "no trainable parameters (LoRA found no layer to adapt?)")
    return trainable


class WeightAverage:
    """Exponential moving average of the trained tensors (Polyak averaging): one example gives noisy last steps."""

    def __init__(self, params: Sequence[nn.Parameter], decay: float) -> None:
        self.params = list(params)
        self.decay = decay
        self.shadow = [p.detach().clone() for p in self.params]

    @torch.no_grad()
    def update(self) -> None:
        for shadow, param in zip(self.shadow, self.params):
            shadow.lerp_(param.detach(), 1.0 - self.decay)

    @torch.no_grad()
    def copy_to_params(self) -> None:
        for shadow, param in zip(self.shadow, self.params):
            param.copy_(shadow)


# ---- the loop ---------------------------------------------------------------------------------------------


def _step_plan(n_pool: int, params: OnTheFlyRecipe) -> int:
    if params.max_steps is not None:
        return params.max_steps
    if n_pool == 0:
        raise MotionDataError(
            "onthefly fine-tune", "no corpus clips for the semantic loss: give a corpus or set max_steps"
        )
    return params.epochs * math.ceil(n_pool / params.batch_size)


def _batches(n_pool: int, n_steps: int, batch_size: int, generator: torch.Generator) -> list[list[int]]:
    """Corpus indices per step: consecutive slices of a fresh permutation each pass."""
    if n_pool == 0:
        return [[] for _ in range(n_steps)]
    order: list[int] = []
    plan = []
    for _ in range(n_steps):
        if len(order) < min(batch_size, n_pool):
            order += torch.randperm(n_pool, generator=generator).tolist()
        plan.append(order[:batch_size])
        order = order[batch_size:]
    return plan


def finetune(
    base: BaseModels, pairs: StylePairs, pool: ContentPool, params: OnTheFlyRecipe, progress: Progress | None = None
) -> FitResult:
    """Sec. 3.3-3.5: copy the prior, train it on lambda_rec L_rec + lambda_s L_s; everything else stays frozen.

    The copy runs in eval mode: the loss follows a deterministic DDIM path, and training-time text dropout would
    spend the style example on the unconditional branch. It trains on the prior's device; randomness is drawn on
    CPU from the seed, so a seed means the same noise, batches and LoRA init on every device.
    """
    generator = seeded_generator(params.seed)
    model = copy.deepcopy(base.prior).eval()
    zero = torch.zeros((), device=module_device(model))
    trainable = _trainable(model, params)
    optimizer = torch.optim.AdamW(trainable, lr=params.lr, weight_decay=0.0)
    average = WeightAverage(trainable, params.ema_decay) if params.ema_decay is not None else None
    use_s = params.lambda_s > 0 and len(pool) > 0
    if not use_s and params.lambda_rec == 0:
        raise MotionDataError("onthefly fine-tune", "lambda_rec is 0 and no corpus clips for L_s: nothing to learn")
    where = "config method.params.loss_terms"
    terms = [(split_spec(spec)[0], loss_terms.create(spec, where)) for spec in params.loss_terms]
    n_steps = _step_plan(len(pool), params)
    plan = _batches(len(pool) if use_s else 0, n_steps, params.batch_size, generator)
    curve: list[dict[str, float]] = []
    start = time.perf_counter()
    for step, indices in enumerate(plan):
        l_rec, x0 = reconstruction_loss(model, pairs, params, generator) if params.lambda_rec > 0 else (zero, None)
        l_s = semantic_guidance_loss(model, base, pool, indices, params, generator) if use_s else zero
        total = params.lambda_rec * l_rec + params.lambda_s * l_s
        extra = extra_terms(terms, base, x0, pairs) if terms and x0 is not None else {}
        for name, term in terms:
            total = total + term.weight * extra.get(name, zero)
        optimizer.zero_grad(set_to_none=True)
        total.backward()
        if params.grad_clip is not None:
            nn.utils.clip_grad_norm_(optimizer.param_groups[0]["params"], params.grad_clip)
        optimizer.step()
        if average is not None:
            average.update()
        record = {
            "step": float(step),
            "l_rec": l_rec.item(),
            "l_s": l_s.item(),
            **{name: value.item() for name, value in extra.items()},
            "total": total.item(),
            "seconds": time.perf_counter() - start,
        }
        curve.append(record)
        if progress is not None:
            progress(step + 1, n_steps, record)
    if average is not None:
        average.copy_to_params()
    model.requires_grad_(False)
    return FitResult(model, curve, {"finetune_s": time.perf_counter() - start, "steps": float(n_steps)})


# ---- preparing the inputs of fine-tuning ------------------------------------------------------------------


def resolve_tempo(
    params: OnTheFlyRecipe,
    base: BaseModels,
    examples: Sequence[MotionClip],
    corpus: Sequence[MotionClip],
    vocab: dict[str, Any],
) -> tuple[float, str]:
    """(tempo, how it was set). ``"example"``: measured (``augment.motion.tempo.style_tempo``); 1.0 when it
    cannot be."""
    return tempo_setting(params.tempo, params.tempo_references, params.seed, base, examples, corpus, vocab)


def make_pool(
    base: BaseModels,
    corpus: Sequence[MotionClip],
    style: StyleSpec,
    params: OnTheFlyRecipe,
    generator: torch.Generator,
    tempo: float = 1.0,
) -> tuple[ContentPool, int]:
    """The L_s pool: usable corpus clips, normalised, with revised captions. Returns (pool, clips skipped).

    Clips whose captions name a style are skipped (``styled_corpus="skip"``, the default: the pool is for learning
    how neutral content takes the style) or replaced by their neutral twins. Clips too short, not finite, or whose
    captions cannot be revised are skipped. Clips are retimed to ``tempo`` as the transfer will retime them.
    """
    longest = longest_frames(base.prior, base)
    vocab = style_vocab(style.words, style.name)
    clean, styled, skipped = [], [], 0
    for i, clip in enumerate(corpus):
        is_styled = carries_style(caption_text(clip), vocab)
        if is_styled and params.styled_corpus == "skip":
            skipped += 1
            continue
        try:
            motion = check_motion(clip.motion, f"corpus clip {clip.id}", min_frames=params.min_frames)
            if len(motion) > longest:
                raise MotionDataError(f"corpus clip {clip.id}", f"{len(motion)} frames exceed the models' {longest}")
            motion = retimed(motion, tempo, base, longest)
            texts = [c.text for c in revised_texts(clip, style.words, params.caption_variants, params.seed + i, vocab)]
        except MotionDataError:
            skipped += 1
            continue
        (styled if is_styled else clean).append((clip, motion, texts))
    motions = [base.normalizer.normalize(m) for _, m, _ in clean]
    for chunk_start in range(0, len(styled), params.batch_size):
        chunk = styled[chunk_start : chunk_start + params.batch_size]
        batch = MotionBatch.from_motions([m for _, m, _ in chunk], base)
        embed = base.text_encoder.encode([neutral_text(caption_text(c), vocab) for c, _, _ in chunk])
        twins = neutral_twins(base.prior, batch, embed, params, generator)
        motions += [twins[i, :n].cpu().numpy() for i, n in enumerate(batch.lengths)]
    return ContentPool(motions, [t for _, _, t in clean + styled]), skipped
