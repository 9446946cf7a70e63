"""Pretraining the base models on a corpus: the T2M prior, the motion encoder, the evaluators.

Three stages, in order, each checkpointed and resumable: (a) ``prior``, MDM predicting x0 with masked MSE plus MDM's
geometric losses, condition dropout, AdamW with warm-up and cosine decay, bf16 autocast where the hardware has it;
(b) ``motion_encoder``, through the prior's frozen input layer onto the caption embedding (semantic loss, Hu et al.
2024 sec. 3.4.1); (c) ``evaluators``, content and style classifiers with held-out accuracy. Every random draw comes
from checkpointed seeded generators and is made on CPU, then moved to the device chosen once per run, so a resumed
run ends with the weights of one that never stopped and a seed means the same batches, noise and initialisation on
every device. ``ensure_base_models`` reuses a folder whose corpus fingerprint and config hash match.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Literal

import torch
import torch.distributed as dist
from pydantic import BaseModel, ConfigDict, Field
from torch import Tensor, nn

from motionaug.augment.corpus.fingerprint import corpus_fingerprint
from motionaug.augment.corpus.humanml3d import ADDED_SPLIT, HumanML3DReader
from motionaug.augment.device import bf16_autocast, pick_device
from motionaug.augment.diffusion import NoiseSchedule, masked_mse, q_sample, sample_timesteps
from motionaug.augment.metrics import retrieval_r_at_k
from motionaug.augment.motion.batch import pad_batch
from motionaug.augment.motion.features import Normalizer, compute_mean_std, features_to_joints
from motionaug.augment.training.base_models import BASE_JSON, BaseModels, BaseModelsInfo, config_dict
from motionaug.augment.training.checkpoints import (
    StageCheckpoint,
    load_checkpoint,
    read_record,
    save_checkpoint,
    stage_dir,
    step_folder,
)
from motionaug.augment.training.data import (
    Batch,
    MotionSet,
    build_motion_set,
    iter_batches,
    read_clips,
    sample_batch,
    share_weights,
    split_ids,
)
from motionaug.augment.training.evaluators import (
    EVALUATORS_DIR,
    classifier_accuracy,
    evaluators_folder,
    fit_classifier,
    save_evaluators,
)
from motionaug.augment.training.geometric_losses import geometric_losses
from motionaug.models.evaluators import MotionClassifier, make_classifier
from motionaug.models.mdm import MDM, MDMConfig
from motionaug.models.motion_encoder import MotionEncoder, MotionEncoderConfig, semantic_loss
from motionaug.models.text_encoder import TextEncoder, make_text_encoder
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.skeleton import BUILTIN_SKELETONS, Skeleton

ProgressFn = Callable[[str, int, int, dict[str, float]], None]
CPU = torch.device("cpu")
STAGES = ("prior", "motion_encoder", "evaluators")
CHECKPOINTS = "checkpoints"
LOSS_LOG = "loss_log.jsonl"
TRAINING_RECORDS = frozenset({CHECKPOINTS, LOSS_LOG})
"""Files of a base-models folder that record how training went (wall-clock times), not what was trained."""
RETRIEVAL_POOL = 32

LOG = logging.getLogger(__name__)


class PretrainConfig(BaseModel):
    """How to pretrain. Fields that do not change the result (threads, checkpoint cadence) stay out of the hash."""

    model_config = ConfigDict(extra="forbid")

    version: int = 1
    size: Literal["tiny", "small", "paper"] = "small"
    seed: int = 0
    prior_steps: int = Field(4000, ge=1)
    encoder_steps: int = Field(1500, ge=1)
    classifier_epochs: int = Field(40, ge=1)
    classifier_size: Literal["tiny", "default"] = "default"
    batch_size: int = Field(64, ge=1)
    bucket: int | None = Field(128, ge=1, description="Draw each batch among this many clips of similar length.")
    lr: float = Field(3e-4, gt=0)
    encoder_lr: float = Field(5e-4, gt=0)
    classifier_lr: float = Field(1e-3, gt=0)
    weight_decay: float = Field(0.01, ge=0)
    warmup_steps: int = Field(100, ge=0)
    min_lr_ratio: float = Field(0.1, ge=0, le=1, description="Cosine decay floor, as a share of lr.")
    grad_clip: float = Field(1.0, gt=0)
    dropout: float = Field(
        0.0, ge=0, lt=1, description="Prior and encoder dropout; off, as CPU runs are short and underfit."
    )
    max_frames: int = Field(196, ge=2)
    lambda_pos: float = Field(1.0, ge=0)
    lambda_vel: float = Field(1.0, ge=0)
    lambda_foot: float = Field(1.0, ge=0)
    input_perturbation: float = Field(
        0.0,
        ge=0,
        description="DDPM-IP (Ning et al. 2023): the prior's input carries this much extra N(0, I) noise on top "
        "of the noise q_sample adds, so it learns to correct the drift its own predictions put into x_t when sampling.",
    )
    added_share: float | None = Field(
        None,
        gt=0,
        lt=1,
        description="Share of the prior's and encoder's draws given to the clips an expansion added (the corpus's "
        "added.txt); None: every train clip alike. Ignored for a corpus without added clips.",
    )
    prior_latent_dim: int | None = Field(None, ge=8, description="Prior width; None = the size's MDM preset.")
    prior_ff_size: int | None = Field(None, ge=8, description="Prior feed-forward width; None = the size's preset.")
    prior_layers: int | None = Field(None, ge=1, description="Prior transformer layers; None = the size's preset.")
    bf16: bool | None = Field(None, description="bf16 autocast; None = on CUDA and on CPUs with bf16 units.")
    text_encoder: str = "minilm"
    from_mdm: str | None = Field(
        None, description="Official MDM checkpoint to use as the prior (augment.training.from_mdm); None: train one."
    )
    clip_weights: str | None = Field(None, description="CLIP ViT-B/32 weights for from_mdm; None: found locally.")
    mdm_stats: str | None = Field(None, description="Folder with the prior's Mean/Std.npy; None: beside it or corpus.")
    threads: int | None = Field(None, ge=1)
    checkpoint_every: int = Field(500, ge=1)
    log_every: int = Field(10, ge=1)

    @classmethod
    def for_size(cls, size: str, **overrides: Any) -> PretrainConfig:
        """Defaults per model size: ``tiny`` is for tests (seconds), ``small`` for a CPU (minutes)."""
        presets: dict[str, dict[str, Any]] = {
            "tiny": {
                "prior_steps": 40,
                "encoder_steps": 30,
                "classifier_epochs": 5,
                "classifier_size": "tiny",
                "batch_size": 8,
                "warmup_steps": 5,
                "lr": 1e-3,
                "encoder_lr": 1e-3,
                "checkpoint_every": 20,
            },
            # small: a narrow prior (d=128) learns the synthetic corpus faster per CPU second than d=256; input
            # perturbation (DDPM-IP) raises text-to-motion style recognition for a little content recognition
            "small": {
                "prior_steps": 3600,
                "prior_latent_dim": 128,
                "prior_ff_size": 256,
                "encoder_steps": 1500,
                "classifier_epochs": 10,
                "batch_size": 32,
                "lr": 2e-3,
                "encoder_lr": 1e-3,
                "input_perturbation": 0.1,
            },
            "paper": {"prior_steps": 50000, "encoder_steps": 10000, "lr": 1e-4},
        }
        if size not in presets:
            raise MotionDataError("PretrainConfig", f"unknown size {size!r} (choose from {sorted(presets)})")
        return cls(size=size, **{**presets[size], **overrides})

    def config_hash(self) -> str:
        """Hash of every field that changes the trained weights (the MDM files count by content, in the fingerprint)."""
        ignored = {"threads", "checkpoint_every", "log_every", "from_mdm", "clip_weights", "mdm_stats"}
        ignored |= {"added_share"} if self.added_share is None else set()  # hashes from before the field stay valid
        relevant = self.model_dump(exclude=ignored)
        return hashlib.sha256(json.dumps(relevant, sort_keys=True).encode()).hexdigest()[:16]


def skeleton_for(feature_dim: int) -> Skeleton:
    for skeleton in BUILTIN_SKELETONS.values():
        if skeleton.feature_dim == feature_dim:
            return skeleton
    raise MotionDataError("corpus", f"no built-in skeleton has {feature_dim}-wide features")


# ---- run context ----------------------------------------------------------------------------


ReportFn = Callable[[dict[str, float], Path | None], None]


@dataclass(frozen=True)
class Parallel:
    """This process's place in a data-parallel run (``torch.distributed`` already initialised when ``world`` > 1).

    Every process draws the same global batch from the same seeded generator and trains on its ``part`` of it;
    DDP averages the gradients, so N processes take the steps one process takes with the same global batch.
    Only the lead process writes files; ``report`` (when set) is called on every process after each checkpoint.
    """

    rank: int = 0
    world: int = 1
    report: ReportFn | None = None

    @property
    def lead(self) -> bool:
        return self.rank == 0

    def part(self, batch_size: int) -> slice:
        """This process's contiguous, equal share of a global batch."""
        if batch_size % self.world:
            reason = f"batch_size {batch_size} does not split evenly over {self.world} workers"
            raise MotionDataError("pretrain", reason)
        size = batch_size // self.world
        return slice(self.rank * size, (self.rank + 1) * size)

    def wrap(self, module: nn.Module) -> nn.Module:
        """DDP around ``module`` in a parallel run (gradients averaged over processes), else ``module`` itself."""
        if self.world == 1:
            return module
        device = next(module.parameters()).device
        ids = [device] if device.type == "cuda" else None
        return nn.parallel.DistributedDataParallel(module, device_ids=ids)

    def mean(self, values: dict[str, float]) -> dict[str, float]:
        """Each value averaged over processes: shard means of equal shards average to the global batch's."""
        if self.world == 1:
            return values
        device = torch.device("cuda", torch.cuda.current_device()) if dist.get_backend() == "nccl" else None
        packed = torch.tensor(list(values.values()), dtype=torch.float64, device=device)
        dist.all_reduce(packed)
        return dict(zip(values, (packed / self.world).tolist(), strict=True))


