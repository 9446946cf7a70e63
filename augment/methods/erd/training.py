"""Train Style-ERD (Tao et al., CVPR 2022, sec. 3.2) on labelled clips; save and load the generator.

``train_erd`` runs two stages at fixed step counts, bit-identical for the same clips, config, seed and threads:
the content classifier D_C (then frozen: its features are Eq. 7's phi), then the generator against the FT-Att
discriminator (LSGAN, Eqs. 4-6), each batch both reconstructed (Eqs. 2-3) and transferred (sec. 3.2's targets).
The paper's recipe alone does not stylize at a CPU budget of a few thousand steps, so the defaults add an output
skip, a class-conditional moment loss and neutral-heavy batches, and re-weight Eq. 8 (docs/internals.md;
``ErdTrainConfig`` says how to get the paper's recipe back). Output folder, through a temporary sibling:
``erd.safetensors``, ``critics.safetensors`` (for inspection) and ``erd.json`` (``ErdArtifact``).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
import torch.nn.functional as F
from pydantic import BaseModel, ConfigDict, Field, model_serializer, model_validator
from safetensors.torch import load_file
from torch import Tensor, nn

from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.io import read_json_model
from motionaug.augment.methods.base import Progress
from motionaug.augment.methods.common import run_steps, write_model_folder
from motionaug.augment.methods.hooks import HookSpec, LossBatch, LossTerms, loss_terms, split_spec
from motionaug.augment.motion.features import compute_mean_std, recover_from_ric
from motionaug.augment.motion.rotations import cont6d_to_matrix
from motionaug.models.style_erd import (
    NEUTRAL,
    ContentClassifier,
    ErdNetwork,
    FtAttDiscriminator,
    StyleClassifier,
    StyleErdConfig,
    channel_groups,
)
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.skeleton import T2M

WEIGHTS_FILE = "erd.safetensors"
CRITICS_FILE = "critics.safetensors"
META_FILE = "erd.json"


class ErdTrainConfig(BaseModel):
    """How to train Style-ERD. Defaults follow the paper where it gives a value (sec. 3.2, supp. A)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    steps: int = Field(3000, ge=1, description="generator/critic steps (fixed count; there is no time cap)")
    batch_size: int = Field(32, ge=2, description="real windows per step (supp. A: 16)")
    window_s: float = Field(1.6, gt=0, description="generator training window, seconds (32 frames at 20 fps)")
    disc_window_s: float = Field(0.4, gt=0, description="FT-Att window: the paper's 24 frames at 60 fps = 0.4 s")
    disc_stride_s: float = Field(0.2, gt=0, description="stride of the critic's sub-windows in a training window")
    classifier_steps: int = Field(300, ge=1, description="content-classifier steps, before the GAN stage")
    classifier_batch_size: int = Field(64, ge=2)
    # supp. A trains with Adam 1e-4 / 5e-5 for 2000 epochs (~500k steps at batch 16); a CPU budget allows a few
    # thousand steps, so the rates are 30x / 10x the paper's. The defaults below are the recipe that stylizes at that
    # budget; the paper's own: residual_output=False, neutral_share=0, w_moments=0,
    # w_adv=1, w_per=0.1, lr_generator=1e-4, lr_discriminator=5e-5.
    lr_generator: float = Field(3e-3, gt=0, description="Adam; supp. A: 1e-4 (see above)")
    lr_discriminator: float = Field(5e-4, gt=0, description="Adam; supp. A: 5e-5 (see above)")
    lr_classifier: float = Field(1e-3, gt=0)
    # Eq. 8 has w_adv = 1, w_per = 0.1. With the moment loss doing the styling, an adversarial term at full weight
    # undoes it (the moment loss stops falling), and the perceptual term at 0.1 is too small beside the generator
    # loss, so content drifts.
    w_adv: float = Field(0.1, ge=0, description="Eq. 8 (paper: 1; see above)")
    w_per: float = Field(1.0, ge=0, description="Eq. 8 (paper: 0.1; see above)")
    # Eq. 9's w_gp = 128 does not carry over as a number. The authors' code applies it to the gradient of the
    # *batch-mean* score (summed squares / B), i.e. 128 / B^2 per sample = 0.5 at their batch of 16, on raw
    # positions; Eq. 6 here is the per-sample mean of |grad D|^2 on normalised inputs. Measured: with 128 in this
    # form the critic stays flat (D ~ 0 on real and fake, L_cri ~ 1.9, L_adv ~ 0.003: no style signal) even
    # against a poor generator; with 1 it separates them (D(real) ~ 0.8, D(fake) ~ -0.7 within 300 steps).
    w_gp: float = Field(0.5, ge=0, description="Eq. 9, per-sample mean |grad D|^2 (the paper's 128 / 16^2)")
    # Style supervision beyond the paper's losses (its recipe does not stylize within a CPU budget): both are
    # applied to the transfer windows only.
    w_style: float = Field(
        0.0, ge=0, description="cross-entropy of a frozen style classifier on the transfer, against the target style"
    )
    w_moments: float = Field(
        1.0,
        ge=0,
        description="class-conditional moment matching: the transfer's per-channel change in window mean and std "
        "against the change between the (source style, content) and (target style, content) averages of real clips",
    )
    neutral_share: float = Field(
        0.5,
        ge=0,
        lt=1,
        description="share of each batch drawn from neutral clips (the neutral -> style pairs of sec. 3.2); 0 draws "
        "clips uniformly, so with 6 other styles only 1 in 7 pairs goes from neutral",
    )
    content_dropout: float = Field(
        0.2, ge=0, le=1, description="share of generator inputs shown as unknown content (trains that initial state)"
    )
    seed: int = 0
    threads: int = Field(
        1,
        ge=1,
        description="torch threads while training (part of what makes runs identical); the tensors are small, "
        "so one thread is fastest and a second one only spin-waits (18x slower on a busy 2-core machine)",
    )
    log_every: int = Field(50, ge=1, description="history interval, steps")
    # network sizes (supp. A); smaller values for tests and latency experiments
    latent: int = Field(32, ge=1)
    enc_hidden: int = Field(64, ge=1)
    neutral_layers: int = Field(6, ge=1)
    style_layers: int = Field(4, ge=1)
    dec_hidden: tuple[int, ...] = (64, 128, 256)
    disc_channels: tuple[int, int] = (96, 64)
    cls_channels: tuple[int, int] = (96, 64)
    residual_output: bool = Field(True, description="x' = x + D(z', S_hat) (see StyleErdConfig)")
    attention: bool = Field(True, description="FT-Att discriminator; False: Table 1's multi-class baseline")
    learned_init: bool = Field(True, description="learned initial states; False: zeros (Table 1 ablation)")
    loss_terms: LossTerms = Field(
        (), description="generator-loss terms registered by name (augment.methods.hooks.loss_terms), with weights"
    )

    @model_serializer(mode="wrap")
    def _dump(self, handler: Any) -> dict[str, Any]:
        """``loss_terms`` left out when empty: the keys of the models trained before it existed stay the same."""
        data = handler(self)
        if not self.loss_terms:
            data.pop("loss_terms", None)
        return data

    @model_validator(mode="after")
    def _check(self) -> ErdTrainConfig:
        if self.style_layers > self.neutral_layers:
            raise ValueError(f"style_layers {self.style_layers} > neutral_layers {self.neutral_layers}")
        if self.disc_window_s > self.window_s:
            raise ValueError(f"disc_window_s {self.disc_window_s} longer than window_s {self.window_s}")
        return self

    def frames(self, fps: float) -> tuple[int, int, int]:
        """(window, critic window, critic stride) in frames at ``fps``."""
        window = max(2, round(self.window_s * fps))
        disc = max(2, round(self.disc_window_s * fps))
        return window, min(disc, window), max(1, round(self.disc_stride_s * fps))


