"""On-the-fly style transfer by fine-tuning a diffusion prior (Hu, Zhang, Ye, Xu, Xia, CGF 2024).

Learning a style from one (or a few) example clips, paper sections 3.2-3.5:

1. Style-neutral pair (Eqs. 3-5): noise the example to step G and denoise it with the *prior* (DDPM) conditioned
   on the neutral description, inpainting the example's root trajectory at every step. The result m_sn does
   what the example does, on the same path, without the style.
2. Fine-tuning: a copy of the prior (all of it, or LoRA adapters) learns m_sn -> m_s along the deterministic DDIM
   path from step K (L_rec), while a semantic loss L_s keeps corpus motions it transfers close to their
   style-revised captions in the motion-text space (the motion encoder and text encoder stay frozen).
3. Transfer (sec. 3.5.2): noise a content clip to K and DDIM-denoise it with the transfer model conditioned on
   its revised caption, keeping the content's root trajectory by inpainting (sec. 7.1).

Beyond the paper: the transfer keeps the content's clock, but styles change tempo (a depressed walk cycles slower).
By default the style's tempo is measured from its examples against neutral corpus clips described alike
(``augment.tempo``) and content clips are retimed to it before the transfer (and in the L_s pool, so the model
is tuned on what it will see); ``tempo="content"`` keeps the paper's behaviour.

Everything runs in the normalised feature space of the base models (``BaseModels.normalizer``).
"""

from __future__ import annotations

import copy
import hashlib
import math
import os
import time
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Literal

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field, ValidationError
from safetensors.torch import load_file, save_file
from torch import Tensor, nn

from augment.base_models import BASE_JSON, PRIOR, BaseModels, load_module
from augment.clip import MotionClip
from augment.corpus.rejects import Reject
from augment.cpu import bf16_autocast
from augment.diffusion import (
    InpaintSpec,
    NoiseSchedule,
    bind_model,
    ddim_path,
    ddim_sample,
    ddpm_sample,
    masked_mse,
    q_sample,
    start_step_for,
)
from augment.diffusion.schedule import NUM_TRAIN_TIMESTEPS
from schemas.errors import MotionDataError, first_error
from augment.evaluation_inputs import features_to_joints, pad_batch
from augment.features import feature_slices
from augment.io import atomic_path, atomic_write_text, read_json_model
from augment.methods.base import ARTIFACT_JSON, ARTIFACT_WEIGHTS, Progress, StyleTransferMethod, TransferOutput
from augment.metrics import foot_skating_ratio
from augment.style_examples import check_motion
from augment.tempo import TEMPO_RANGE, retime, retime_captions, style_tempo
from models.lora import DEFAULT_TARGETS as LORA_TARGETS
from models.lora import (
    adapted_biases,
    apply_lora,
    is_lora_key,
    load_biases,
    load_lora_state_dict,
    lora_state_dict,
    merge_lora,
)
from models.motion_encoder import cosine_similarity, semantic_loss
from models.text_encoder import TextEncoder
from schemas.captions import Caption
from schemas.skeleton import T2M
from schemas.styles import StyleSpec, StyleWords

METHOD_NAME = "onthefly"
THREADS_ENV = ("MOTIONAUG_TORCH_THREADS", "OMP_NUM_THREADS")


# ---- configuration ----------------------------------------------------------------------------------------