SINGLE = Parallel()


@dataclass
class Run:
    """What every stage needs: config, data (in CPU memory), output places, the progress hook, the device."""

    config: PretrainConfig
    out_dir: Path
    normalizer: Normalizer
    skeleton: Skeleton
    train: MotionSet
    test: MotionSet
    run_hash: str
    progress: ProgressFn | None
    weights: Tensor | None = None  # per train clip draw weights (``added_share``); None: uniform
    metrics: dict[str, float] = field(default_factory=dict)
    parallel: Parallel = SINGLE
    device: torch.device = CPU

    @property
    def checkpoints(self) -> Path:
        return self.out_dir / CHECKPOINTS

    def local(self, batch: Batch) -> Batch:
        """This process's part of a global batch, on the run's device."""
        return take(batch, self.parallel.part(batch.motion.shape[0])).to(self.device)

    def log(self, stage: str, step: int, values: dict[str, float]) -> None:
        if not self.parallel.lead:
            return
        line = json.dumps({"stage": stage, "step": step, **{k: round(v, 6) for k, v in values.items()}})
        with open(self.out_dir / LOSS_LOG, "a", encoding="utf-8") as handle:
            handle.write(line + "\n")

    def report(self, stage: str, step: int, total: int, values: dict[str, float]) -> None:
        if self.progress is not None:
            self.progress(stage, step, total, values)


