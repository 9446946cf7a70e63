"""Train UMSD (Qian et al., ACM MM 2025, sec. 3.4) on labelled clips; save and load the network.

Each step draws rows of three kinds: ``rec`` (ours: supervised transfer from labelled pairs), ``dcc`` (Eq. 10:
content and style example share the style, so the output must be the content) and ``dsc`` (Eq. 11: they share the
content, so the output must be the style motion); Eq. 12's geometric terms apply on recovered global joints, and
beyond the paper ``w_spec`` (amplitude spectra) and the ``skip`` parametrisations; docs/internals.md says why.
``UmsdTrain`` (``method.params.train``) expands with the run's size and seed into ``UmsdTrainConfig``.
``train_umsd`` runs a fixed number of steps, bit-identical for the same clips, config, seed and threads, and
writes ``umsd.safetensors`` + ``umsd.json`` (``UmsdTrainArtifact``) through a temporary sibling folder.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field, model_serializer, model_validator
from safetensors.torch import load_file
from torch import Tensor

from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.diffusion import NoiseSchedule, SpectralPrior, estimate_spectral_prior, q_sample, skip_x0
from motionaug.augment.io import read_json_model
from motionaug.augment.methods.base import Progress
from motionaug.augment.methods.common import run_steps, write_model_folder
from motionaug.augment.methods.hooks import HookSpec, LossBatch, LossTerms, loss_terms, split_spec
from motionaug.augment.motion.batch import pad_batch
from motionaug.augment.motion.features import Normalizer, compute_mean_std, feature_slices, recover_from_ric
from motionaug.augment.synth import restyled
from motionaug.models.pace import PaceNet
from motionaug.models.umsd import UmsdConfig, UmsdNet, frame_aligned
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.skeleton import T2M

WEIGHTS_FILE = "umsd.safetensors"
META_FILE = "umsd.json"
NEUTRAL = "neutral"
TERMS = ("rec", "dcc", "dsc")
SKIP_KEYS = ("skip.basis", "skip.var")  # the data prior of ``skip_x0``, saved beside the weights
SPECTRAL_KEYS = ("skip.spectral_bases", "skip.spectral_variances")  # ``skip_time: spectral``'s prior, the same
SPECTRAL_BANDS = 32  # frequency bands of the spectral prior: windows of 32 frames, bands 1/64 cycle per frame apart
PACE_KEY_PREFIX = "pace."  # the pace regressor's weights in the model file (``pace_steps``)
FOOT_JOINTS = (*T2M.feet_left, *T2M.feet_right)  # the order of the four foot-contact channels
PRIOR_SKIPS = ("covariance", "content")  # the skips whose estimate uses the training frames' second moments
# left out of config dumps at their defaults
OMITTED_AT_DEFAULT = (
    "align_content",
    "synthetic_pairs",
    "w_spec",
    "loss_terms",
    "skip_time",
    "content_pace",
    "pace_steps",
)


class UmsdTrainConfig(BaseModel):
    """How to train UMSD. The paper gives AdamW and lr 1e-6 for ~10 GPU hours (sec. 4.1); a fixed CPU step budget
    needs a larger rate, so lr defaults to 1e-4."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    steps: int = Field(2000, ge=1, description="optimiser steps (a fixed count; there is no time cap)")
    batch_size: int = Field(8, ge=1, description="rows per loss term and step (rec, dcc, dsc each)")
    lr: float = Field(1e-4, gt=0, description="AdamW learning rate (sec. 4.1: AdamW)")
    weight_decay: float = Field(0.01, ge=0)
    grad_clip: float = Field(1.0, gt=0, description="gradient-norm clip")
    max_frames: int = Field(120, ge=8, description="training crop per clip, frames (6 s at 20 fps)")
    min_frames: int = Field(20, ge=2, description="shorter clips are not trained on")
    w_rec: float = Field(1.0, ge=0, description="supervised transfer term (not in the paper, see the module doc)")
    w_dcc: float = Field(1.0, ge=0, description="Eq. 10 / Eq. 12 weight")
    w_dsc: float = Field(1.0, ge=0, description="Eq. 11 / Eq. 12 weight")
    w_pos: float = Field(1.0, ge=0, description="Eq. 12: joint positions, metres")
    w_vel: float = Field(1.0, ge=0, description="Eq. 12: joint velocities, m/s")
    w_foot: float = Field(1.0, ge=0, description="Eq. 12: planted-foot speed, m/s")
    w_spec: float = Field(
        0.0,
        ge=0,
        description="L1 on the temporal amplitude spectrum of the facing-frame joints and root height, metres "
        "(not in the paper): rewards rhythm (sway, bob, step-rate swings) whatever its phase",
    )
    loss_terms: tuple[HookSpec, ...] = Field(
        (), description="training-loss terms registered by name (augment.methods.hooks.loss_terms), with weights"
    )
    use_dcc: bool = Field(True, description="ablation switch for L_dcc (sec. 4.5)")
    use_dsc: bool = Field(True, description="ablation switch for L_dsc (sec. 4.5)")
    skip: Literal["none", "covariance", "unit", "content"] = Field(
        "none",
        description="x0 = the linear estimate from x_t under a Gaussian prior with the training frames' second "
        "moments (covariance), the same centred on the content condition frame by frame (content), or unit "
        "variance (unit), + the network's residual (augment.diffusion.skip_x0); none: the network's output is x0",
    )
    skip_time: Literal["frame", "spectral"] = Field(
        "frame",
        description="the skip prior over time (covariance and content skips): frames independent (frame), or "
        "stationary, a feature covariance per temporal frequency band (spectral, augment.diffusion.SpectralPrior), "
        "so the skip removes the noise at frequencies real motion lacks instead of passing it to x0 (not in the paper)",
    )
    content_pace: bool = Field(
        True,
        description="skip: content centres the root's ground velocity on the content's too; False: on the data "
        "mean, so the network sets the pace itself from the style example (styles that walk slower or faster; "
        "sample with keep: heading, which keeps the content's turning but not its speed) (not in the paper)",
    )
    pace_steps: int = Field(
        0,
        ge=0,
        description="> 0: after the diffusion network, fit the pace regressor (augment.methods.umsd.pace) for this "
        "many steps, which sampling with pace: example uses to carry the content's root at the style's speed "
        "(not in the paper); the diffusion weights are the same either way",
    )
    exclude_styles: tuple[str, ...] = Field((), description="styles held out of training (zero-shot, sec. 4.4)")
    seed: int = 0
    threads: int = Field(1, ge=1, description="torch threads while training (part of what makes runs identical)")
    log_every: int = Field(50, ge=1, description="history interval, steps")
    # network (``motionaug.models.umsd.UmsdConfig``); the paper gives no widths: CPU-sized defaults. The Bandai-2
    # preset keeps them and trains on shorter crops and batches; a wider network is slower per step on a CPU
    d_model: int = Field(64, ge=1)
    n_heads: int = Field(4, ge=1)
    ff_size: int = Field(256, ge=1)
    msm_blocks: int = Field(3, ge=1, description="Eq. 7 iterations (paper: 3)")
    d_state: int = Field(8, ge=1)
    expand: int = Field(2, ge=1)
    d_conv: int = Field(4, ge=1)
    dropout: float = Field(0.1, ge=0, lt=1)
    max_len: int = Field(1024, ge=8, description="longest sequence the network takes (transfer too)")
    denoiser: Literal["msm", "transformer"] = "msm"
    use_ssm: bool = True
    use_mha: bool = True
    align_content: bool = Field(
        False, description="add each content token to the noisy token of its frame too (models.umsd; not in the paper)"
    )
    synthetic_pairs: bool = Field(
        False,
        description="render every synthetic clip (meta 'spec') in a partner style, neutral for a styled clip and a "
        "drawn trained style for a neutral one, so each motion has a frame-aligned pair (augment.synth.restyled)",
    )

    @model_serializer(mode="wrap")
    def _dump(self, handler: Any) -> dict[str, Any]:
        """Omit the fields added later at their defaults, so the configs (and the keys of the models) made before
        they existed stay the same."""
        data = handler(self)
        for name in OMITTED_AT_DEFAULT:
            if getattr(self, name) == type(self).model_fields[name].default:
                data.pop(name, None)
        return data

    @model_validator(mode="after")
    def _check(self) -> UmsdTrainConfig:
        if self.d_model % self.n_heads:
            raise ValueError(f"d_model {self.d_model} is not a multiple of n_heads {self.n_heads}")
        if self.max_frames > self.max_len:
            raise ValueError(f"max_frames {self.max_frames} > max_len {self.max_len}")
        if self.min_frames > self.max_frames:
            raise ValueError(f"min_frames {self.min_frames} > max_frames {self.max_frames}")
        if self.skip_time == "spectral" and self.skip not in PRIOR_SKIPS:
            raise ValueError(f"skip_time 'spectral' needs a skip with a data prior ({', '.join(PRIOR_SKIPS)})")
        return self

    def network(self, n_feats: int = T2M.feature_dim) -> UmsdConfig:
        return UmsdConfig(
            n_feats=n_feats,
            d_model=self.d_model,
            n_heads=self.n_heads,
            ff_size=self.ff_size,
            msm_blocks=self.msm_blocks,
            d_state=self.d_state,
            expand=self.expand,
            d_conv=self.d_conv,
            dropout=self.dropout,
            max_len=self.max_len,
            denoiser=self.denoiser,
            use_ssm=self.use_ssm,
            use_mha=self.use_mha,
            align_content=self.align_content,
        )

    def weights(self) -> dict[str, float]:
        """Per diffusion term; an ablated term weighs 0."""
        return {
            "rec": self.w_rec,
            "dcc": self.w_dcc if self.use_dcc else 0.0,
            "dsc": self.w_dsc if self.use_dsc else 0.0,
        }