class OnTheFlyParams(BaseModel):
    """Every knob of the method; ``extra="forbid"`` so a typo in a config is an error, not a default."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    version: int = 1
    pair_noise_step: int = Field(950, description="G: training timestep the example is noised to for its neutral twin.")
    pair_steps: int = Field(
        100, description="DDPM steps of pair generation (respaced; 1000 = unspaced as the paper, ~10x slower on CPU)."
    )
    pair_guidance_scale: float | None = Field(2.5, description="Classifier-free guidance of the neutral twin.")
    transfer_noise_step: int = Field(300, description="K: training timestep content is noised to (fine-tune and transfer).")
    ddim_steps: int = Field(20, description="S: DDIM steps of the whole process (K=300 of 1000 runs 6 of 20).")
    transfer_guidance_scale: float | None = None
    trajectory: Literal["horizontal", "root"] = Field(
        "horizontal", description="Inpainted channels: root rotation + linear velocity, or also the root height."
    )
    inpaint_feet: bool = Field(
        False, description="Also inpaint the foot-contact channels (pairs and transfer keep the gait's phase)."
    )
    lambda_rec: float = 1.0
    lambda_s: float = 0.1
    lr: float = 1e-4
    grad_clip: float | None = 1.0
    epochs: int = Field(1, description="Passes over the corpus pool of L_s (ignored when max_steps is set).")
    max_steps: int | None = None
    batch_size: int = 8
    lora_rank: int = Field(
        0, description="0: full fine-tune; >0: LoRA adapters on lora_targets (they start at zero: give them a larger "
        "lr and alpha, but not more passes, which memorise the example; configs/onthefly-lora-synthetic.yaml is the "
        "recipe bench/RESULTS.md compares with full fine-tuning)."
    )  # fmt: skip
    lora_alpha: float | None = Field(None, description="LoRA scale numerator; defaults to the rank.")
    lora_targets: tuple[str, ...] = Field(
        LORA_TARGETS, description="Modules given adapters, by their last name components (models.lora)."
    )
    lora_biases: bool = Field(
        False, description="LoRA: also train the biases of the adapted layers and of the output layer (BitFit): "
        "shifts a style holds over the whole clip cost low-rank deltas rank, a bias carries them.",
    )  # fmt: skip
    ema_decay: float | None = Field(
        None, description="Keep an exponential moving average of the trained weights and ship it (None: the last step)."
    )
    caption_variants: int = 3
    tempo: Literal["example", "content"] | float = Field(
        "example", description="Clock of the outputs: 'example' retimes content to the style's tempo measured from its "
        "examples (augment.tempo); 'content' keeps the content's clock (the paper); a number sets it (below 1: slower).",
    )  # fmt: skip
    tempo_references: int = Field(
        16, description="Neutral corpus clips (captions nearest the examples' neutral descriptions) giving the neutral cycle."
    )
    neutralise_content: bool = Field(True, description="Transfer: neutralise content clips whose captions name a style.")
    styled_corpus: Literal["skip", "neutralise"] = Field(
        "skip", description="L_s pool: drop corpus clips whose captions name a style, or neutralise them (slow: DDPM from G)."
    )
    min_frames: int = 20
    bf16: bool | None = Field(None, description="bf16 autocast on CPU; None = where the CPU has bf16 units.")
    seed: int = 0


def _fail(field: str, reason: str) -> MotionDataError:
    return MotionDataError(f"onthefly params: {field}", reason)


def validate_params(params: OnTheFlyParams, num_timesteps: int = NUM_TRAIN_TIMESTEPS) -> OnTheFlyParams:
    """Range checks across fields, each failing with the field's name (pydantic only checks types)."""
    for name in ("pair_noise_step", "transfer_noise_step"):
        value = getattr(params, name)
        if not 0 < value <= num_timesteps:
            raise _fail(name, f"{value} outside (0, {num_timesteps}]")
    for name in ("pair_steps", "ddim_steps"):
        value = getattr(params, name)
        if not 1 <= value <= num_timesteps:
            raise _fail(name, f"{value} outside [1, {num_timesteps}]")
    positive = {"lr": params.lr, "epochs": params.epochs, "batch_size": params.batch_size,
                "caption_variants": params.caption_variants}  # fmt: skip
    for name, value in positive.items():
        if not value > 0:
            raise _fail(name, f"must be > 0, got {value}")
    for name in ("lambda_rec", "lambda_s"):
        if not getattr(params, name) >= 0:
            raise _fail(name, f"must be >= 0, got {getattr(params, name)}")
    if params.lambda_rec == 0 and params.lambda_s == 0:
        raise _fail("lambda_rec", "lambda_rec and lambda_s are both 0: nothing to learn")
    if params.max_steps is not None and params.max_steps < 1:
        raise _fail("max_steps", f"must be >= 1, got {params.max_steps}")
    if params.lora_rank < 0:
        raise _fail("lora_rank", f"must be >= 0, got {params.lora_rank}")
    if params.ema_decay is not None and not 0.0 < params.ema_decay < 1.0:
        raise _fail("ema_decay", f"{params.ema_decay} outside (0, 1)")
    if params.lora_rank > 0 and not params.lora_targets:
        raise _fail("lora_targets", "empty: LoRA needs at least one module to adapt")
    if params.min_frames < 2:
        raise _fail("min_frames", f"must be >= 2, got {params.min_frames}")
    if params.grad_clip is not None and params.grad_clip <= 0:
        raise _fail("grad_clip", f"must be > 0 or null, got {params.grad_clip}")
    if isinstance(params.tempo, float) and not TEMPO_RANGE[0] <= params.tempo <= TEMPO_RANGE[1]:
        raise _fail("tempo", f"{params.tempo} outside [{TEMPO_RANGE[0]}, {TEMPO_RANGE[1]}]")
    if params.tempo_references < 1:
        raise _fail("tempo_references", f"must be >= 1, got {params.tempo_references}")
    return params


def parse_params(data: dict[str, Any] | None = None, **overrides: Any) -> OnTheFlyParams:
    """Params from a dict (a config file) plus overrides, validated; errors name the field."""
    try:
        params = OnTheFlyParams.model_validate({**(data or {}), **overrides})
    except ValidationError as err:
        raise _fail(*first_error(err, "params")) from None
    return validate_params(params)


def trajectory_channels(mode: str = "horizontal") -> list[int]:
    """Feature channels that carry the root trajectory: rotation velocity + xz velocity (+ height for ``root``)."""
    slices = feature_slices(T2M)
    blocks = ["root_rot_vel", "root_lin_vel"] + (["root_y"] if mode == "root" else [])
    return [c for block in blocks for c in range(slices[block].start, slices[block].stop)]