ERD_SIZES: dict[str, dict[str, Any]] = {
    "tiny": {  # seconds-long smoke runs: a small network and a short content-classifier stage
        "latent": 8,
        "enc_hidden": 16,
        "neutral_layers": 2,
        "style_layers": 1,
        "dec_hidden": (16, 16, 16),
        "disc_channels": (8, 8),
        "cls_channels": (8, 8),
        "classifier_steps": 2,
        "classifier_batch_size": 4,
    },
    "small": {},  # the defaults of ``ErdTrainConfig``
    "paper": {},  # the paper's widths are the defaults
}


class ErdTrain(BaseModel):
    """What a run config sets of Style-ERD's training (``method.params.train``): the schedule, the windows, the
    paper's optimiser rates and loss weights (Eqs. 8-9, supp. A) and its Table 1 ablations. The network's size is
    the run's ``base_models.size`` and its seed the run's (``recipe``)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    steps: int = Field(3000, ge=1, description="generator/critic steps (fixed count; there is no time cap)")
    batch_size: int = Field(32, ge=2, description="real windows per step (supp. A: 16)")
    window_s: float = Field(1.6, gt=0, description="generator training window, seconds (32 frames at 20 fps)")
    disc_window_s: float = Field(0.4, gt=0, description="FT-Att window: the paper's 24 frames at 60 fps = 0.4 s")
    lr_generator: float = Field(3e-3, gt=0, description="Adam; supp. A: 1e-4")
    lr_discriminator: float = Field(5e-4, gt=0, description="Adam; supp. A: 5e-5")
    w_adv: float = Field(0.1, ge=0, description="Eq. 8 (paper: 1)")
    w_per: float = Field(1.0, ge=0, description="Eq. 8 (paper: 0.1)")
    w_gp: float = Field(0.5, ge=0, description="Eq. 9, per-sample mean |grad D|^2 (the paper's 128 / 16^2)")
    attention: bool = Field(True, description="FT-Att discriminator; False: Table 1's multi-class baseline")
    learned_init: bool = Field(True, description="learned initial states; False: zeros (Table 1 ablation)")
    log_every: int = Field(50, ge=1, description="history interval, steps")
    loss_terms: tuple[HookSpec, ...] = Field(
        (), description="generator-loss terms by name (augment.methods.hooks.loss_terms; lab hooks), with weights"
    )

    def recipe(self, size: str = "small", seed: int = 0) -> ErdTrainConfig:
        """The full training config: these settings, the network of ``size`` (``ERD_SIZES``) and ``seed``."""
        if size not in ERD_SIZES:
            known = list(ERD_SIZES)
            where = "config base_models.size"
            raise MotionDataError(where, f"Style-ERD has no network size {size!r}; known: {known}")
        return ErdTrainConfig(**self.model_dump(), **ERD_SIZES[size], seed=seed)


class ErdArtifact(BaseModel):
    """``erd.json``: everything but the weights."""

    model_config = ConfigDict(extra="forbid")

    version: int = 1
    method: Literal["style_erd"] = "style_erd"
    network: dict[str, Any]
    styles: list[str]
    contents: list[str]
    fps: float
    normalizer: dict[str, list[float]]
    train: ErdTrainConfig
    data: dict[str, Any]
    classifier: dict[str, float]
    final: dict[str, float]
    history: list[dict[str, float]]
    seconds: float


# ---- data ---------------------------------------------------------------------------------------------------


@dataclass
class ErdData:
    """Labelled clips ready to sample: normalised float32 motions and label indices."""

    motions: list[np.ndarray]
    styles: np.ndarray  # (N,) style index, 0 = neutral
    contents: np.ndarray  # (N,) content index, len(content_names) = unknown
    style_names: tuple[str, ...]
    content_names: tuple[str, ...]
    fps: float
    mean: np.ndarray
    std: np.ndarray
    dropped_short: int


def prepare_data(
    clips: Sequence[MotionClip], window: int | None = None, config: ErdTrainConfig | None = None
) -> ErdData:
    """Check labels, compute the corpus Mean/Std, normalise, drop clips shorter than the training window.

    Every clip needs a style label (``neutral`` and at least one other style must occur); content may be None
    (the unknown-content slot) but at least two content labels must occur for the content classifier.
    """
    config = config or ErdTrainConfig()
    if not clips:
        raise MotionDataError("Style-ERD training", "no clips")
    fps = {float(c.fps) for c in clips}
    if len(fps) != 1:
        raise MotionDataError("Style-ERD training", f"clips mix frame rates {sorted(fps)}")
    rate = fps.pop()
    window = window or config.frames(rate)[0]
    unlabelled = [c.id for c in clips if not c.style]
    if unlabelled:
        raise MotionDataError(
            "Style-ERD training", f"{len(unlabelled)} clips without a style label, e.g. {unlabelled[0]}"
        )
    styles = sorted({c.style for c in clips if c.style})
    if NEUTRAL not in styles or len(styles) < 2:
        raise MotionDataError("Style-ERD training", f"need {NEUTRAL!r} and another style, got {styles}")
    style_names = (NEUTRAL, *[s for s in styles if s != NEUTRAL])
    content_names = tuple(sorted({c.content for c in clips if c.content}))
    if len(content_names) < 2:
        raise MotionDataError(
            "Style-ERD training", f"need 2+ content labels for the content classifier, got {content_names}"
        )
    for c in clips:
        m = np.asarray(c.motion)
        if m.ndim != 2 or m.shape[1] != T2M.feature_dim or not np.isfinite(m).all():
            raise MotionDataError(f"clip {c.id}", f"need finite (T, {T2M.feature_dim}) features, got shape {m.shape}")
    kept = [c for c in clips if c.n_frames >= window]
    if not kept:
        raise MotionDataError("Style-ERD training", f"no clip has the {window} frames of a training window")
    norm = compute_mean_std(c.motion for c in kept)
    return ErdData(
        motions=[((c.motion - norm.mean) / norm.std).astype(np.float32) for c in kept],
        styles=np.array([style_names.index(c.style) for c in kept]),
        contents=np.array([content_names.index(c.content) if c.content else len(content_names) for c in kept]),
        style_names=style_names,
        content_names=content_names,
        fps=rate,
        mean=norm.mean,
        std=norm.std,
        dropped_short=len(clips) - len(kept),
    )


# ---- losses -------------------------------------------------------------------------------------------------


def rotation_geodesic(pred6d: Tensor, real6d: Tensor) -> Tensor:
    """Half the rotation angle between 6D rotations (..., 6): ``acos(|q . q''|)`` of Eq. 2, without quaternions.

    With ``R = R_pred^T R_real``: ``cos(theta) = (tr R - 1) / 2`` and ``sin(theta) = |vee(R - R^T)| / 2``;
    atan2 of the two is stable at 0 and pi, unlike acos.
    """
    rel = cont6d_to_matrix(pred6d).transpose(-1, -2) @ cont6d_to_matrix(real6d)
    cos = (rel.diagonal(dim1=-2, dim2=-1).sum(-1) - 1.0) / 2.0
    skew = torch.stack(
        [rel[..., 2, 1] - rel[..., 1, 2], rel[..., 0, 2] - rel[..., 2, 0], rel[..., 1, 0] - rel[..., 0, 1]], -1
    )
    sin = torch.sqrt((skew**2).sum(-1) + 1e-12) / 2.0
    return torch.atan2(sin, cos) / 2.0


def class_moments(data: ErdData) -> tuple[Tensor, Tensor]:
    """(mean, std) of normalised channels per (style, content): averages over clips of each clip's mean over
    time and std over time, shape (n_styles, n_contents + 1, D); the last content slot averages every content
    of the style (used for clips without a content label)."""
    n_s, n_c = len(data.style_names), len(data.content_names) + 1
    dim = data.motions[0].shape[1]
    mu, sd, count = np.zeros((n_s, n_c, dim)), np.zeros((n_s, n_c, dim)), np.zeros((n_s, n_c, 1))
    for motion, s, c in zip(data.motions, data.styles, data.contents):
        m, d = motion.mean(axis=0), motion.std(axis=0)
        for slot in {int(c), n_c - 1}:
            mu[s, slot] += m
            sd[s, slot] += d
            count[s, slot] += 1
    # a (style, content) pair without clips falls back to the style's average over contents
    empty = count[..., 0] == 0
    mu, sd = mu / np.maximum(count, 1), sd / np.maximum(count, 1)
    mu[empty] = np.broadcast_to(mu[:, -1:], mu.shape)[empty]
    sd[empty] = np.broadcast_to(sd[:, -1:], sd.shape)[empty]
    return torch.from_numpy(mu.astype(np.float32)), torch.from_numpy(sd.astype(np.float32))


class ErdTrainer:
    """The two-player training state: generator, critic, frozen content classifier, optimisers, data sampler.

    ``sample()`` draws a batch; ``critic_step`` / ``generator_step`` apply one update each and return their
    losses; ``losses`` evaluates both without updating (tests use it on a fixed batch).
    """

    def __init__(self, data: ErdData, config: ErdTrainConfig) -> None:
        self.data, self.config = data, config
        self.window, self.disc_window, self.disc_stride = config.frames(data.fps)
        net_config = StyleErdConfig(
            styles=data.style_names,
            contents=data.content_names,
            enc_hidden=config.enc_hidden,
            latent=config.latent,
            neutral_layers=config.neutral_layers,
            style_layers=config.style_layers,
            dec_hidden=config.dec_hidden,
            disc_window=self.disc_window,
            disc_channels=config.disc_channels,
            cls_channels=config.cls_channels,
            residual_output=config.residual_output,
            attention=config.attention,
            learned_init=config.learned_init,
        )
        self.net = ErdNetwork(net_config)
        self.net.set_normalizer(torch.from_numpy(data.mean), torch.from_numpy(data.std))
        self.disc = FtAttDiscriminator(net_config)
        self.classifier = ContentClassifier(net_config)
        self.style_classifier = StyleClassifier(net_config)
        self.moments = class_moments(data)
        self.opt_g = torch.optim.Adam(self.net.parameters(), lr=config.lr_generator)
        self.opt_d = torch.optim.Adam(self.disc.parameters(), lr=config.lr_discriminator)
        self.rng = np.random.default_rng([config.seed, 1])
        groups = channel_groups(net_config.n_joints)
        self.groups = {k: torch.tensor(v) for k, v in groups.items()}
        self.rot_mean = self.net.mean[self.groups["rot"]].view(-1, 6)
        self.rot_std = self.net.std[self.groups["rot"]].view(-1, 6)
        self.labelled = np.flatnonzero(data.contents < len(data.content_names))
        self.neutral, self.styled = np.flatnonzero(data.styles == 0), np.flatnonzero(data.styles != 0)
        self.loss_terms = loss_terms.create_all(list(config.loss_terms), "config method.params.train.loss_terms")

    # -- sampling --

    def _windows(self, clip_idx: np.ndarray) -> Tensor:
        rows = []
        for i in clip_idx:
            motion = self.data.motions[int(i)]
            start = int(self.rng.integers(0, len(motion) - self.window + 1))
            rows.append(motion[start : start + self.window])
        return torch.from_numpy(np.stack(rows))

    def sample(self, batch_size: int | None = None) -> dict[str, Tensor]:
        """Real windows with labels, the sec. 3.2 transfer targets and the content the generator is shown."""
        n = batch_size or self.config.batch_size
        if self.config.neutral_share > 0:
            k = max(1, round(n * self.config.neutral_share))
            idx = np.concatenate(
                [
                    self.neutral[self.rng.integers(0, len(self.neutral), size=k)],
                    self.styled[self.rng.integers(0, len(self.styled), size=n - k)],
                ]
            )
        else:
            idx = self.rng.integers(0, len(self.data.motions), size=n)
        style = torch.from_numpy(self.data.styles[idx])
        content = torch.from_numpy(self.data.contents[idx])
        n_styles = len(self.data.style_names)
        # sec. 3.2: neutral -> any other style, every other style -> neutral
        other = torch.from_numpy(self.rng.integers(1, n_styles, size=n))
        target = torch.where(style == 0, other, torch.zeros_like(style))
        hide = torch.from_numpy(self.rng.random(n) < self.config.content_dropout)
        shown = torch.where(hide, torch.full_like(content, len(self.data.content_names)), content)
        return {"x": self._windows(idx), "style": style, "content": content, "target": target, "shown": shown}

    def _sub_windows(self, x: Tensor) -> Tensor:
        """(B, W, D) -> (B * k, disc_window, D): the critic's windows, ``disc_stride`` apart."""
        w = x.unfold(1, self.disc_window, self.disc_stride)  # (B, k, D, dw)
        return w.permute(0, 1, 3, 2).reshape(-1, self.disc_window, x.shape[-1])

    def _critic(self, x: Tensor, style: Tensor, content: Tensor) -> Tensor:
        wins = self._sub_windows(x)
        k = wins.shape[0] // x.shape[0]
        return self.disc(
            wins,
            self.net.style_onehot(style).repeat_interleave(k, 0),
            self.net.content_onehot(content).repeat_interleave(k, 0),
        )

    # -- generator pass --

    def generate(self, batch: dict[str, Tensor]) -> tuple[Tensor, Tensor]:
        """(reconstruction with target = source, transfer to the sec. 3.2 target), one batched forward."""
        net = self.net
        x = batch["x"]
        n = x.shape[0]
        src = net.style_onehot(batch["style"])
        shown = net.content_onehot(batch["shown"])
        target = torch.cat([src, net.style_onehot(batch["target"])])
        y, _ = net(torch.cat([x, x]), torch.cat([src, src]), torch.cat([shown, shown]), target, skip_idle=True)
        return y[:n], y[n:]

    def reconstruction(self, pred: Tensor, real: Tensor) -> dict[str, Tensor]:
        """Eq. 3 per frame, averaged over frames: L_quat (Eq. 2) + 1/2 |p - p''|^2 + |v - v''|^2 (+ contacts).

        L_quat is Eq. 2 as written: the squared norm over the 21 joints of the half rotation angle (radians).
        Positions, velocities and foot contacts (which the paper's frames lack) are compared in normalised units
        and averaged per channel, so every term starts O(1) next to the adversarial term (w_adv = 1). (A per-joint
        *mean* of L_quat instead gives rotations ~25x less gradient than positions per normalised unit, and the
        rotation error did not fall in 2,000 steps.)
        """
        g = self.groups
        shape = pred.shape[:-1] + (-1, 6)
        pred6 = pred[..., g["rot"]].view(shape) * self.rot_std + self.rot_mean
        real6 = real[..., g["rot"]].view(shape) * self.rot_std + self.rot_mean
        quat = rotation_geodesic(pred6, real6).pow(2).sum(-1).mean()  # Eq. 2: squared norm over the joints
        pos = F.mse_loss(pred[..., g["pos"]], real[..., g["pos"]])
        vel = F.mse_loss(pred[..., g["vel"]], real[..., g["vel"]])
        feet = F.mse_loss(pred[..., g["feet"]], real[..., g["feet"]])
        return {
            "rec_quat": quat,
            "rec_pos": pos,
            "rec_vel": vel,
            "rec_feet": feet,
            "rec": quat + 0.5 * pos + vel + feet,
        }

    # -- updates --

    def critic_losses(self, batch: dict[str, Tensor], fake: Tensor) -> dict[str, Tensor]:
        """Eq. 5 (LSGAN: real -> +1, fake -> -1) and Eq. 6 (gradient penalty on real windows); Eq. 9 total."""
        real = batch["x"].detach().requires_grad_(True)
        d_real = self._critic(real, batch["style"], batch["content"])
        d_fake = self._critic(fake.detach(), batch["target"], batch["content"])
        cri = (d_real - 1).pow(2).mean() + (d_fake + 1).pow(2).mean()
        (grad,) = torch.autograd.grad(d_real.sum(), real, create_graph=True)
        gp = grad.pow(2).sum(dim=(1, 2)).mean()
        return {"cri": cri, "gp": gp, "dis": cri + self.config.w_gp * gp}

    def generator_losses(self, batch: dict[str, Tensor], rec: Tensor, fake: Tensor) -> dict[str, Tensor]:
        """Eq. 8: reconstruction + w_adv * Eq. 4 (LSGAN: fake -> 0) + w_per * Eq. 7 (content features match)."""
        cfg = self.config
        losses = self.reconstruction(rec, batch["x"])
        adv = self._critic(fake, batch["target"], batch["content"]).pow(2).mean()
        with torch.no_grad():
            phi = self.classifier.features(batch["x"])
        per = (self.classifier.features(fake) - phi).pow(2).mean()
        gen = losses["rec"] + cfg.w_adv * adv + cfg.w_per * per
        if cfg.w_style > 0:
            sty = F.cross_entropy(self.style_classifier(fake), batch["target"])
            losses["style"] = sty
            gen = gen + cfg.w_style * sty
        if cfg.w_moments > 0:
            mom = self.moment_loss(batch, fake)
            losses["moments"] = mom
            gen = gen + cfg.w_moments * mom
        if self.loss_terms:  # on the reconstruction, the one output with a target: global joints, metres
            joints = [recover_from_ric(x * self.net.std + self.net.mean, T2M.n_joints) for x in (rec, batch["x"])]
            step = LossBatch(joints[0], joints[1], torch.ones(rec.shape[:2], dtype=torch.bool), self.data.fps)
            for spec, term in zip(cfg.loss_terms, self.loss_terms):
                losses[split_spec(spec)[0]] = value = term(step)
                gen = gen + term.weight * value
        losses |= {"adv": adv, "per": per, "gen": gen}
        return losses

    def moment_loss(self, batch: dict[str, Tensor], fake: Tensor) -> Tensor:
        """Per-channel change of the window mean and std, transfer vs input, against the class averages' change.

        Bandai-2 and the synthetic corpus hold every content in every style, but not time-aligned; the first two
        moments over time need no alignment and carry posture (mean), amplitude and speed (std).
        """
        mu, sd = self.moments
        x = batch["x"]
        src, tgt, con = batch["style"], batch["target"], batch["content"]
        d_mu = (fake.mean(dim=1) - x.mean(dim=1)) - (mu[tgt, con] - mu[src, con])
        d_sd = (fake.std(dim=1) - x.std(dim=1)) - (sd[tgt, con] - sd[src, con])
        return d_mu.pow(2).mean() + d_sd.pow(2).mean()

    def critic_step(self, batch: dict[str, Tensor], fake: Tensor | None = None) -> dict[str, float]:
        """One critic update (Eq. 9) against ``fake`` (default: the current generator's transfer of ``batch``)."""
        if fake is None:
            with torch.no_grad():
                fake = self.generate(batch)[1]
        self.opt_d.zero_grad(set_to_none=True)
        d = self.critic_losses(batch, fake)
        d["dis"].backward()
        self.opt_d.step()
        return {k: v.detach().item() for k, v in d.items()}

    def generator_step(
        self, batch: dict[str, Tensor], outputs: tuple[Tensor, Tensor] | None = None
    ) -> dict[str, float]:
        """One generator update (Eq. 8) against the current critic; ``outputs`` = ``generate(batch)`` if done."""
        rec, fake = outputs if outputs is not None else self.generate(batch)
        self.opt_g.zero_grad(set_to_none=True)
        self.disc.requires_grad_(False)  # the generator's loss flows through the critic, not into it
        try:
            g = self.generator_losses(batch, rec, fake)
            g["gen"].backward()
        finally:
            self.disc.requires_grad_(True)
        self.opt_g.step()
        return {k: v.detach().item() for k, v in g.items()}

    def train_step(self, batch: dict[str, Tensor]) -> dict[str, float]:
        """One critic update, then one generator update against the updated critic (one generator forward)."""
        rec, fake = self.generate(batch)
        d = self.critic_step(batch, fake.detach())
        return d | self.generator_step(batch, (rec, fake))

    def losses(self, batch: dict[str, Tensor]) -> dict[str, float]:
        """Both players' losses on ``batch`` without updating anything."""
        rec, fake = self.generate(batch)
        d = self.critic_losses(batch, fake)
        with torch.no_grad():
            g = self.generator_losses(batch, rec, fake)
        return {k: v.detach().item() for k, v in (d | g).items()}

    def train_classifier(self, progress: Progress | None = None, total: int | None = None) -> dict[str, float]:
        """Stage 1: the content classifier D_C on labelled windows (cross-entropy), then frozen."""
        cfg = self.config
        total = total or cfg.classifier_steps

        def report(step: int, loss: float, acc: float) -> None:
            if progress is not None:
                progress(step + 1, total, {"cls_loss": loss, "cls_acc": acc})

        tail_loss, tail_acc = self._fit_classifier(self.classifier, self.labelled, self.data.contents, report)
        info = {"steps": float(cfg.classifier_steps), "loss": tail_loss, "accuracy": tail_acc}
        if cfg.w_style > 0:  # the frozen style critic of ``w_style``: real windows, as many steps as D_C
            all_windows = np.arange(len(self.data.motions))
            info["style_accuracy"] = self._fit_classifier(self.style_classifier, all_windows, self.data.styles)[1]
        return info

    def _fit_classifier(
        self,
        model: nn.Module,
        pool: np.ndarray,
        labels: np.ndarray,
        report: Callable[[int, float, float], None] | None = None,
    ) -> tuple[float, float]:
        """Cross-entropy on windows of clips drawn from ``pool``, then frozen; (loss, accuracy) over the last 10%."""
        cfg = self.config
        opt = torch.optim.Adam(model.parameters(), lr=cfg.lr_classifier)
        tail_loss, tail_acc, tail = 0.0, 0.0, max(1, cfg.classifier_steps // 10)
        for step in range(cfg.classifier_steps):
            idx = pool[self.rng.integers(0, len(pool), size=cfg.classifier_batch_size)]
            x, y = self._windows(idx), torch.from_numpy(labels[idx])
            logits = model(x)
            loss = F.cross_entropy(logits, y)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            acc = float((logits.argmax(-1) == y).float().mean())
            if step >= cfg.classifier_steps - tail:
                tail_loss, tail_acc = tail_loss + loss.item() / tail, tail_acc + acc / tail
            if report is not None:
                report(step, loss.item(), acc)
        model.requires_grad_(False)
        model.eval()
        return tail_loss, tail_acc


# ---- public API -----------------------------------------------------------------------------------------------


def train_erd(
    clips: Sequence[MotionClip],
    out_dir: str | os.PathLike[str],
    config: ErdTrainConfig | None = None,
    progress: Progress | None = None,
) -> Path:
    """Train Style-ERD on labelled clips and write the model folder ``out_dir``; returns its path.

    ``clips``: HumanML3D-feature clips with ``style`` labels (``neutral`` plus others) and ``content`` labels
    (None allowed: unknown content). Same clips + config (seed, threads) -> bit-identical weights.
    ``progress(step, total, metrics)`` is called after every classifier and every GAN step (``total`` counts both).
    An existing ``out_dir`` is replaced only once the new folder is complete.
    """
    config = config or ErdTrainConfig()
    start = time.perf_counter()
    data = prepare_data(clips, config=config)
    threads = torch.get_num_threads()
    torch.set_num_threads(config.threads)
    try:
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(config.seed)
            trainer = ErdTrainer(data, config)
            total = config.classifier_steps + config.steps
            cls_info = trainer.train_classifier(progress, total)
            history = run_steps(
                lambda: trainer.train_step(trainer.sample()),
                config.steps,
                config.log_every,
                "Style-ERD",
                progress,
                done=config.classifier_steps,
                total=total,
            )
    finally:
        torch.set_num_threads(threads)
    artifact = ErdArtifact(
        network=trainer.net.config.to_dict(),
        styles=list(data.style_names),
        contents=list(data.content_names),
        fps=data.fps,
        normalizer={"mean": data.mean.tolist(), "std": data.std.tolist()},
        train=config,
        data={
            "clips": len(data.motions),
            "dropped_short": data.dropped_short,
            "styles": {s: int((data.styles == i).sum()) for i, s in enumerate(data.style_names)},
            "window_frames": trainer.window,
            "disc_window_frames": trainer.disc_window,
        },
        classifier=cls_info,
        final={k: v for k, v in history[-1].items() if k != "step"},
        history=history,
        seconds=time.perf_counter() - start,
    )
    critics = {f"discriminator.{k}": v for k, v in trainer.disc.state_dict().items()}
    critics |= {f"classifier.{k}": v for k, v in trainer.classifier.state_dict().items()}
    if config.w_style > 0:
        critics |= {f"style_classifier.{k}": v for k, v in trainer.style_classifier.state_dict().items()}
    tensors = {WEIGHTS_FILE: trainer.net.state_dict(), CRITICS_FILE: critics}
    return write_model_folder(Path(out_dir), tensors, {META_FILE: artifact.model_dump_json(indent=1)})


def read_artifact(path: str | os.PathLike[str]) -> ErdArtifact:
    """The ``erd.json`` of a model folder."""
    return read_json_model(Path(path) / META_FILE, ErdArtifact, "a Style-ERD model folder")


def load_erd(path: str | os.PathLike[str]) -> ErdNetwork:
    """The generator of a folder written by ``train_erd``, in eval mode (safetensors: weights only, no pickle)."""
    folder = Path(path)
    artifact = read_artifact(folder)
    try:
        net = ErdNetwork(StyleErdConfig.from_dict(artifact.network))
        state = load_file(str(folder / WEIGHTS_FILE))
        net.load_state_dict(state, strict=True)
    except Exception as err:  # safetensors, shape or key mismatches: one line, naming the folder
        raise MotionDataError(str(folder), f"unreadable Style-ERD weights ({str(err).splitlines()[0]})") from None
    if not np.allclose(net.mean.numpy(), artifact.normalizer["mean"]) or not np.allclose(
        net.std.numpy(), artifact.normalizer["std"]
    ):
        raise MotionDataError(str(folder), f"{WEIGHTS_FILE} and {META_FILE} disagree on the normaliser")
    return net.eval()