NETWORK_SIZES: dict[str, dict[str, int]] = {
    "tiny": {"d_model": 32, "n_heads": 2, "ff_size": 64, "msm_blocks": 1, "d_state": 4},  # seconds-long smoke runs
    "small": {},  # the CPU-sized defaults of ``UmsdTrainConfig``
    "paper": {"d_model": 128, "ff_size": 512, "d_state": 16},  # about 4x slower per step than small
}


class UmsdTrain(BaseModel):
    """What a run config sets of UMSD's training (``method.params.train``): the schedule, the crop, Eq. 12's
    weights, the skip, the synthetic pairs, held-out styles and loss terms by name. The network's size is the
    run's ``base_models.size`` and its seed the run's (``recipe``)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    steps: int = Field(2000, ge=1, description="optimiser steps (a fixed count; there is no time cap)")
    batch_size: int = Field(8, ge=1, description="rows per loss term and step (rec, dcc, dsc each)")
    lr: float = Field(1e-4, gt=0, description="AdamW learning rate (sec. 4.1: AdamW)")
    max_frames: int = Field(120, ge=8, description="training crop per clip, frames (6 s at 20 fps)")
    w_dcc: float = Field(1.0, ge=0, description="Eq. 10 / Eq. 12 weight (0: the sec. 4.5 ablation)")
    w_dsc: float = Field(1.0, ge=0, description="Eq. 11 / Eq. 12 weight (0: the sec. 4.5 ablation)")
    w_pos: float = Field(1.0, ge=0, description="Eq. 12: joint positions, metres")
    w_vel: float = Field(1.0, ge=0, description="Eq. 12: joint velocities, m/s")
    w_foot: float = Field(1.0, ge=0, description="Eq. 12: planted-foot speed, m/s")
    w_spec: float = Field(0.0, ge=0, description="L1 on the joints' amplitude spectra over time (module doc)")
    skip: Literal["none", "covariance", "unit", "content"] = Field(
        "none", description="x0 as the linear estimate from x_t + the network's residual (module doc); none: x0"
    )
    synthetic_pairs: bool = Field(False, description="render each synthetic clip in a partner style (module doc)")
    exclude_styles: tuple[str, ...] = Field((), description="styles held out of training (zero-shot, sec. 4.4)")
    log_every: int = Field(50, ge=1, description="history interval, steps")
    loss_terms: LossTerms = Field(
        (), description="more loss terms by name with their weight, e.g. [{name: NAME, weight: 0.1}]"
    )

    def recipe(self, size: str = "small", seed: int = 0) -> UmsdTrainConfig:
        """The full training config: these settings, the network of ``size`` (``NETWORK_SIZES``) and ``seed``."""
        if size not in NETWORK_SIZES:
            known = list(NETWORK_SIZES)
            raise MotionDataError("config base_models.size", f"UMSD has no network size {size!r}; known: {known}")
        return UmsdTrainConfig(**self.model_dump(), **NETWORK_SIZES[size], seed=seed)


class UmsdTrainArtifact(BaseModel):
    """``umsd.json``: everything but the weights."""

    model_config = ConfigDict(extra="forbid")

    version: int = 1
    method: Literal["umsd"] = "umsd"
    network: dict[str, Any]
    fps: float
    normalizer: dict[str, list[float]]
    train: UmsdTrainConfig
    data: dict[str, Any]
    final: dict[str, float]
    history: list[dict[str, float]]
    seconds: float


# ---- data ---------------------------------------------------------------------------------------------------


def spec_key(clip: MotionClip) -> str | None:
    """The clip's synthetic motion spec without its style fields: equal keys = the same motion in other styles."""
    raw = clip.meta.get("spec") if clip.meta else None
    if not raw:
        return None
    try:
        spec = json.loads(raw)
    except ValueError:
        return None
    if not isinstance(spec, dict):
        return None
    return json.dumps({k: v for k, v in spec.items() if k not in ("style", "intensity")}, sort_keys=True)