def kept_channels(params: OnTheFlyParams) -> list[int]:
    """Channels every sampler of the method inpaints from its reference: the trajectory, and the feet if asked."""
    feet = feature_slices(T2M)["feet"]
    return trajectory_channels(params.trajectory) + (list(range(feet.start, feet.stop)) if params.inpaint_feet else [])


def configure_threads() -> int:
    """Apply the thread count the workflow exported (Ray sets it per worker); returns torch's count."""
    for name in THREADS_ENV:
        value = os.environ.get(name, "")
        if value.isdigit() and int(value) > 0:
            torch.set_num_threads(int(value))
            break
    return torch.get_num_threads()


# ---- caption handling (augment.caption_revision) ----------------------------------------------------------


def _caption_text(clip: MotionClip) -> str:
    """The caption a clip is conditioned on: its first whole-clip caption, else its first, else its content."""
    for caption in clip.captions:
        if caption.whole_clip:
            return caption.text
    if clip.captions:
        return clip.captions[0].text
    return f"a person does {clip.content.replace('_', ' ')}" if clip.content else "a person moves"


def style_vocab(words: StyleWords, name: str) -> dict[str, Any]:
    """The built-in styles' words plus this style's own, so a user-defined style is neutralised too."""
    from augment.caption_revision import DEFAULT_VOCAB

    return {**DEFAULT_VOCAB, name: words}


def neutral_text(text: str, vocab: dict[str, Any]) -> str:
    """The description with every known style word removed (the prior's condition for the neutral twin)."""
    from augment.caption_revision import neutral_description

    return neutral_description(text, vocab)


def carries_style(text: str, vocab: dict[str, Any]) -> bool:
    from augment.caption_revision import has_style_words

    return bool(has_style_words(text, vocab))


def revised_texts(clip: MotionClip, words: StyleWords, n_variants: int, seed: int, vocab: dict[str, Any]) -> list[Caption]:
    """Several phrasings of the clip's captions in the target style (their old style words removed first)."""
    from augment.caption_revision import revised_captions

    captions = clip.captions or [Caption(text=_caption_text(clip))]
    try:
        revised = revised_captions(list(captions), words, n_variants, seed, vocab)
    except MotionDataError as err:
        raise MotionDataError(f"clip {clip.id}", f"caption revision failed: {err}") from None
    if not revised:
        raise MotionDataError(f"clip {clip.id}", "no revised caption")
    return revised


# ---- tempo (augment.tempo) ---------------------------------------------------------------------------------

MAX_TEMPO_CANDIDATES = 4096  # corpus clips whose captions are embedded to find the tempo references


def longest_frames(model: nn.Module, base: BaseModels) -> int:
    """Most frames a clip may have here: the prior's and the motion encoder's tables (+1 token each)."""
    return min(model.config.max_len, base.motion_encoder.config.max_len) - 1


def retimed(motion: np.ndarray, tempo: float, base: BaseModels, longest: int) -> np.ndarray:
    """``motion`` at the style's tempo; slowing never makes it longer than the base's longest clip or ``longest``."""
    if tempo == 1.0:
        return motion
    cap = min(longest, max(len(motion), base.info.max_frames))
    return retime(motion, tempo, cap)


def tempo_references(
    base: BaseModels, corpus: Sequence[MotionClip], descriptions: Sequence[str], vocab: dict[str, Any], k: int, seed: int
) -> list[MotionClip]:
    """The ``k`` neutral corpus clips whose captions are nearest (text embedding) to the examples' neutral descriptions."""
    candidates = [c for c in corpus if not carries_style(_caption_text(c), vocab) and np.isfinite(c.motion).all()]
    if len(candidates) > MAX_TEMPO_CANDIDATES:
        order = torch.randperm(len(candidates), generator=seeded_generator(seed)).tolist()
        candidates = [candidates[i] for i in order[:MAX_TEMPO_CANDIDATES]]
    if not candidates:
        return []
    query = base.text_encoder.encode(list(descriptions)).mean(dim=0, keepdim=True)
    keys = base.text_encoder.encode([_caption_text(c) for c in candidates])
    similarity = torch.nn.functional.cosine_similarity(keys, query, dim=-1)
    return [candidates[i] for i in similarity.argsort(descending=True)[:k].tolist()]


def resolve_tempo(
    params: OnTheFlyParams, base: BaseModels, examples: Sequence[MotionClip], corpus: Sequence[MotionClip],
    vocab: dict[str, Any],
) -> tuple[float, str]:  # fmt: skip
    """(tempo, how it was set). ``"example"``: measured (``augment.tempo.style_tempo``); 1.0 when it cannot be."""
    if params.tempo == "content":
        return 1.0, "content clock kept (tempo='content')"
    if not isinstance(params.tempo, str):
        return float(params.tempo), "set in the params"
    descriptions = [neutral_text(_caption_text(e), vocab) for e in examples]
    references = tempo_references(base, corpus, descriptions, vocab, params.tempo_references, params.seed)
    tempo, why = style_tempo([(e.motion, e.fps) for e in examples], [(c.motion, c.fps) for c in references])
    if tempo is None:
        return 1.0, f"content clock kept: {why}"
    return tempo, f"tempo {tempo:.3f} from {why}"


