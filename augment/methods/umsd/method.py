"""UMSD behind the method contract: trained once per run on a labelled corpus, any style zero-shot from examples.

``train`` fits the network on the train split of the labelled corpus (all of it without split files) and is
reused while the corpus and the training config match. Styles need no learning: ``check_style`` accepts any
style, ``prepare`` only validates the example clips and stores them normalised in the network's feature space.
``load`` + ``transfer``: DDIM sampling of x0 conditioned on U(content clip, style example) (sec. 3.1, Fig. 3 right:
from pure noise down to step 0, the MSM predicting x0 at every step), keeping the content's root trajectory by
inpainting, with captions revised in the style's words. A clip longer than the network's training crop is
sampled in overlapping windows of that length, blended over the overlaps. Sampler callbacks plug in by name
(``augment.methods.hooks``) and see every step's x0; output shapers are the run's, for every method alike.
"""

from __future__ import annotations

import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Literal

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field, field_validator

from motionaug.augment.corpus import MotionClip, Reject
from motionaug.augment.corpus.style_examples import MIN_EXAMPLE_FRAMES, check_motion
from motionaug.augment.diffusion import NoiseSchedule, ddim_sample
from motionaug.augment.methods.base import (
    ARTIFACT_WEIGHTS,
    CostRates,
    Prepared,
    Progress,
    StyleModel,
    TrainingSpec,
    TransferOutput,
)
from motionaug.augment.methods.common import (
    CorpusTrainedMethod,
    MotionBatch,
    clip_noise,
    configure_threads,
    files_fingerprint,
    read_artifact_json,
    read_tensors,
    revised_texts,
    style_vocab,
    tensor_bytes,
    trajectory_channels,
    write_artifact,
)
from motionaug.augment.methods.hooks import HookSpec, SamplerStep, sampler_callbacks
from motionaug.augment.methods.shaping import example_index
from motionaug.augment.methods.umsd.training import (
    META_FILE,
    WEIGHTS_FILE,
    UmsdModel,
    UmsdTrain,
    UmsdTrainConfig,
    load_umsd,
    pace_channels,
    train_umsd,
    x0_from_output,
)
from motionaug.augment.motion.batch import pad_batch
from motionaug.augment.motion.travel import travels
from motionaug.schemas.captions import Caption
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.styles import StyleSpec

METHOD_NAME = "umsd"
NUM_TIMESTEPS = 1000


REMOVED = {
    "posture": "posture and amplitude 'example' are the output shaper 'moments' now: method.shapers: [moments]",
    "amplitude": "posture and amplitude 'example' are the output shaper 'moments' now: method.shapers: [moments]",
    "amplitude_floor": "it is the moments shaper's option now: method.shapers: [{name: moments, floor: F}]",
    "shapers": "output shapers apply to every method's outputs now: method.shapers (beside method.params)",
    "x0_smooth": "it is a lab sampler callback now: see lab/README.md",
    "x0_smooth_from": "it is a lab sampler callback's option now: see lab/README.md",
    "ceiling_slack": "the spectral ceiling is a lab output shaper now: see lab/README.md",
    "ceiling_from_hz": "the spectral ceiling is a lab output shaper now: see lab/README.md",
    "smooth_frames": "smoothing is a lab output shaper now: see lab/README.md",
    "guidance_below": "interval guidance is a lab variant now: see lab/README.md",
    "guidance_motion_scale": "split guidance is a lab variant now: see lab/README.md",
    "keep": "transfers keep the content's root ground path and heading (keep: horizontal); drop the setting",
    "pace": "transfers walk the content's pace; drop the setting",
    "eta": "sampling is deterministic DDIM (eta 0); drop the setting",
    "transfer_noise_step": "sampling starts from pure noise as in the paper; drop the setting",
    "reference_pool": "the plan hands the shapers 64 pool clips to pick references from; drop the setting",
    "window": "clips longer than the training crop are sampled in windows of that length; drop the setting",
    "window_overlap": "windows overlap by at least 16 frames; drop the setting",
    "bf16": "UMSD samples in float32; drop the setting",
    "min_frames": f"shorter clips than {MIN_EXAMPLE_FRAMES} frames are rejected; drop the setting",
    "seed": "the run's seed sets the sampling noise; drop the setting",
}
NETWORK = "the network's size is the run's base_models.size (tiny, small, paper); drop the setting"
LAB_RECIPE = "a research variant the lab sets on UmsdTrainConfig (lab/README.md); drop the setting"
FIXED = "fixed at its default; drop the setting"
REMOVED_TRAIN = {
    **{f"train.{n}": NETWORK for n in ("d_model", "n_heads", "ff_size", "msm_blocks", "d_state", "expand")},
    **{f"train.{n}": NETWORK for n in ("d_conv", "dropout", "max_len")},
    **{f"train.{n}": LAB_RECIPE for n in ("denoiser", "use_ssm", "use_mha", "align_content", "skip_time")},
    **{f"train.{n}": LAB_RECIPE for n in ("content_pace", "pace_steps")},
    **{f"train.{n}": FIXED for n in ("weight_decay", "grad_clip", "min_frames", "w_rec", "threads")},
    "train.seed": "the run's seed trains the network; drop the setting",
    "train.use_dcc": "w_dcc: 0 is the sec. 4.5 ablation",
    "train.use_dsc": "w_dsc: 0 is the sec. 4.5 ablation",
    "train.w_acc": "the acceleration term is a lab loss term now: loss_terms: [{name: acceleration, weight: W}] "
    "with hooks.modules: [lab.umsd_hooks]",
}
WINDOW_OVERLAP = 16  # least overlap of two sampling windows, frames (the blend ramp)
KEPT = "horizontal"  # the content's root channels inpainted: its ground path and heading