@dataclass
class UmsdData:
    """Labelled clips ready to sample: normalised motions and, per clip, its partners for each loss term."""

    ids: list[str]
    motions: list[np.ndarray]  # normalised float32 (T, F)
    styles: list[str]
    contents: list[str | None]
    spec_keys: list[str | None]
    fps: float
    normalizer: Normalizer
    same_motion: list[list[int]]  # same spec (else same content label), another style: Eq. 11's pair, rec's content
    same_style: list[list[int]]  # same style, other content where possible: Eq. 10's pair, rec's style example
    eligible: dict[str, np.ndarray]  # per term, the clips that can be its row's anchor
    dropped: dict[str, int]
    rendered: int = 0  # partners rendered from synthetic specs (``synthetic_pairs``)

    def second_moments(self) -> tuple[Tensor, Tensor]:
        """(basis (F, F), var (F,)): eigen-decomposition of E[x x^T] over every normalised training frame, the
        Gaussian data prior of ``skip_x0`` (uncentred: the linear estimate has no intercept)."""
        frames = torch.from_numpy(np.concatenate(self.motions)).double()
        var, basis = torch.linalg.eigh(frames.T @ frames / len(frames))
        return basis.float().contiguous(), var.clamp(min=0).float()

    def spectral_prior(self) -> SpectralPrior:
        """The stationary prior over time of ``skip_time: spectral``, from the same normalised training clips."""
        try:
            return estimate_spectral_prior(self.motions, SPECTRAL_BANDS)
        except ValueError as err:
            raise MotionDataError("UMSD training clips", str(err)) from None

    def summary(self) -> dict[str, Any]:
        count = lambda names: {n: names.count(n) for n in sorted(set(names))}  # noqa: E731
        return {
            "clips": len(self.motions),
            "styles": count(self.styles),
            "contents": count([c or "<none>" for c in self.contents]),
            "spec_pairs": sum(
                1
                for i, js in enumerate(self.same_motion)
                if js and self.spec_keys[i] is not None and self.spec_keys[js[0]] == self.spec_keys[i]
            ),
            "eligible": {k: int(len(v)) for k, v in self.eligible.items()},
            "dropped": self.dropped,
            **({"rendered": self.rendered} if self.rendered else {}),
        }