# ---- batches in the normalised space ----------------------------------------------------------------------


@dataclass
class MotionBatch:
    """Normalised, padded motions (B, T, D) with their frame mask (B, T) and lengths."""

    x: Tensor
    mask: Tensor
    lengths: list[int]

    @classmethod
    def from_motions(cls, motions: Sequence[np.ndarray], base: BaseModels | None) -> MotionBatch:
        """Pad raw motions, normalising them with ``base``'s Mean/Std (``base=None``: already normalised)."""
        arrays = [np.asarray(m, dtype=np.float32) for m in motions]
        x, mask = pad_batch([a if base is None else base.normalizer.normalize(a) for a in arrays])
        return cls(x, mask, [int(a.shape[0]) for a in arrays])

    def inpaint(self, channels: Sequence[int], reference: Tensor | None = None) -> InpaintSpec:
        """Keep ``channels`` of ``reference`` (default: these motions) on the real frames."""
        return InpaintSpec(self.x if reference is None else reference, list(channels), frames=self.mask)


def seeded_generator(seed: int) -> torch.Generator:
    """A generator for any integer seed: the workflow derives 64-bit seeds, torch takes them below 2**63."""
    return torch.Generator().manual_seed(seed % (1 << 63))


def clip_noise(shape: Sequence[int], clip_ids: Sequence[str], seed: int) -> Tensor:
    """Initial noise drawn per clip from (seed, clip id): a clip's output does not depend on its batch mates."""
    rows = []
    for clip_id in clip_ids:
        generator = seeded_generator(seed * 1_000_003 + zlib.crc32(clip_id.encode("utf-8")))
        rows.append(torch.randn(tuple(shape[1:]), generator=generator))
    return torch.stack(rows)


def neutral_twins(
    prior: nn.Module, batch: MotionBatch, text_embed: Tensor, params: OnTheFlyParams, generator: torch.Generator
) -> Tensor:
    """Eqs. 3-5: the prior's neutral version of each motion, same trajectory (inpainted exactly), (B, T, D).

    DDPM from G (``pair_noise_step``) conditioned on the neutral description; padding frames are left as noise.
    """
    model_fn = bind_model(prior, text_embed, batch.mask)
    start = start_step_for(params.pair_noise_step, params.pair_steps)
    with torch.no_grad(), bf16_autocast(params.bf16):
        return ddpm_sample(
            model_fn, batch.x.shape, steps=params.pair_steps, start_step=start, x_start=batch.x,
            inpaint=batch.inpaint(kept_channels(params)),
            guidance_scale=params.pair_guidance_scale, generator=generator,
        )  # fmt: skip


# ---- fine-tuning ------------------------------------------------------------------------------------------


@dataclass
class StylePairs:
    """The examples (m_s) with their neutral twins (m_sn), padded together, and their descriptions' embeddings."""

    styled: MotionBatch
    neutral: Tensor
    text_embed: Tensor


@dataclass
class ContentPool:
    """Corpus clips for L_s: normalised motions and each clip's revised captions (several phrasings)."""

    motions: list[np.ndarray]
    captions: list[list[str]]

    def __len__(self) -> int:
        return len(self.motions)


def _schedule_index(params: OnTheFlyParams) -> tuple[NoiseSchedule, int]:
    """The respaced DDIM schedule and the number of steps from K to 0."""
    return NoiseSchedule.cosine().respace(params.ddim_steps), start_step_for(params.transfer_noise_step, params.ddim_steps)


def reconstruction_loss(model: nn.Module, pairs: StylePairs, params: OnTheFlyParams, generator: torch.Generator) -> Tensor:
    """L_rec: mean over the DDIM path from K of ||m_s - y0_hat(t)||^2, starting from q_sample(m_sn, K)."""
    sched, n_run = _schedule_index(params)
    styled = pairs.styled
    noise = torch.randn(styled.x.shape, generator=generator)
    t = torch.full((styled.x.shape[0],), n_run - 1, dtype=torch.long)
    y_k = q_sample(sched, pairs.neutral, t, noise)
    with bf16_autocast(params.bf16):
        preds = ddim_path(
            bind_model(model, pairs.text_embed, styled.mask), y_k, n_run, steps=params.ddim_steps,
            inpaint=styled.inpaint(kept_channels(params)),
        )  # fmt: skip
    return torch.stack([masked_mse(p.float(), styled.x, styled.mask).mean() for p in preds]).mean()


def transferred_path_end(
    model: nn.Module, batch: MotionBatch, text_embed: Tensor, params: OnTheFlyParams, noise: Tensor
) -> Tensor:
    """The differentiable DDIM transfer of ``batch`` from K (trajectory inpainted), the last x0 of the path."""
    sched, n_run = _schedule_index(params)
    t = torch.full((batch.x.shape[0],), n_run - 1, dtype=torch.long)
    with bf16_autocast(params.bf16):
        preds = ddim_path(
            bind_model(model, text_embed, batch.mask), q_sample(sched, batch.x, t, noise), n_run,
            steps=params.ddim_steps, inpaint=batch.inpaint(kept_channels(params)),
        )  # fmt: skip
    return preds[-1].float()