class UmsdParams(BaseModel):
    """What a UMSD transfer is asked: the network's training, DDIM sampling with optional style guidance, and
    the sampler callbacks (``augment.methods.hooks``) that see every sampling step."""

    model_config = ConfigDict(extra="forbid")

    train: UmsdTrain = Field(default_factory=UmsdTrain)
    neutral_style: str = Field("neutral", description="The labelled corpus's name for neutral (Bandai: normal).")
    ddim_steps: int = Field(50, ge=1, le=NUM_TIMESTEPS, description="DDIM steps of a transfer (of T = 1000)")
    guidance: Literal["none", "style"] = Field(
        "none",
        description="style: x0(c, c) + w (x0(c, s) - x0(c, c)), the content as its own style example standing "
        "in for no style (Eq. 10 teaches that it gives the content back); none: x0(c, s)",
    )
    guidance_scale: float = Field(1.0, ge=0.0, description="w of style guidance (1: none; > 1: more of the style)")
    callbacks: list[HookSpec] = Field(
        default_factory=list, description="sampler callbacks called on every step's x0 prediction, in order"
    )
    batch_size: int = Field(16, ge=1, description="windows (clips) per sampling batch")
    caption_variants: int = Field(1, ge=1, description="Revised captions per output clip.")

    @field_validator("callbacks")
    @classmethod
    def _known_callbacks(cls, specs: list[HookSpec]) -> list[HookSpec]:
        return sampler_callbacks.checked(specs)


class UmsdArtifact(BaseModel):
    """A style's ``artifact.json``: the style and where its normalised examples came from."""

    model_config = ConfigDict(extra="forbid")

    version: int = 1
    method: Literal["umsd"] = METHOD_NAME
    style: StyleSpec
    examples: list[str]
    example_frames: list[int]  # as stored (the middle ``train.max_frames`` of a longer example)
    references: list[str] = []  # artefacts made when UMSD shaped its own outputs; unused
    trained_fingerprint: str
    weights_bytes: int


def trained_fingerprint(folder: Path) -> str:
    """Ties a style artefact to the network its examples were normalised for."""
    return files_fingerprint(folder, [META_FILE, WEIGHTS_FILE], "UMSD model file")