def _load_data(
    corpus_dir: Path, text_encoder: TextEncoder | None, require_stats: bool = True
) -> tuple[Normalizer, MotionSet, MotionSet]:
    """Normaliser, train and test sets. Without Mean/Std files (and ``require_stats`` off) they come from train."""
    train_clips = read_clips(corpus_dir, split_ids(corpus_dir, "train"))
    if require_stats or (corpus_dir / "Mean.npy").is_file():
        normalizer = Normalizer(*HumanML3DReader(corpus_dir, split=None, feature_dim=None).mean_std())
    else:
        normalizer = compute_mean_std([c.motion for c in train_clips])
    train = build_motion_set(train_clips, normalizer, text_encoder)
    test_clips = read_clips(corpus_dir, split_ids(corpus_dir, "test"))
    test = build_motion_set(test_clips, normalizer, text_encoder, train.content_labels, train.style_labels)
    if train.motions[0].shape[1] != normalizer.dim:
        raise MotionDataError(
            str(corpus_dir), f"features are {train.motions[0].shape[1]} wide, Mean/Std {normalizer.dim}"
        )
    return normalizer, train, test


# ---- shared training-loop pieces --------------------------------------------------------------


def lr_at(config: PretrainConfig, base_lr: float, progress: float, step: int) -> float:
    """Linear warm-up over ``warmup_steps``, then cosine decay to ``min_lr_ratio`` at ``progress`` = 1."""
    if step < config.warmup_steps:
        return base_lr * (step + 1) / config.warmup_steps
    floor = config.min_lr_ratio
    return base_lr * (floor + (1 - floor) * 0.5 * (1 + math.cos(math.pi * min(progress, 1.0))))


@dataclass
class LoopState:
    step: int = 0
    elapsed: float = 0.0
    cpu: float = 0.0  # process CPU seconds: on shared cores, a steadier cost measure than wall time
    generator: torch.Generator = field(default_factory=torch.Generator)