def semantic_guidance_loss(
    model: nn.Module, base: BaseModels, pool: ContentPool, indices: Sequence[int], params: OnTheFlyParams,
    generator: torch.Generator,
) -> Tensor:  # fmt: skip
    """L_s (Eq. 8): 1 - cos(motion_encoder(transferred corpus motions), text_encoder(revised captions))."""
    batch = MotionBatch.from_motions([pool.motions[i] for i in indices], None)
    picks = torch.randint(0, 1 << 30, (len(indices),), generator=generator).tolist()
    texts = [pool.captions[i][p % len(pool.captions[i])] for i, p in zip(indices, picks)]
    text_embed = base.text_encoder.encode(texts)
    noise = torch.randn(batch.x.shape, generator=generator)
    transferred = transferred_path_end(model, batch, text_embed, params, noise)
    return semantic_loss(base.motion_encoder(transferred, batch.mask), text_embed)


@dataclass
class FitResult:
    """What fine-tuning produced: the transfer model, its loss curve and timings."""

    model: nn.Module
    curve: list[dict[str, float]]
    timings: dict[str, float]
    tempo_note: str = ""


LORA_OUTPUT_LAYERS = ("output_process.poseFinal",)  # biased with ``lora_biases``: the direct pose offset


def _lora_biases(model: nn.Module, params: OnTheFlyParams) -> dict[str, nn.Parameter]:
    return adapted_biases(model, LORA_OUTPUT_LAYERS) if params.lora_biases else {}


def _trainable(model: nn.Module, params: OnTheFlyParams) -> list[nn.Parameter]:
    """Full fine-tune: every prior weight. LoRA: only the adapters (the copied prior is frozen first)."""
    if params.lora_rank == 0:
        model.requires_grad_(True)
    else:
        model.requires_grad_(False)
        alpha = params.lora_alpha or float(params.lora_rank)
        apply_lora(model, params.lora_rank, alpha, params.lora_targets, generator=seeded_generator(params.seed))
        for bias in _lora_biases(model, params).values():
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


def _step_plan(n_pool: int, params: OnTheFlyParams) -> int:
    if params.max_steps is not None:
        return params.max_steps
    if n_pool == 0:
        raise MotionDataError("onthefly fine-tune", "no corpus clips for the semantic loss: give a corpus or set max_steps")
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
    base: BaseModels, pairs: StylePairs, pool: ContentPool, params: OnTheFlyParams, progress: Progress | None = None
) -> FitResult:
    """Sec. 3.3-3.5: copy the prior, train it on lambda_rec L_rec + lambda_s L_s; everything else stays frozen.

    The copy runs in eval mode: the loss follows a deterministic DDIM path, and training-time text dropout would
    spend the style example on the unconditional branch.
    """
    generator = seeded_generator(params.seed)
    model = copy.deepcopy(base.prior).eval()
    trainable = _trainable(model, params)
    optimizer = torch.optim.AdamW(trainable, lr=params.lr, weight_decay=0.0)
    average = WeightAverage(trainable, params.ema_decay) if params.ema_decay is not None else None
    use_s = params.lambda_s > 0 and len(pool) > 0
    if not use_s and params.lambda_rec == 0:
        raise MotionDataError("onthefly fine-tune", "lambda_rec is 0 and no corpus clips for L_s: nothing to learn")
    n_steps = _step_plan(len(pool), params)
    plan = _batches(len(pool) if use_s else 0, n_steps, params.batch_size, generator)
    curve: list[dict[str, float]] = []
    start = time.perf_counter()
    for step, indices in enumerate(plan):
        l_rec = reconstruction_loss(model, pairs, params, generator) if params.lambda_rec > 0 else torch.zeros(())
        l_s = semantic_guidance_loss(model, base, pool, indices, params, generator) if use_s else torch.zeros(())
        total = params.lambda_rec * l_rec + params.lambda_s * l_s
        optimizer.zero_grad(set_to_none=True)
        total.backward()
        if params.grad_clip is not None:
            nn.utils.clip_grad_norm_(optimizer.param_groups[0]["params"], params.grad_clip)
        optimizer.step()
        if average is not None:
            average.update()
        record = {"step": float(step), "l_rec": l_rec.item(), "l_s": l_s.item(), "total": total.item(),
                  "seconds": time.perf_counter() - start}  # fmt: skip
        curve.append(record)
        if progress is not None:
            progress(step + 1, n_steps, record)
    if average is not None:
        average.copy_to_params()
    model.requires_grad_(False)
    return FitResult(model, curve, {"finetune_s": time.perf_counter() - start, "steps": float(n_steps)})


# ---- preparing the inputs of fine-tuning ------------------------------------------------------------------