class UmsdMethod(CorpusTrainedMethod):
    """UMSD (Qian et al., ACM MM 2025) as a motionaug method."""

    name: ClassVar[str] = METHOD_NAME
    Params: ClassVar[type[BaseModel]] = UmsdParams
    params: UmsdParams
    removed_params: ClassVar[dict[str, str]] = {**REMOVED, **REMOVED_TRAIN}
    smoke_params: ClassVar[dict[str, Any]] = {
        "train": {"steps": 3, "batch_size": 2, "max_frames": 40, "log_every": 1},  # with base_models.size tiny
        "ddim_steps": 4,
        "batch_size": 4,
        "guidance": "style",
        "guidance_scale": 2.0,
    }

    cost_rates: ClassVar[CostRates] = CostRates(prepare_s=0.04, transfer_clips_per_s=0.67)

    # ---- once per run: the network ----------------------------------------------------------------------

    def training_config(self, spec: TrainingSpec) -> UmsdTrainConfig:
        """``train`` with the network of the run's ``base_models.size`` and the run's seed."""
        return self.params.train.recipe(spec.size, spec.seed)

    def fit_network(self, clips: list[MotionClip], out: Path, config: Any, progress: Progress | None) -> Path:
        return train_umsd(clips, out, config, progress)

    # ---- once per style ---------------------------------------------------------------------------------

    def check_style(self, style: StyleSpec, trained: Path | None, corpus: Path | None = None) -> None:
        """Any style: UMSD takes the style from an example motion (zero-shot, sec. 4.4), not from a label."""

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
        """No learning: validate the examples, normalise them for the trained network, store them.

        An example longer than the network's training crop (``train.max_frames``) is cut to its middle that many
        frames: style inputs were never longer in training.
        """
        assert trained is not None  # checked by ``prepare``
        model = load_umsd(trained)
        weights: dict[str, torch.Tensor] = {}
        motions: list[np.ndarray] = []
        for i, example in enumerate(examples):
            motion = self._checked_clip(example, model, f"style {style.name!r} example {example.id}")
            motions.append(motion)
            weights[f"example.{i}"] = self._stored(motion, model)
        info = UmsdArtifact(
            style=style,
            examples=[e.id for e in examples],
            example_frames=[int(weights[f"example.{i}"].shape[0]) for i in range(len(examples))],
            trained_fingerprint=trained_fingerprint(Path(trained)),
            weights_bytes=tensor_bytes(weights),
        )
        write_artifact(Path(out), info, weights)
        return Prepared(Path(out))

    def _checked_clip(self, clip: MotionClip, model: UmsdModel, source: str) -> np.ndarray:
        """A clip's raw features, checked for the network (width, finite, length, fps)."""
        motion = self._checked_length(check_motion(clip.motion, source, model.normalizer.dim), model, source)
        if clip.fps != model.info.fps:
            raise MotionDataError(source, self._fps_reason(clip, model))
        return motion

    @staticmethod
    def _stored(motion: np.ndarray, model: UmsdModel) -> torch.Tensor:
        """Normalised, cut to the middle ``train.max_frames`` frames (style inputs were never longer in training)."""
        longest = model.info.train.max_frames
        if motion.shape[0] > longest:
            first = (motion.shape[0] - longest) // 2
            motion = motion[first : first + longest]
        return torch.from_numpy(model.normalizer.normalize(motion).astype(np.float32))

    def _checked_length(self, motion: np.ndarray, model: UmsdModel, source: str) -> np.ndarray:
        if motion.shape[0] < MIN_EXAMPLE_FRAMES:
            raise MotionDataError(source, f"too short: {motion.shape[0]} frames < {MIN_EXAMPLE_FRAMES}")
        if motion.shape[0] > model.net.config.max_len:
            raise MotionDataError(source, f"{motion.shape[0]} frames exceed the network's {model.net.config.max_len}")
        return motion

    @staticmethod
    def _fps_reason(clip: MotionClip, model: UmsdModel) -> str:
        return f"{clip.fps:g} fps, the network was trained at {model.info.fps:g} fps"

    def load(self, artifact: Path, trained: Path | None) -> StyleModel:
        if trained is None:
            raise MotionDataError(f"{METHOD_NAME} load", "needs the trained network (the train step's folder)")
        configure_threads()
        info = read_artifact_json(Path(artifact), UmsdArtifact, METHOD_NAME, "a UMSD style artefact")
        found = trained_fingerprint(Path(trained))
        if found != info.trained_fingerprint:
            raise MotionDataError(
                str(artifact), f"prepared for UMSD network {info.trained_fingerprint}, {trained} is {found}"
            )
        tensors = read_tensors(Path(artifact) / ARTIFACT_WEIGHTS)
        examples = [tensors[f"example.{i}"] for i in range(len(info.examples))]
        return UmsdStyleModel(info.style, load_umsd(trained), examples, self.params)