def _partners(styles: list[str], contents: list[str | None], keys: list[str | None]) -> tuple[list, list]:
    n = len(styles)
    same_motion, same_style = [], []
    for i in range(n):
        by_spec = [j for j in range(n) if keys[i] is not None and keys[j] == keys[i] and styles[j] != styles[i]]
        by_label = [
            j for j in range(n) if contents[i] is not None and contents[j] == contents[i] and styles[j] != styles[i]
        ]
        same_motion.append(by_spec or by_label)
        style_mates = [j for j in range(n) if j != i and styles[j] == styles[i]]
        other_content = [j for j in style_mates if contents[j] is None or contents[j] != contents[i]]
        same_style.append(other_content or style_mates)
    return same_motion, same_style


def rendered_partners(clips: Sequence[MotionClip], seed: int) -> list[MotionClip]:
    """Each synthetic clip's motion rendered in a partner style: neutral for a styled clip, for a neutral one a style
    drawn (by ``seed``) among the styles of ``clips``, so held-out styles are never rendered. Clips without a
    spec get none. The pairs are what the synthetic corpus exists for: the same motion in two styles."""
    styles = sorted({str(c.style) for c in clips} - {NEUTRAL})
    rng = np.random.default_rng([seed, 2])
    out = []
    for clip in clips:
        if spec_key(clip) is None:
            continue
        if clip.style != NEUTRAL:
            out.append(restyled(clip, NEUTRAL))
        elif styles:
            out.append(restyled(clip, styles[int(rng.integers(0, len(styles)))]))
    return out