def _on_cpu(value: Any) -> Any:
    """``value`` with every tensor in it on CPU: a checkpoint written on a GPU resumes on any device."""
    if isinstance(value, Tensor):
        return value.cpu()
    if isinstance(value, dict):
        return {k: _on_cpu(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return type(value)(_on_cpu(v) for v in value)
    return value


def _rng_state(loop: LoopState, optimizer: torch.optim.Optimizer, device: torch.device) -> dict[str, Any]:
    """Optimizer and RNG states; with CUDA also its RNG (dropout draws there), else exactly the CPU run's state."""
    state = {
        "optimizer": _on_cpu(optimizer.state_dict()),
        "generator": loop.generator.get_state(),
        "torch_rng": torch.get_rng_state(),
    }
    if device.type == "cuda":
        state["cuda_rng"] = torch.cuda.get_rng_state(device)
    return state


def _resume(
    run: Run, stage: str, modules: dict[str, nn.Module], optimizer: torch.optim.Optimizer, loop: LoopState
) -> bool:
    """Restore weights, optimizer and RNGs from the stage's checkpoint; True when the stage had finished.

    Weights load into ``modules`` where they are; the optimizer moves its (CPU-saved) state to its parameters.
    """
    resumed = load_checkpoint(run.checkpoints, stage, run.run_hash, modules)
    if resumed is None:
        return False
    optimizer.load_state_dict(resumed.state["optimizer"])
    loop.generator.set_state(resumed.state["generator"])
    torch.set_rng_state(resumed.state["torch_rng"])
    if run.device.type == "cuda" and "cuda_rng" in resumed.state:
        torch.cuda.set_rng_state(resumed.state["cuda_rng"], run.device)
    loop.step, loop.elapsed = resumed.record.step, resumed.record.metrics.get("elapsed_s", 0.0)
    run.metrics.update({k: v for k, v in resumed.record.metrics.items() if k != "elapsed_s"})
    return resumed.record.done


def _checkpoint(
    run: Run,
    stage: str,
    total: int,
    done: bool,
    modules: dict[str, nn.Module],
    state: dict[str, Any],
    loop: LoopState,
    metrics: dict[str, float] | None = None,
) -> None:
    record = StageCheckpoint(
        stage=stage,
        step=loop.step,
        total=total,
        done=done,
        config_hash=run.run_hash,
        folder=step_folder(loop.step),
        metrics={"elapsed_s": loop.elapsed, **(metrics or {})},
    )
    if run.parallel.lead:
        save_checkpoint(run.checkpoints, record, modules, state)
    if run.parallel.report is not None:
        folder = stage_dir(run.checkpoints, stage) / record.folder if run.parallel.lead else None
        run.parallel.report({"step": float(loop.step), **record.metrics, **(metrics or {})}, folder)


def _train_loop(
    run: Run,
    stage: str,
    modules: dict[str, nn.Module],
    optimizer: torch.optim.Optimizer,
    loss_fn: Callable[[Batch, torch.Generator], tuple[Tensor, dict[str, float]]],  # global CPU batch in, part's loss
    settings: tuple[int, float],
    finish: Callable[[], dict[str, float]],
) -> None:
    """Run ``loss_fn`` for ``total`` steps with checkpoints; resumes where it stopped.

    The length is a step count, never a time: the same config and seed give the same weights on a busy machine.
    Every process of a data-parallel run draws the same global batch (on CPU); ``loss_fn`` moves its own part
    (``run.local``) to the device.
    """
    total, base_lr = settings
    loop = LoopState(generator=torch.Generator().manual_seed(run.config.seed * 1000 + STAGES.index(stage) + 1))
    if _resume(run, stage, modules, optimizer, loop):
        return
    params = [p for group in optimizer.param_groups for p in group["params"]]
    for module in modules.values():
        module.train()
    while loop.step < total:
        started, cpu_started = time.perf_counter(), time.process_time()
        lr = lr_at(run.config, base_lr, loop.step / total, loop.step)
        for group in optimizer.param_groups:
            group["lr"] = lr
        batch = sample_batch(
            run.train, run.config.batch_size, run.config.max_frames, loop.generator, run.config.bucket, run.weights
        )
        loss, parts = loss_fn(batch, loop.generator)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(params, run.config.grad_clip)
        optimizer.step()
        loop.step += 1
        loop.elapsed += time.perf_counter() - started
        loop.cpu += time.process_time() - cpu_started
        values = {**run.parallel.mean({"loss": float(loss.detach()), **parts}), "lr": lr}
        if loop.step % run.config.log_every == 0 or loop.step == 1:
            run.log(stage, loop.step, {**values, "elapsed_s": loop.elapsed, "cpu_s": loop.cpu})
        if loop.step % run.config.checkpoint_every == 0:
            _checkpoint(run, stage, total, False, modules, _rng_state(loop, optimizer, run.device), loop)
        run.report(stage, loop.step, total, values)
    for module in modules.values():
        module.eval()
    final = finish()
    run.metrics.update(final)
    _checkpoint(run, stage, total, True, modules, _rng_state(loop, optimizer, run.device), loop, final)
    run.log(stage, loop.step, {**final, "elapsed_s": loop.elapsed, "done": 1.0})


# ---- stage a: prior -----------------------------------------------------------------------------


def build_prior(config: PretrainConfig, n_feats: int, text_dim: int) -> MDM:
    """The seeded prior, initialised on CPU (the same weights whichever device it then trains on)."""
    torch.manual_seed(config.seed)
    overrides = {
        name: value
        for name, value in (
            ("latent_dim", config.prior_latent_dim),
            ("ff_size", config.prior_ff_size),
            ("num_layers", config.prior_layers),
        )
        if value is not None
    }
    return MDM(MDMConfig.named(config.size, n_feats=n_feats, text_dim=text_dim, dropout=config.dropout, **overrides))


def take(batch: Batch, part: slice) -> Batch:
    """Rows ``part`` of every field of a batch."""
    return Batch(*(getattr(batch, f.name)[part] for f in fields(batch)))


def cond_drop(prior: MDM, batch_size: int) -> Tensor:
    """MDM's classifier-free condition dropout mask (B,), drawn here for the whole global batch.

    The same draw MDM makes inside ``forward`` in training (global RNG, same shape), so one process trains as
    before, and each process of a data-parallel run keeps its part of the one mask.
    """
    if not prior.training or prior.config.cond_mask_prob <= 0:
        return torch.zeros(batch_size, dtype=torch.bool)
    return (torch.rand(batch_size, 1) < prior.config.cond_mask_prob).view(-1)


def prior_loss(
    prior: MDM,
    schedule: NoiseSchedule,
    batch: Batch,
    run: Run,
    generator: torch.Generator,
    net: nn.Module | None = None,
) -> tuple[Tensor, dict[str, float]]:
    """x0 masked MSE on normalised features plus weighted geometric losses on de-normalised ones (fp32).

    Every draw is for the global batch, on CPU, then cut to this process's part and moved to the device;
    ``net`` is ``prior`` or its DDP wrapper.
    """
    b = batch.motion.shape[0]
    t = sample_timesteps(b, schedule, generator)
    noise = torch.randn(batch.motion.shape, generator=generator)
    if run.config.input_perturbation > 0:  # the target stays x0: only the input is off the training manifold
        noise = noise + run.config.input_perturbation * torch.randn(batch.motion.shape, generator=generator)
    drop = cond_drop(prior, b)
    part = run.parallel.part(b)
    batch, t = run.local(batch), t[part]  # t stays on CPU, beside the schedule's tables it indexes
    noise, drop = noise[part].to(run.device), drop[part].to(run.device)
    x0, mask = batch.motion, batch.mask
    x_t = q_sample(schedule, x0, t, noise)
    with bf16_autocast(run.config.bf16, run.device):
        steps = schedule.timesteps[t].to(run.device)
        x0_hat = (net or prior)(x_t, steps, batch.text_embed, mask, force_uncond=drop)
    x0_hat = x0_hat.float()
    mse = masked_mse(x0_hat, x0, mask).mean()
    cfg = run.config
    parts = {"mse": float(mse.detach())}
    loss = mse
    if cfg.lambda_pos or cfg.lambda_vel or cfg.lambda_foot:
        mean = torch.from_numpy(run.normalizer.mean).to(run.device)
        std = torch.from_numpy(run.normalizer.std).to(run.device)
        geo = geometric_losses(x0_hat * std + mean, x0 * std + mean, mask, run.skeleton)
        for name, weight in (("pos", cfg.lambda_pos), ("vel", cfg.lambda_vel), ("foot", cfg.lambda_foot)):
            term = geo[name].mean()
            parts[name] = float(term.detach())
            loss = loss + weight * term
    return loss, parts


@torch.no_grad()
def held_out_prior_mse(prior: MDM, schedule: NoiseSchedule, run: Run, seed: int = 123) -> float:
    """Mean x0 MSE on the test split at seeded timesteps: a loss that does not depend on the training batches."""
    generator = torch.Generator().manual_seed(seed)
    total, count = 0.0, 0
    for batch in iter_batches(run.test, run.config.batch_size, run.config.max_frames):
        t = sample_timesteps(batch.motion.shape[0], schedule, generator)
        noise = torch.randn(batch.motion.shape, generator=generator).to(run.device)
        batch = batch.to(run.device)
        x_t = q_sample(schedule, batch.motion, t, noise)
        with bf16_autocast(run.config.bf16, run.device):
            steps = schedule.timesteps[t].to(run.device)
            x0_hat = prior(x_t, steps, batch.text_embed, batch.mask, force_uncond=False).float()
        total += float(masked_mse(x0_hat, batch.motion, batch.mask).sum())
        count += batch.motion.shape[0]
    return total / max(count, 1)


def train_prior(run: Run) -> MDM:
    cfg = run.config
    prior = build_prior(cfg, run.normalizer.dim, run.train.text_embed.shape[1]).to(run.device)
    schedule = NoiseSchedule.cosine()
    optimizer = torch.optim.AdamW(prior.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    net = run.parallel.wrap(prior)
    _train_loop(
        run,
        "prior",
        {"prior": prior},
        optimizer,
        lambda batch, gen: prior_loss(prior, schedule, batch, run, gen, net),
        (cfg.prior_steps, cfg.lr),
        lambda: {"prior_test_mse": held_out_prior_mse(prior, schedule, run)},
    )
    return prior.eval()


# ---- stage b: motion encoder ------------------------------------------------------------------


def build_motion_encoder(config: PretrainConfig, prior: MDM) -> MotionEncoder:
    """An encoder reading through the prior's input layer (shared module, frozen by the caller), on the prior's
    device; its own layers are initialised on CPU from the seed first."""
    torch.manual_seed(config.seed + 1)
    enc_config = MotionEncoderConfig.named(
        config.size,
        input_dim=prior.config.n_feats,
        d_model=prior.config.latent_dim,
        text_dim=prior.config.text_dim,
        dropout=config.dropout,
    )
    return MotionEncoder(enc_config, prior.input_process).to(next(prior.parameters()).device)


@torch.no_grad()
def encode_set(encoder: MotionEncoder, data: MotionSet, batch_size: int, max_frames: int) -> tuple[Tensor, Tensor]:
    """Motion embeddings and first-caption embeddings of every clip, (N, E) each, on CPU (encoded where
    ``encoder`` is)."""
    device = next(encoder.parameters()).device
    motions, texts = [], []
    for batch in iter_batches(data, batch_size, max_frames):
        motions.append(encoder(batch.motion.to(device), batch.mask.to(device)).cpu())
        texts.append(batch.text_embed)
    return torch.cat(motions), torch.cat(texts)


def encoder_metrics(encoder: MotionEncoder, run: Run) -> dict[str, float]:
    """Held-out semantic loss and, with at least one pool of 32 clips, text-to-motion R@1."""
    motion, text = encode_set(encoder.eval(), run.test, run.config.batch_size, run.config.max_frames)
    out = {"encoder_test_loss": float(semantic_loss(motion, text))}
    if motion.shape[0] >= RETRIEVAL_POOL:
        out["encoder_r1"] = retrieval_r_at_k(motion.numpy(), text.numpy(), k=1, pool=RETRIEVAL_POOL, seed=0)
    return out


def train_motion_encoder(run: Run, prior: MDM) -> MotionEncoder:
    """Stage b on ``run.device`` (``prior`` moves there too: the encoder shares its input layer)."""
    cfg = run.config
    encoder = build_motion_encoder(cfg, prior.to(run.device))
    prior.input_process.requires_grad_(False)  # the denoiser's layer is shared, not retrained
    trainable = [p for p in encoder.parameters() if p.requires_grad]
    optimizer = torch.optim.AdamW(trainable, lr=cfg.encoder_lr, weight_decay=cfg.weight_decay)
    net = run.parallel.wrap(encoder)

    def loss_fn(batch: Batch, _: torch.Generator) -> tuple[Tensor, dict[str, float]]:
        batch = run.local(batch)
        with bf16_autocast(cfg.bf16, run.device):
            motion = net(batch.motion, batch.mask)
        return semantic_loss(motion.float(), batch.text_embed), {}

    _train_loop(
        run,
        "motion_encoder",
        {"motion_encoder": encoder},
        optimizer,
        loss_fn,
        (cfg.encoder_steps, cfg.encoder_lr),
        lambda: encoder_metrics(encoder, run),
    )
    prior.input_process.requires_grad_(True)
    return encoder.eval()


# ---- stage c: evaluators ----------------------------------------------------------------------


def joints_of(data: MotionSet, normalizer: Normalizer, skeleton: Skeleton, max_frames: int) -> tuple[Tensor, Tensor]:
    """Joint positions (N, T, J, 3) of every clip's first ``max_frames`` frames, padded, with the frame mask."""
    return pad_batch(
        [features_to_joints(m[:max_frames], skeleton, normalizer.mean, normalizer.std) for m in data.motions]
    )


def _fit_one(
    run: Run, name: str, labels: list[str], train: tuple[Tensor, Tensor, Tensor], test: tuple[Tensor, Tensor, Tensor]
) -> MotionClassifier | None:
    """Train (or reload from its checkpoint) one classifier; records held-out accuracy in ``run.metrics``."""
    keep = train[2] >= 0
    if len(labels) < 2 or int(keep.sum()) == 0:
        return None
    torch.manual_seed(run.config.seed + 2 + len(name))
    model = make_classifier(len(labels), run.skeleton.n_joints, run.config.classifier_size).to(run.device)
    stage = f"evaluators_{name}"
    resumed = load_checkpoint(run.checkpoints, stage, run.run_hash, {name: model})
    if resumed is not None:
        run.metrics.update({k: v for k, v in resumed.record.metrics.items() if k != "elapsed_s"})
        return model.eval()
    history = fit_classifier(
        model,
        (train[0][keep], train[1][keep], train[2][keep]),
        run.config.classifier_epochs,
        lr=run.config.classifier_lr,
        seed=run.config.seed,
    )
    for epoch, loss in enumerate(history, 1):
        run.log(stage, epoch, {"loss": loss})
    metrics: dict[str, float] = {}
    tested = test[2] >= 0
    if int(tested.sum()) > 0:
        metrics[f"{name}_accuracy"] = classifier_accuracy(model, test[0][tested], test[1][tested], test[2][tested])
    run.metrics.update(metrics)
    loop = LoopState(step=run.config.classifier_epochs)
    _checkpoint(run, stage, loop.step, True, {name: model}, {}, loop, metrics)
    run.report("evaluators", 1 + (name == "style_classifier"), 2, metrics)
    return model.eval()


def train_evaluators(run: Run) -> dict[str, MotionClassifier | None]:
    cfg = run.config
    train_joints, train_mask = joints_of(run.train, run.normalizer, run.skeleton, cfg.max_frames)
    test_joints, test_mask = joints_of(run.test, run.normalizer, run.skeleton, cfg.max_frames)
    out: dict[str, MotionClassifier | None] = {}
    for name, labels, attr in (
        ("content_classifier", run.train.content_labels, "content"),
        ("style_classifier", run.train.style_labels, "style"),
    ):
        train = (train_joints, train_mask, getattr(run.train, attr))
        test = (test_joints, test_mask, getattr(run.test, attr))
        out[name] = _fit_one(run, name, labels, train, test)
    return out


# ---- the whole procedure ----------------------------------------------------------------------


def for_corpus(config: PretrainConfig, corpus_dir: str | Path) -> PretrainConfig:
    """``config`` as it acts on this corpus: ``added_share`` is dropped where no clips were added, so a base
    corpus trained under the expanded corpora's config keeps the models (and hash) of the plain one."""
    if config.added_share is not None and not (Path(corpus_dir) / f"{ADDED_SPLIT}.txt").is_file():
        return config.model_copy(update={"added_share": None})
    return config


def _weights(config: PretrainConfig, corpus_dir: Path, train: MotionSet) -> Tensor | None:
    if config.added_share is None:
        return None
    return share_weights(train.ids, split_ids(corpus_dir, ADDED_SPLIT), config.added_share)


def run_hash(config: PretrainConfig, fingerprint: str) -> str:
    """What checkpoints are keyed by: the config and the corpus together."""
    return hashlib.sha256(f"{config.config_hash()}:{fingerprint}".encode()).hexdigest()[:16]


def _stale_checkpoints(out: Path, current: str) -> bool:
    stages = [*STAGES[:2], "evaluators_content_classifier", "evaluators_style_classifier"]
    return any(
        (record := read_record(out / CHECKPOINTS, s)) is not None and record.config_hash != current for s in stages
    )


def _threads(config: PretrainConfig) -> None:
    torch.set_num_threads(config.threads or os.cpu_count() or 1)


def pretrain(
    corpus_dir: str | Path,
    out_dir: str | Path,
    config: PretrainConfig | None = None,
    progress: ProgressFn | None = None,
    text_encoder: TextEncoder | None = None,
    parallel: Parallel = SINGLE,
    device: torch.device | None = None,
    evaluators: bool = True,
) -> BaseModelsInfo | None:
    """Train all three stages into ``out_dir`` (resuming from its checkpoints) and save the base models there;
    ``evaluators`` False leaves stage c out (a protocol that scores with judges of its own needs no others).

    ``device``: where to train; None = ``pick_device()`` (a Ray Train worker passes its own GPU). In a
    data-parallel run every process trains the prior and the motion encoder together; then the lead alone
    trains the small evaluators and saves, and the other processes return None.
    """
    corpus, out = Path(corpus_dir), Path(out_dir)
    config = for_corpus(config or PretrainConfig(), corpus)
    device = device or pick_device()
    fingerprint = corpus_fingerprint(corpus)
    _threads(config)
    out.mkdir(parents=True, exist_ok=True)
    (out / BASE_JSON).unlink(missing_ok=True)  # base.json marks a complete folder; this one is not, until the end
    encoder = text_encoder or make_text_encoder(config.text_encoder)
    normalizer, train, test = _load_data(corpus, encoder)
    run = Run(
        config, out, normalizer, skeleton_for(normalizer.dim), train, test, run_hash(config, fingerprint), progress
    )
    run.parallel, run.device, run.weights = parallel, device, _weights(config, corpus, train)
    prior = train_prior(run)
    motion_encoder = train_motion_encoder(run, prior)
    if not parallel.lead:
        return None
    run.parallel = SINGLE
    if evaluators:
        classifiers = train_evaluators(run)
        labels = {"content": run.train.content_labels, "style": run.train.style_labels}
        save_evaluators(out / EVALUATORS_DIR, classifiers, labels, fingerprint, run.metrics)
    info = _info(run, prior, motion_encoder, fingerprint)
    BaseModels(info=info, prior=prior.cpu(), motion_encoder=motion_encoder.cpu(), normalizer=normalizer).save(out)
    return info


def _info(run: Run, prior: MDM, encoder: MotionEncoder, fingerprint: str) -> BaseModelsInfo:
    return BaseModelsInfo(
        size=run.config.size,
        text_encoder=run.config.text_encoder,
        fps=20.0,
        max_frames=run.config.max_frames,
        prior=config_dict(prior.config),
        motion_encoder=config_dict(encoder.config),
        corpus_fingerprint=fingerprint,
        config_hash=run.config.config_hash(),
        pretrain_config=run.config.model_dump(),
        metrics=dict(sorted(run.metrics.items())),
    )


def fit_evaluators(
    corpus_dir: str | Path, work_dir: str | Path, config: PretrainConfig | None = None
) -> dict[str, float]:
    """Stage c alone on any labelled corpus (no prior, no text encoder), saved as an evaluators folder at
    ``work_dir``; returns the held-out content/style accuracy.

    Without train/test split files the split is a stable hash of the ids (``training_data.split_ids``).
    """
    config = config or PretrainConfig()
    _threads(config)
    corpus, work = Path(corpus_dir), Path(work_dir)
    work.mkdir(parents=True, exist_ok=True)
    normalizer, train, test = _load_data(corpus, None, require_stats=False)
    fingerprint = corpus_fingerprint(corpus)
    run = Run(config, work, normalizer, skeleton_for(normalizer.dim), train, test, run_hash(config, fingerprint), None)
    run.device = pick_device()
    classifiers = train_evaluators(run)
    labels = {"content": train.content_labels, "style": train.style_labels}
    save_evaluators(work, classifiers, labels, fingerprint, run.metrics)
    return {**run.metrics, "train_clips": float(len(train)), "test_clips": float(len(test))}


def _complete(out: Path, fingerprint: str, config_hash: str, evaluators: bool = True) -> bool:
    """True when ``out`` holds base models made from this corpus with this config (and evaluators, if wanted)."""
    try:
        info = BaseModelsInfo.model_validate_json((out / BASE_JSON).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    files_ok = all((out / f"{n}.safetensors").is_file() for n in ("prior", "motion_encoder"))
    files_ok = files_ok and (out / "Mean.npy").is_file() and (not evaluators or evaluators_folder(out) is not None)
    return files_ok and info.corpus_fingerprint == fingerprint and info.config_hash == config_hash


def ensure_base_models(
    corpus_dir: str | Path,
    out_dir: str | Path,
    size: str = "small",
    seed: int = 0,
    progress: ProgressFn | None = None,
    config: PretrainConfig | None = None,
    text_encoder: TextEncoder | None = None,
    runner: Callable[[Path, Path, PretrainConfig], object] | None = None,
    evaluators: bool = True,
) -> Path:
    """``out_dir`` if it already holds matching base models, else pretrain into it (stale checkpoints cleared).

    ``runner(corpus, out, config)`` trains instead of the one-process ``pretrain`` (the Ray Train workflow).
    ``evaluators`` False: the prior and the motion encoder only.
    """
    config = config or PretrainConfig.for_size(size, seed=seed)
    if config.from_mdm is not None:  # the official prior: only the motion encoder and evaluators are trained
        from motionaug.augment.training.from_mdm import ensure_from_mdm, source_of

        if runner is not None:
            raise MotionDataError("pretrain --workers", "not supported with --from-mdm, which trains in one process")
        return ensure_from_mdm(corpus_dir, out_dir, source_of(config), config, progress)
    out = Path(out_dir)
    config = for_corpus(config, corpus_dir)
    fingerprint = corpus_fingerprint(corpus_dir)
    if _complete(out, fingerprint, config.config_hash(), evaluators):
        return out
    if (out / BASE_JSON).is_file():  # never replace models silently: say why they are made again
        LOG.warning(
            "%s: base models there were made from another corpus or pre-training config; pre-training again", out
        )
    if _stale_checkpoints(out, run_hash(config, fingerprint)):  # made from another corpus or config: start over
        shutil.rmtree(out / CHECKPOINTS, ignore_errors=True)
        (out / LOSS_LOG).unlink(missing_ok=True)
    if runner is not None:
        runner(Path(corpus_dir), out, config)
        return out
    pretrain(corpus_dir, out, config, progress, text_encoder, evaluators=evaluators)
    return out