def make_pairs(
    base: BaseModels, examples: Sequence[MotionClip], params: OnTheFlyParams, generator: torch.Generator,
    vocab: dict[str, Any] | None = None,
) -> StylePairs:  # fmt: skip
    """Validate the examples and generate their neutral twins with the prior (all examples in one batch)."""
    motions = [check_motion(e.motion, f"style example {e.id}", min_frames=params.min_frames) for e in examples]
    styled = MotionBatch.from_motions(motions, base)
    descriptions = [_caption_text(e) for e in examples]
    neutral_embed = base.text_encoder.encode([neutral_text(d, vocab) for d in descriptions])
    neutral = neutral_twins(base.prior, styled, neutral_embed, params, generator)
    neutral = torch.where(styled.mask[..., None], neutral, styled.x)  # padding: keep finite, it is never read
    return StylePairs(styled, neutral, base.text_encoder.encode(descriptions))


def make_pool(
    base: BaseModels, corpus: Sequence[MotionClip], style: StyleSpec, params: OnTheFlyParams, generator: torch.Generator,
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
        is_styled = carries_style(_caption_text(clip), vocab)
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
        embed = base.text_encoder.encode([neutral_text(_caption_text(c), vocab) for c, _, _ in chunk])
        twins = neutral_twins(base.prior, batch, embed, params, generator)
        motions += [twins[i, :n].numpy() for i, n in enumerate(batch.lengths)]
    return ContentPool(motions, [t for _, _, t in clean + styled]), skipped


# ---- the loaded style ---------------------------------------------------------------------------------------


@dataclass
class _Job:
    """One usable clip of a transfer batch: its position, validated motion, revised captions, whether it is styled."""

    index: int
    clip: MotionClip
    motion: np.ndarray
    captions: list[Caption]
    styled: bool


class OnTheFlyModel:
    """A fine-tuned transfer model serving batches (``StyleModel``). Bad clips come back as ``Reject``s."""

    def __init__(self, style: StyleSpec, base: BaseModels, model: nn.Module, params: OnTheFlyParams,
                 batch_size: int | None = None, tempo: float = 1.0) -> None:  # fmt: skip
        self.style = style.name
        self.tempo = tempo  # content clips are retimed to it before the transfer (1.0: their own clock)
        self.spec = style
        self.base = base
        self.model = model.eval().requires_grad_(False)
        self.params = params
        self.batch_size = batch_size or params.batch_size
        self.vocab = style_vocab(style.words, style.name)

    def _job(self, index: int, clip: MotionClip, seed: int) -> _Job:
        """Validate a clip and revise its captions; any ``MotionDataError`` here rejects just this clip."""
        source = f"clip {clip.id}"
        motion = check_motion(clip.motion, source, feature_dim=self.base.normalizer.dim, min_frames=self.params.min_frames)
        longest = longest_frames(self.model, self.base)
        if motion.shape[0] > longest:
            raise MotionDataError(source, f"{motion.shape[0]} frames exceed the models' {longest}")
        motion = retimed(motion, self.tempo, self.base, longest)
        clip_seed = seed + zlib.crc32(clip.id.encode("utf-8"))
        captions = revised_texts(clip, self.spec.words, self.params.caption_variants, clip_seed, self.vocab)
        captions = retime_captions(captions, self.tempo, motion.shape[0] / clip.fps)
        if not captions:
            raise MotionDataError(source, f"no caption segment left after retiming to tempo {self.tempo:.3f}")
        styled = self.params.neutralise_content and carries_style(_caption_text(clip), self.vocab)
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
        batch = MotionBatch.from_motions([j.motion for j in jobs], self.base)
        if not any(j.styled for j in jobs):
            return batch
        embed = self.base.text_encoder.encode([neutral_text(_caption_text(j.clip), self.vocab) for j in jobs])
        twins = neutral_twins(self.base.prior, batch, embed, self.params, seeded_generator(seed))
        keep = torch.tensor([j.styled for j in jobs])[:, None, None] & batch.mask[..., None]
        return MotionBatch(torch.where(keep, twins, batch.x), batch.mask, batch.lengths)

    def _transfer_batch(self, jobs: Sequence[_Job], seed: int) -> list[TransferOutput]:
        content = self._content(jobs, seed)
        cond = self.base.text_encoder.encode([j.captions[0].text for j in jobs])
        n_run = start_step_for(self.params.transfer_noise_step, self.params.ddim_steps)
        noise = clip_noise(content.x.shape, [j.clip.id for j in jobs], seed)
        with torch.no_grad(), bf16_autocast(self.params.bf16):
            out = ddim_sample(
                bind_model(self.model, cond, content.mask), content.x.shape, steps=self.params.ddim_steps,
                start_step=n_run, x_start=content.x, noise=noise,
                inpaint=content.inpaint(kept_channels(self.params)),
                guidance_scale=self.params.transfer_guidance_scale,
            ).float()  # fmt: skip
        scores = self._scores(out, content.mask, cond, jobs)
        return [self._output(j, out[i, : j.motion.shape[0]], scores[i]) for i, j in enumerate(jobs)]

    def _scores(self, out: Tensor, mask: Tensor, style_embed: Tensor, jobs: Sequence[_Job]) -> list[dict[str, float]]:
        """Per clip: cosine to the revised caption (style), to the original caption (content), foot skating."""
        originals = [_caption_text(j.clip) for j in jobs]
        with torch.no_grad():
            feats = self.base.motion_encoder(out, mask)
            style = cosine_similarity(feats, style_embed).tolist()
            content = cosine_similarity(feats, self.base.text_encoder.encode(originals)).tolist()
        joints = features_to_joints(out, T2M, self.base.normalizer.mean, self.base.normalizer.std)
        lengths = mask.sum(dim=1).tolist()
        skate = [foot_skating_ratio(joints[i, :n].numpy(), T2M, j.clip.fps) for i, (j, n) in enumerate(zip(jobs, lengths))]
        return [{"style_score": s, "content_score": c, "foot_skating": f} for s, c, f in zip(style, content, skate)]

    def _output(self, job: _Job, out: Tensor, scores: dict[str, float]) -> TransferOutput:
        motion = self.base.normalizer.denormalize(out.numpy()).astype(np.float32)
        channels = kept_channels(self.params)
        motion[:, channels] = job.motion[:, channels]  # exact, not just up to normalise/denormalise rounding
        return TransferOutput(source_id=job.clip.id, style=self.style, motion=motion, captions=job.captions, scores=scores)


# ---- the artefact -------------------------------------------------------------------------------------------


class OnTheFlyArtifact(BaseModel):
    """``artifact.json``: enough to rebuild the transfer model over the same base models, and how it was made."""

    model_config = ConfigDict(extra="forbid")

    version: int = 1
    method: str = METHOD_NAME
    style: StyleSpec
    params: OnTheFlyParams
    base_fingerprint: str
    weights: Literal["full", "lora"]
    weights_bytes: int
    full_model_bytes: int
    trainable_parameters: int
    pool_clips: int
    pool_skipped: int
    tempo: float = 1.0
    tempo_note: str = ""
    loss_curve: list[dict[str, float]]
    timings: dict[str, float]


def base_fingerprint(base_dir: Path) -> str:
    """sha256 of base.json and the prior's weights: an artefact only fits the prior it was tuned from."""
    digest = hashlib.sha256()
    for name in (BASE_JSON, f"{PRIOR}.safetensors"):
        path = Path(base_dir) / name
        if not path.is_file():
            raise MotionDataError(str(path), "base-models file missing")
        with path.open("rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                digest.update(block)
    return digest.hexdigest()[:16]


def tensor_bytes(state: dict[str, Tensor]) -> int:
    return sum(t.numel() * t.element_size() for t in state.values())


def weights_state(model: nn.Module, params: OnTheFlyParams) -> dict[str, Tensor]:
    """What the artefact stores: only adapter tensors for LoRA, else the whole transfer model."""
    if params.lora_rank > 0:
        state = {**lora_state_dict(model), **_lora_biases(model, params)}
    else:
        state = model.state_dict()
    return {k: v.detach().contiguous().clone() for k, v in state.items()}


def read_artifact(artifact_dir: Path) -> OnTheFlyArtifact:
    path = Path(artifact_dir) / ARTIFACT_JSON
    info = read_json_model(path, OnTheFlyArtifact, "an on-the-fly artefact")
    if info.method != METHOD_NAME:
        raise MotionDataError(str(path), f"artefact of method {info.method!r}, not {METHOD_NAME!r}")
    return info


def rebuild_transfer_model(base: BaseModels, info: OnTheFlyArtifact, weights: Path, merge: bool = False) -> nn.Module:
    """The prior copy with the artefact's weights (adapters re-attached, optionally merged for speed)."""
    model = copy.deepcopy(base.prior)
    if info.weights == "full":
        load_module(model, weights)
        return model.eval().requires_grad_(False)
    try:
        state = load_file(str(weights))
    except Exception as err:  # safetensors has its own error types
        raise MotionDataError(str(weights), f"unreadable safetensors ({err})") from None
    rank, targets = info.params.lora_rank, info.params.lora_targets
    apply_lora(model, rank, info.params.lora_alpha or float(rank), targets)
    load_lora_state_dict(model, {k: v for k, v in state.items() if is_lora_key(k)})
    load_biases(_lora_biases(model, info.params), {k: v for k, v in state.items() if not is_lora_key(k)})
    if merge:
        merge_lora(model)
    return model.eval().requires_grad_(False)


# ---- the method ---------------------------------------------------------------------------------------------


class OnTheFlyMethod(StyleTransferMethod):
    """``prepare``: pair generation + fine-tuning -> artefact; ``load``: artefact -> ``OnTheFlyModel``."""

    name: ClassVar[str] = METHOD_NAME
    needs_base_models: ClassVar[bool] = True

    @classmethod
    def validate_params(cls, params: dict[str, Any]) -> dict[str, Any]:
        """The registry's hook: a bad parameter is a config error before the run starts."""
        return parse_params(params).model_dump()

    @classmethod
    def from_params(cls, params: dict[str, Any]) -> OnTheFlyMethod:
        """The registry's factory: an instance from a config's (validated) params."""
        return cls(parse_params(params))

    def __init__(self, params: OnTheFlyParams | dict[str, Any] | None = None, text_encoder: TextEncoder | None = None) -> None:
        self.params = params if isinstance(params, OnTheFlyParams) else parse_params(params)
        validate_params(self.params)
        self.text_encoder = text_encoder

    def fit(
        self, style: StyleSpec, examples: Sequence[MotionClip], base: BaseModels, corpus: Sequence[MotionClip],
        seed: int | None = None, progress: Progress | None = None,
    ) -> tuple[OnTheFlyModel, FitResult, ContentPool, int]:  # fmt: skip
        """Everything ``prepare`` does except writing: (loaded model, fit result, L_s pool, clips skipped)."""
        if not examples:
            raise MotionDataError(f"style {style.name!r}", "no example clips")
        # a caller's seed (the workflow's per-style seed) wins over the params'
        params = self.params if seed is None else self.params.model_copy(update={"seed": seed})
        generator = seeded_generator(params.seed)
        start = time.perf_counter()
        vocab = style_vocab(style.words, style.name)
        pairs = make_pairs(base, examples, params, generator, vocab)
        tempo, fit_note = resolve_tempo(params, base, examples, corpus, vocab)
        pool, skipped = make_pool(base, corpus, style, params, generator, tempo)  # also sets the step count when lambda_s=0
        prep_s = time.perf_counter() - start
        fit = finetune(base, pairs, pool, params, progress)
        fit.timings["pairs_and_pool_s"] = prep_s
        fit.tempo_note = fit_note
        return OnTheFlyModel(style, base, fit.model, params, tempo=tempo), fit, pool, skipped

    def prepare(
        self, style: StyleSpec, examples: Sequence[MotionClip], base_dir: Path, corpus: Sequence[MotionClip],
        out_dir: Path, seed: int | None = None, progress: Progress | None = None,
    ) -> Path:  # fmt: skip
        configure_threads()
        base = BaseModels.load(base_dir, text_encoder=self.text_encoder)
        model, fit, pool, skipped = self.fit(style, examples, base, corpus, seed, progress)
        return self.save(Path(out_dir), Path(base_dir), model, fit, pool, skipped)

    def save(
        self, out_dir: Path, base_dir: Path, model: OnTheFlyModel, fit: FitResult, pool: ContentPool, skipped: int
    ) -> Path:
        """Write ``weights.safetensors`` (adapters only for LoRA) and ``artifact.json`` (written last)."""
        weights = weights_state(fit.model, model.params)
        info = OnTheFlyArtifact(
            style=model.spec, params=model.params, base_fingerprint=base_fingerprint(base_dir),
            weights="lora" if model.params.lora_rank > 0 else "full", weights_bytes=tensor_bytes(weights),
            full_model_bytes=tensor_bytes(model.base.prior.state_dict()),
            trainable_parameters=sum(t.numel() for t in weights.values()), pool_clips=len(pool), pool_skipped=skipped,
            tempo=model.tempo, tempo_note=fit.tempo_note, loss_curve=fit.curve, timings=fit.timings,
        )  # fmt: skip
        out_dir.mkdir(parents=True, exist_ok=True)
        with atomic_path(out_dir / ARTIFACT_WEIGHTS) as tmp:
            save_file(weights, str(tmp))
        atomic_write_text(out_dir / ARTIFACT_JSON, info.model_dump_json(indent=2))  # last: marks a complete artefact
        return out_dir

    def load(self, artifact_dir: Path, base_dir: Path, **options: Any) -> OnTheFlyModel:
        """Options: ``merge`` (fold LoRA adapters into the weights; faster, not bit-identical), ``batch_size``,
        ``bf16`` (override the artefact's autocast choice), ``text_encoder``."""
        unknown = sorted(set(options) - {"merge", "batch_size", "bf16", "text_encoder"})
        if unknown:
            raise MotionDataError(f"{METHOD_NAME} load", f"unknown options {unknown}")
        configure_threads()
        info = read_artifact(Path(artifact_dir))
        found = base_fingerprint(Path(base_dir))
        if found != info.base_fingerprint:
            raise MotionDataError(str(artifact_dir), f"tuned from base models {info.base_fingerprint}, {base_dir} is {found}")
        base = BaseModels.load(base_dir, text_encoder=options.get("text_encoder", self.text_encoder))
        model = rebuild_transfer_model(base, info, Path(artifact_dir) / ARTIFACT_WEIGHTS, bool(options.get("merge", False)))
        params = info.params if "bf16" not in options else info.params.model_copy(update={"bf16": bool(options["bf16"])})
        return OnTheFlyModel(info.style, base, model, params, options.get("batch_size"), tempo=info.tempo)