def prepare_data(clips: Sequence[MotionClip], config: UmsdTrainConfig | None = None) -> UmsdData:
    """Check labels and motions, drop held-out styles and short clips, add the rendered partners when
    ``synthetic_pairs``, normalise with the kept clips' Mean/Std, and find every clip's partners. Every clip needs a
    style label; content labels may be missing."""
    config = config or UmsdTrainConfig()
    if not clips:
        raise MotionDataError("UMSD training", "no clips")
    unlabelled = [c.id for c in clips if not c.style]
    if unlabelled:
        raise MotionDataError("UMSD training", f"{len(unlabelled)} clips without a style label, e.g. {unlabelled[0]}")
    for c in clips:
        m = np.asarray(c.motion)
        if m.ndim != 2 or m.shape[1] != T2M.feature_dim or not np.isfinite(m).all():
            raise MotionDataError(f"clip {c.id}", f"need finite (T, {T2M.feature_dim}) features, got shape {m.shape}")
    held_out = set(config.exclude_styles)
    kept = [c for c in clips if c.style not in held_out]
    long_enough = [c for c in kept if c.n_frames >= config.min_frames]
    dropped = {"held_out": len(clips) - len(kept), "short": len(kept) - len(long_enough)}
    if not long_enough:
        raise MotionDataError("UMSD training", f"no clip left with >= {config.min_frames} frames")
    rendered = rendered_partners(long_enough, config.seed) if config.synthetic_pairs else []
    long_enough = [*long_enough, *rendered]
    rates = {float(c.fps) for c in long_enough}
    if len(rates) != 1:
        raise MotionDataError("UMSD training", f"clips mix frame rates {sorted(rates)}")
    norm = compute_mean_std(c.motion for c in long_enough)
    styles = [str(c.style) for c in long_enough]
    contents = [c.content for c in long_enough]
    keys = [spec_key(c) for c in long_enough]
    same_motion, same_style = _partners(styles, contents, keys)
    weights = config.weights()
    anchors = {
        "rec": [i for i in range(len(styles)) if same_motion[i] and same_style[i]],
        "dcc": [i for i in range(len(styles)) if same_style[i]],
        "dsc": [i for i in range(len(styles)) if same_motion[i]],
    }
    eligible = {k: np.array(v, dtype=np.int64) for k, v in anchors.items() if weights[k] > 0 and v}
    if not eligible:
        raise MotionDataError(
            "UMSD training", "no trainable pair: need two clips of one style, or one motion in two styles"
        )
    return UmsdData(
        ids=[c.id for c in long_enough],
        motions=[norm.normalize(np.asarray(c.motion, dtype=np.float32)).astype(np.float32) for c in long_enough],
        styles=styles,
        contents=contents,
        spec_keys=keys,
        fps=rates.pop(),
        normalizer=norm,
        same_motion=same_motion,
        same_style=same_style,
        eligible=eligible,
        dropped=dropped,
        rendered=len(rendered),
    )


def pace_channels(config: UmsdTrainConfig) -> list[int]:
    """The channels ``content_pace: false`` takes out of the content-centred prior: the root's ground velocity."""
    if config.content_pace or config.skip != "content":
        return []
    block = feature_slices(T2M)["root_lin_vel"]
    return list(range(block.start, block.stop))


def x0_from_output(
    skip: str,
    schedule: NoiseSchedule,
    x_t: Tensor,
    t: Tensor,
    out: Tensor,
    prior: tuple[Tensor, Tensor] | tuple[None, None],
    content: Tensor,
    spectral: SpectralPrior | None = None,
    mask: Tensor | None = None,
    free: Sequence[int] = (),
) -> Tensor:
    """The x0 prediction from the network's output under ``skip`` (``UmsdTrainConfig.skip``); ``content`` (B, Tc, F)
    is the normalised content condition, zero at padding, frame i the prior mean of frame i for ``content``, but
    in the ``free`` channels (``pace_channels``), whose prior mean is the data mean; ``spectral`` (``skip_time:
    spectral``) with x_t's frame ``mask`` (B, T)."""
    if skip == "none":
        return out
    mean = frame_aligned(content, x_t.shape[1]) if skip == "content" else None
    if mean is not None and len(free):
        mean = mean.clone()
        mean[..., list(free)] = 0.0  # normalised: the data mean
    return skip_x0(schedule, x_t, t, out, *prior, mean=mean, spectral=spectral, mask=mask)


# ---- the trainer ----------------------------------------------------------------------------------------------


@dataclass
class UmsdBatch:
    """Rows of every active term, padded: target x0, its condition, and the noising (t, noise)."""

    kinds: list[str]
    x0: Tensor
    x_mask: Tensor
    content: Tensor
    content_mask: Tensor
    style: Tensor
    style_mask: Tensor
    t: Tensor
    noise: Tensor