def window_spans(frames: int, window: int, overlap: int = WINDOW_OVERLAP) -> list[tuple[int, int]]:
    """[start, end) of the sampling windows of a ``frames``-long clip: one when it fits (or ``window`` is 0), else
    the fewest windows of ``window`` frames, evenly spaced, whose neighbours overlap by >= ``overlap``."""
    if window <= 0 or frames <= window:
        return [(0, frames)]
    stride = max(1, window - overlap)
    count = -(-(frames - window) // stride) + 1
    starts = [round(k * (frames - window) / (count - 1)) for k in range(count)]
    return [(a, a + window) for a in starts]


def blend_ramp(start: int, end: int, frames: int, overlap: int) -> np.ndarray:
    """(end - start, 1) blend weights of a window: rising over its first ``overlap`` frames unless it starts the
    clip, falling over its last ``overlap`` unless it ends it; always > 0."""
    length = end - start
    t = np.arange(length, dtype=np.float32)
    ramp = np.ones(length, np.float32)
    if overlap > 0 and start > 0:
        ramp = np.minimum(ramp, (t + 1) / (overlap + 1))
    if overlap > 0 and end < frames:
        ramp = np.minimum(ramp, (length - t) / (overlap + 1))
    return ramp[:, None]


@dataclass
class _Job:
    index: int
    clip: MotionClip
    motion: np.ndarray  # validated raw features
    captions: list[Caption]


class UmsdStyleModel:
    """The trained network and one style's examples; stylizes batches of whole clips (``StyleModel``)."""

    def __init__(
        self,
        style: StyleSpec,
        model: UmsdModel,
        examples: Sequence[torch.Tensor],
        params: UmsdParams,
    ):
        if not examples:
            raise MotionDataError(f"style {style.name!r}", "no example motions")
        self.spec = style
        self.style = style.name
        self.model = model
        self.net = model.net.eval().requires_grad_(False)
        self.examples = [e.float() for e in examples]
        fps = model.info.fps
        raw = (model.normalizer.denormalize(e.numpy()) for e in self.examples)
        self.examples_travel = [travels(m, fps) for m in raw]
        self.params = params
        self.vocab = style_vocab(style.words, style.name)
        self.kept = trajectory_channels(KEPT)
        self.schedule = NoiseSchedule.cosine(NUM_TIMESTEPS)  # the training schedule (``skip_x0``)
        self.callbacks = sampler_callbacks.create_all(params.callbacks, "config method.params.callbacks")

    def _job(self, index: int, clip: MotionClip, seed: int) -> _Job:
        source = f"clip {clip.id}"
        motion = check_motion(clip.motion, source, self.model.normalizer.dim, MIN_EXAMPLE_FRAMES)
        if motion.shape[0] > self.net.config.max_len:
            raise MotionDataError(source, f"{motion.shape[0]} frames exceed the network's {self.net.config.max_len}")
        if clip.fps != self.model.info.fps:
            raise MotionDataError(source, UmsdMethod._fps_reason(clip, self.model))
        clip_seed = seed + zlib.crc32(clip.id.encode("utf-8"))
        captions = revised_texts(clip, self.spec.words, self.params.caption_variants, clip_seed, self.vocab)
        return _Job(index, clip, motion, captions)

    def example_index(self, clip: MotionClip, motion: np.ndarray) -> int:
        """Which style example a clip (raw features ``motion``) is conditioned on: the one that shapes its output
        too (``shaping.example_index``)."""
        return example_index(clip.id, travels(motion, clip.fps), self.examples_travel)

    def transfer(self, clips: Sequence[MotionClip], seed: int = 0) -> list[TransferOutput | Reject]:
        """Stylize a batch; a clip that cannot be used (NaN, wrong width, too short or long) is a ``Reject``."""
        results: list[TransferOutput | Reject | None] = [None] * len(clips)
        jobs: list[_Job] = []
        for i, clip in enumerate(clips):
            try:
                jobs.append(self._job(i, clip, seed))
            except MotionDataError as err:
                results[i] = Reject.from_error(clip.id, err)
        size = self.params.batch_size
        for start in range(0, len(jobs), size):
            chunk = jobs[start : start + size]
            for job, output in zip(chunk, self._transfer_batch(chunk, seed)):
                results[job.index] = output
        return [r for r in results if r is not None]

    @torch.no_grad()
    def sample(self, content: MotionBatch, style: torch.Tensor, style_mask: torch.Tensor, noise: torch.Tensor):
        """DDIM from pure noise with the condition U(content, style) computed once; the kept channels are
        inpainted from the content; every step's x0 prediction goes through the sampler callbacks. Normalised
        (B, T, F). Style guidance's stand-in for no style is the content itself."""
        p = self.params
        guided = p.guidance == "style" and p.guidance_scale != 1.0
        cond = self.net.condition(content.x, content.mask, style, style_mask)
        own = self.net.condition(content.x, content.mask, content.x, content.mask) if guided else cond
        skip, free = self.model.info.train.skip, pace_channels(self.model.info.train)
        prior, spectral = self.model.skip_prior, self.model.spectral

        def model_fn(x_t: torch.Tensor, t: torch.Tensor, *, uncond: bool = False) -> torch.Tensor:
            out = self.net.denoise(x_t, t, own if uncond else cond, content.mask).to(x_t.dtype)
            x0 = x0_from_output(skip, self.schedule, x_t, t, out, prior, content.x, spectral, content.mask, free)
            for callback in self.callbacks:
                x0 = callback(SamplerStep(int(t[0]), x0, x_t, content.mask))
            return x0

        return ddim_sample(
            model_fn,
            content.x.shape,
            steps=p.ddim_steps,
            eta=0.0,
            noise=noise,
            inpaint=content.inpaint(self.kept),
            guidance_scale=p.guidance_scale if guided else None,
        ).float()

    def window_size(self) -> int:
        """Frames per sampling window (0: whole clips)."""
        return self.model.info.train.max_frames

    def _sample_windows(self, jobs: Sequence[_Job], seed: int) -> list[np.ndarray]:
        """Normalised outputs (T_i, F) of whole clips, sampled window by window.

        The network was trained on crops of ``train.max_frames`` frames: a longer clip is cut into equal windows
        of ``window`` frames overlapping by at least ``window_overlap``, each conditioned on U(content window,
        style example), and the windows are blended with linear ramps over their overlaps. A window's initial
        noise is its slice of the clip's noise, so the output depends only on the clip, the example and the seed.
        """
        norm = self.model.normalizer
        pieces: list[tuple[int, int, int]] = []  # (job, first frame, end)
        for j, job in enumerate(jobs):
            pieces += [(j, a, b) for a, b in window_spans(job.motion.shape[0], self.window_size())]
        motions = [norm.normalize(job.motion).astype(np.float32) for job in jobs]
        noises = [clip_noise((1, *m.shape), [job.clip.id], seed)[0] for m, job in zip(motions, jobs)]
        sums = [np.zeros_like(m) for m in motions]
        weights = [np.zeros((m.shape[0], 1), np.float32) for m in motions]
        size = self.params.batch_size
        for start in range(0, len(pieces), size):
            chunk = pieces[start : start + size]
            content = MotionBatch.from_motions([motions[j][a:b] for j, a, b in chunk], None)
            picks = [self.example_index(jobs[j].clip, jobs[j].motion) for j, _, _ in chunk]
            style, style_mask = pad_batch([self.examples[i] for i in picks])
            noise, _ = pad_batch([noises[j][a:b] for j, a, b in chunk])
            out = self.sample(content, style, style_mask, noise).numpy()
            for row, (j, a, b) in enumerate(chunk):
                ramp = blend_ramp(a, b, motions[j].shape[0], WINDOW_OVERLAP)
                sums[j][a:b] += out[row, : b - a] * ramp
                weights[j][a:b] += ramp
        return [s / w for s, w in zip(sums, weights)]

    def _transfer_batch(self, jobs: Sequence[_Job], seed: int) -> list[TransferOutput | Reject]:
        norm = self.model.normalizer
        outputs = self._sample_windows(jobs, seed)
        results: list[TransferOutput | Reject] = []
        for i, job in enumerate(jobs):
            motion = norm.denormalize(outputs[i]).astype(np.float32)
            motion[:, self.kept] = job.motion[:, self.kept]  # exactly the content's, not up to rounding
            if not np.isfinite(motion).all():
                results.append(Reject(id=job.clip.id, source=f"clip {job.clip.id}", reason="non-finite UMSD output"))
                continue
            results.append(
                TransferOutput(source_id=job.clip.id, style=self.style, motion=motion, captions=job.captions)
            )
        return results