class UmsdTrainer:
    """Network, optimiser, data sampler. ``sample()`` draws a batch, ``train_step`` updates, ``losses`` evaluates
    (tests use it on a fixed batch)."""

    def __init__(self, data: UmsdData, config: UmsdTrainConfig) -> None:
        self.data, self.config = data, config
        self.net = UmsdNet(config.network())
        self.opt = torch.optim.AdamW(self.net.parameters(), lr=config.lr, weight_decay=config.weight_decay)
        self.schedule = NoiseSchedule.cosine()
        self.rng = np.random.default_rng([config.seed, 1])
        self.noise_gen = torch.Generator().manual_seed(config.seed)
        self.neutral = [[j for j in js if data.styles[j] == NEUTRAL] for js in data.same_motion]
        self.mean = torch.from_numpy(data.normalizer.mean)
        self.std = torch.from_numpy(data.normalizer.std)
        blocks = feature_slices(T2M)
        self.feet, self.ric, self.root_y = blocks["feet"], blocks["ric"], blocks["root_y"]
        self.basis, self.var = data.second_moments()
        self.spectral = data.spectral_prior() if config.skip_time == "spectral" else None
        self.free = pace_channels(config)  # ``content_pace: false``: channels out of the content-centred prior
        self.loss_terms = loss_terms.create_all(list(config.loss_terms), "config method.params.train.loss_terms")

    # -- sampling --

    def _pick(self, options: Sequence[int]) -> int:
        return int(options[int(self.rng.integers(0, len(options)))])

    def _crop(self, i: int, start: int | None = None) -> tuple[np.ndarray, int]:
        """A window of at most ``max_frames``; ``start`` (clamped) keeps two renderings of one spec aligned."""
        motion = self.data.motions[i]
        room = len(motion) - self.config.max_frames
        if room <= 0:
            return motion, 0
        s = int(self.rng.integers(0, room + 1)) if start is None else min(start, room)
        return motion[s : s + self.config.max_frames], s

    def _row(self, kind: str, anchor: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(target, content, style) motions of one row (see the module doc for each kind)."""
        d = self.data
        if kind == "rec":
            target, content = anchor, self._pick(self.neutral[anchor] or d.same_motion[anchor])
            style = self._pick(d.same_style[anchor])
        elif kind == "dcc":  # Eq. 10: c = s, target = the content clip
            target = content = anchor
            style = self._pick(d.same_style[anchor])
        else:  # Eq. 11: m = n, target = the style clip
            target = style = anchor
            content = self._pick(d.same_motion[anchor])
        x0, start = self._crop(target)
        aligned = d.spec_keys[target] is not None and d.spec_keys[content] == d.spec_keys[target]
        c = x0 if content == target else self._crop(content, start if aligned else None)[0]
        s = x0 if style == target else self._crop(style)[0]
        return x0, c, s

    def sample(self) -> UmsdBatch:
        kinds, rows = [], []
        for kind, anchors in self.data.eligible.items():
            for i in self.rng.choice(anchors, size=self.config.batch_size):
                kinds.append(kind)
                rows.append(self._row(kind, int(i)))
        x0, x_mask = pad_batch([r[0] for r in rows])
        content, content_mask = pad_batch([r[1] for r in rows])
        style, style_mask = pad_batch([r[2] for r in rows])
        t = torch.randint(0, len(self.schedule), (len(rows),), generator=self.noise_gen)
        noise = torch.randn(x0.shape, generator=self.noise_gen)
        return UmsdBatch(kinds, x0, x_mask, content, content_mask, style, style_mask, t, noise)

    # -- losses --

    def _joints(self, x: Tensor) -> Tensor:
        """Normalised features (B, T, F) -> global joints (B, T, J, 3), metres."""
        return recover_from_ric(x * self.std + self.mean, T2M.n_joints)

    def losses(self, batch: UmsdBatch) -> dict[str, Tensor]:
        """Eq. 12: the active diffusion terms (L1, Eqs. 10-11 and rec) + L_pos + L_vel + L_foot, and their total."""
        cfg = self.config
        mask = batch.x_mask
        x_t = q_sample(self.schedule, batch.x0 * mask[..., None], batch.t, batch.noise)
        keep = mask[..., None].float()
        pred = self.net(x_t, batch.t, batch.content, batch.content_mask, batch.style, batch.style_mask, mask)
        prior = self.skip_prior()
        pred = x0_from_output(
            cfg.skip, self.schedule, x_t, batch.t, pred, prior, batch.content, self.spectral, mask, self.free
        )
        pred = pred * keep
        frames = keep.sum(dim=(1, 2)).clamp(min=1)
        l1 = ((pred - batch.x0).abs() * keep).sum(dim=(1, 2)) / (frames * pred.shape[-1])  # (B,)
        out: dict[str, Tensor] = {}
        total = pred.new_zeros(())
        kinds = np.array(batch.kinds)
        for kind, weight in cfg.weights().items():
            rows = torch.from_numpy(np.flatnonzero(kinds == kind))
            if len(rows):
                out[kind] = l1[rows].mean()
                total = total + weight * out[kind]
        # Eq. 12's geometric terms on recovered global joints
        pj, tj = self._joints(pred), self._joints(batch.x0)
        jk = keep[..., None]  # (B, T, 1, 1)
        n_j = T2M.n_joints
        out["pos"] = ((pj - tj).abs() * jk).sum() / (jk.sum() * n_j * 3).clamp(min=1)
        pair = (mask[:, 1:] & mask[:, :-1])[..., None, None].float()  # steps between two real frames
        pv, tv = (pj[:, 1:] - pj[:, :-1]) * self.data.fps, (tj[:, 1:] - tj[:, :-1]) * self.data.fps
        out["vel"] = ((pv - tv).abs() * pair).sum() / (pair.sum() * n_j * 3).clamp(min=1)
        # contact channels [l ankle, l toe, r ankle, r toe] at frame i refer to the step i -> i+1
        contact = (batch.x0[:, :-1, self.feet] * self.std[self.feet] + self.mean[self.feet]) > 0.5
        planted = contact.float() * pair[..., 0]  # (B, T-1, 4)
        speed = pv[:, :, list(FOOT_JOINTS)].norm(dim=-1)  # (B, T-1, 4)
        out["foot"] = (speed * planted).sum() / planted.sum().clamp(min=1)
        total = total + cfg.w_pos * out["pos"] + cfg.w_vel * out["vel"] + cfg.w_foot * out["foot"]
        if cfg.w_spec > 0:
            out["spec"] = self._spectrum_l1(pred, batch.x0, keep)
            total = total + cfg.w_spec * out["spec"]
        for spec, term in zip(cfg.loss_terms, self.loss_terms):
            out[split_spec(spec)[0]] = term(LossBatch(pj, tj, mask, self.data.fps))
            total = total + term.weight * out[split_spec(spec)[0]]
        out["total"] = total
        return out

    def _spectrum_l1(self, pred: Tensor, target: Tensor, keep: Tensor) -> Tensor:
        """L1 between the amplitude spectra over time of the root-relative, facing-frame joints (the ``ric`` block)
        and the root height, each channel's mean over the real frames removed, amplitudes per frame (a sinusoid of
        amplitude A peaks at A / 2), summed over frequencies, averaged over channels and rows. An L1 on values alone
        is lowest, where the phase of a swing is uncertain, for no swing at all; the amplitude spectrum forgets the
        phase, so an output without the style's rhythm costs what a wrong rhythm does."""
        dims = [self.root_y.start, *range(self.ric.start, self.ric.stop)]
        frames = keep.sum(dim=1, keepdim=True).clamp(min=1)  # (B, 1, 1)

        def amplitudes(x: Tensor) -> Tensor:
            metres = (x[..., dims] * self.std[dims] + self.mean[dims]) * keep
            centred = (metres - metres.sum(dim=1, keepdim=True) / frames) * keep
            return torch.fft.rfft(centred, dim=1).abs() / frames

        return (amplitudes(pred) - amplitudes(target)).abs().sum(dim=1).mean()

    def skip_prior(self) -> tuple[Tensor, Tensor] | tuple[None, None]:
        return (self.basis, self.var) if self.config.skip in PRIOR_SKIPS else (None, None)

    def train_step(self, batch: UmsdBatch) -> dict[str, float]:
        self.net.train()
        losses = self.losses(batch)
        self.opt.zero_grad(set_to_none=True)
        losses["total"].backward()
        torch.nn.utils.clip_grad_norm_(self.net.parameters(), self.config.grad_clip)
        self.opt.step()
        return {k: v.detach().item() for k, v in losses.items()}

    @torch.no_grad()
    def evaluate(self, batch: UmsdBatch) -> dict[str, float]:
        """The losses on ``batch`` in eval mode (no dropout), without updating anything."""
        self.net.eval()
        return {k: v.item() for k, v in self.losses(batch).items()}


# ---- public API -----------------------------------------------------------------------------------------------


def train_umsd(
    clips: Sequence[MotionClip],
    out_dir: str | os.PathLike[str],
    config: UmsdTrainConfig | None = None,
    progress: Progress | None = None,
) -> Path:
    """Train UMSD on labelled clips and write the model folder ``out_dir``; returns its path.

    ``clips``: HumanML3D-feature clips with ``style`` labels (content labels and synthetic ``meta['spec']`` make the
    pairs). Same clips + config (seed, threads) -> bit-identical weights. ``progress(step, total, metrics)`` is
    called after every step. An existing ``out_dir`` is replaced only once the new folder is complete.
    """
    from motionaug.augment.methods.umsd.pace import fit_pace  # it builds on this module's data types

    config = config or UmsdTrainConfig()
    start = time.perf_counter()
    data = prepare_data(clips, config)
    threads = torch.get_num_threads()
    torch.set_num_threads(config.threads)
    try:
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(config.seed)
            trainer = UmsdTrainer(data, config)
            history = run_steps(
                lambda: trainer.train_step(trainer.sample()), config.steps, config.log_every, "UMSD", progress
            )
        pace = fit_pace(data, config) if config.pace_steps else None
    finally:
        torch.set_num_threads(threads)
    artifact = UmsdTrainArtifact(
        network=trainer.net.config.to_dict(),
        fps=data.fps,
        normalizer={"mean": data.normalizer.mean.tolist(), "std": data.normalizer.std.tolist()},
        train=config,
        data=data.summary(),
        final={k: v for k, v in history[-1].items() if k != "step"} | (pace[1] if pace else {}),
        history=history,
        seconds=time.perf_counter() - start,
    )
    tensors = {**trainer.net.state_dict(), **dict(zip(SKIP_KEYS, (trainer.basis, trainer.var)))}
    if trainer.spectral is not None:
        tensors.update(zip(SPECTRAL_KEYS, (trainer.spectral.bases, trainer.spectral.variances)))
    if pace is not None:
        tensors.update({PACE_KEY_PREFIX + k: v for k, v in pace[0].state_dict().items()})
    return write_model_folder(Path(out_dir), {WEIGHTS_FILE: tensors}, {META_FILE: artifact.model_dump_json(indent=1)})


def read_artifact(path: str | os.PathLike[str]) -> UmsdTrainArtifact:
    """The ``umsd.json`` of a model folder."""
    return read_json_model(Path(path) / META_FILE, UmsdTrainArtifact, "a UMSD model folder")


@dataclass
class UmsdModel:
    """A trained UMSD: the network (eval mode), the normaliser it works in, and its record."""

    net: UmsdNet
    normalizer: Normalizer
    info: UmsdTrainArtifact
    skip_prior: tuple[Tensor, Tensor] | tuple[None, None]  # (basis, var) of ``skip_x0``, or (None, None)
    spectral: SpectralPrior | None = None  # ``skip_time: spectral``'s prior
    pace: PaceNet | None = None  # ``pace_steps``' regressor


def load_umsd(path: str | os.PathLike[str]) -> UmsdModel:
    """The network of a folder written by ``train_umsd`` (safetensors: weights only, no pickle)."""
    folder = Path(path)
    info = read_artifact(folder)
    try:
        net = UmsdNet(UmsdConfig.from_dict(info.network))
        tensors = load_file(str(folder / WEIGHTS_FILE))
        prior = tuple(tensors.pop(k, None) for k in SKIP_KEYS)  # absent from folders trained before the skip
        if info.train.skip in PRIOR_SKIPS and None in prior:
            raise ValueError("no skip.basis / skip.var beside the weights")
        bands = tuple(tensors.pop(k, None) for k in SPECTRAL_KEYS)
        if info.train.skip_time == "spectral" and None in bands:
            raise ValueError("no skip.spectral_bases / skip.spectral_variances beside the weights")
        pace = _pace_net(tensors, info.train.pace_steps > 0)
        net.load_state_dict(tensors, strict=True)
    except Exception as err:  # safetensors, shape or key mismatches: one line, naming the folder
        raise MotionDataError(str(folder), f"unreadable UMSD weights ({str(err).splitlines()[0]})") from None
    normalizer = Normalizer(np.asarray(info.normalizer["mean"]), np.asarray(info.normalizer["std"]))
    skip_prior = prior if info.train.skip in PRIOR_SKIPS else (None, None)
    spectral = SpectralPrior(*bands) if info.train.skip_time == "spectral" else None
    return UmsdModel(net.eval().requires_grad_(False), normalizer, info, skip_prior, spectral, pace)


def _pace_net(tensors: dict[str, Tensor], expected: bool) -> PaceNet | None:
    """The pace regressor's weights taken out of ``tensors`` (None when it was not trained)."""
    state = {k[len(PACE_KEY_PREFIX) :]: tensors.pop(k) for k in list(tensors) if k.startswith(PACE_KEY_PREFIX)}
    if not expected:
        return None
    if not state:
        raise ValueError("no pace.* weights though pace_steps > 0")
    first = state["mlp.0.weight"]
    net = PaceNet(first.shape[1] // 4, first.shape[0])
    net.load_state_dict(state, strict=True)
    return net.eval().requires_grad_(False)
