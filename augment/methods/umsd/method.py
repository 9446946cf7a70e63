"""UMSD behind the method contract: trained once per run on a labelled corpus, any style zero-shot from examples.

``train`` fits the network on the train split of the labelled corpus (all of it without split files) and is
reused while the corpus and the training config match. Styles need no learning: ``check_style`` accepts any
style, ``prepare`` only validates the example clips and stores them normalised in the network's feature space.
``load`` + ``transfer``: DDIM sampling of x0 conditioned on U(content clip, style example) (sec. 3.1, Fig. 3 right:
from pure noise down to step 0, the MSM predicting x0 at every step), keeping the content's root trajectory by
inpainting, with captions revised in the style's words. A clip longer than the network's training crop is
sampled in overlapping windows of that length, blended over the overlaps (``window``). ``transfer_noise_step``
< 1000 starts instead from the content noised to that step (SDEdit), which keeps more of the content's timing.
"""

from __future__ import annotations

import json
import time
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Literal

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field

from motionaug.augment.corpus import MotionClip, Reject
from motionaug.augment.corpus.style_examples import MIN_EXAMPLE_FRAMES, check_motion
from motionaug.augment.device import bf16_autocast
from motionaug.augment.diffusion import NoiseSchedule, ddim_sample, off_own_motion, start_step_for
from motionaug.augment.io import atomic_write_text
from motionaug.augment.methods.base import (
    ARTIFACT_WEIGHTS,
    Progress,
    StyleModel,
    TransferOutput,
)
from motionaug.augment.methods.common import (
    LabelledNetworkMethod,
    MotionBatch,
    clip_noise,
    configure_threads,
    feet_channels,
    files_fingerprint,
    read_artifact_json,
    read_tensors,
    revised_texts,
    style_vocab,
    tensor_bytes,
    trajectory_channels,
    write_artifact,
)
from motionaug.augment.methods.umsd.pace import pace_ratio
from motionaug.augment.methods.umsd.training import (
    META_FILE,
    WEIGHTS_FILE,
    UmsdModel,
    UmsdTrainConfig,
    load_umsd,
    pace_channels,
    train_umsd,
    x0_from_output,
)
from motionaug.augment.motion.batch import pad_batch
from motionaug.augment.motion.features import feature_slices
from motionaug.augment.motion.kinematics import gaussian_smooth_time
from motionaug.augment.motion.spectrum import spectral_ceiling
from motionaug.augment.motion.tempo import paced
from motionaug.augment.outputs.checksums import RUN_FACTS
from motionaug.schemas.captions import Caption
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.skeleton import T2M
from motionaug.schemas.styles import StyleSpec

METHOD_NAME = "umsd"
NUM_TIMESTEPS = 1000
CEILING_BANDS = 16  # frequency bands of ``ceiling_slack``: fps / 32 Hz wide (0.625 Hz at 20 fps)


class UmsdParams(BaseModel):
    model_config = ConfigDict(extra="forbid")

    train: UmsdTrainConfig = Field(default_factory=UmsdTrainConfig)
    neutral_style: str = Field("neutral", description="The labelled corpus's name for neutral (Bandai: normal).")
    ddim_steps: int = Field(50, ge=1, le=NUM_TIMESTEPS, description="DDIM steps of a transfer (eta below)")
    eta: float = Field(0.0, ge=0.0, le=1.0, description="DDIM eta (0: deterministic given the initial noise)")
    transfer_noise_step: int = Field(
        NUM_TIMESTEPS,
        ge=1,
        le=NUM_TIMESTEPS,
        description="1000: sample from pure noise (the paper); K < 1000: start from the content noised to step K",
    )
    guidance: Literal["none", "style", "style-off-content", "style-contrast"] = Field(
        "none",
        description="style: x0(c, c) + w (x0(c, s) - x0(c, c)), the content as its own style example standing in "
        "for no style (Eq. 10's rows teach that it gives the content back); style-off-content: x0(c, s) + (w - 1) "
        "times that direction less its part along the content's own motion, channel by channel (posture and new "
        "motion are extrapolated, the content's gestures are not shrunk or grown); style-contrast: x0(c, r) + "
        "w (x0(c, s) - x0(c, r)), r the pool clip whose root motion is nearest the example's (its content performed "
        "plainly), so what the example's content carries (a walk's steps) cancels and only its style is "
        "extrapolated; none: x0(c, s)",
    )
    guidance_scale: float = Field(1.0, ge=0.0, description="w of style guidance (1: none; > 1: more of the style)")
    guidance_motion_scale: float | None = Field(
        None,
        ge=0.0,
        description="with style or style-contrast guidance: the scale of the guidance direction's motion (each "
        "channel less its mean over the clip's frames), guidance_scale then scaling only its mean, the posture: "
        "x0_u + w mean(d) + w_motion (d - mean(d)), d = x0_c - x0_u. A style's posture extrapolated without "
        "exaggerating how the limbs move, which is what carries the content (None: w for both)",
    )
    guidance_below: int = Field(
        NUM_TIMESTEPS,
        ge=1,
        le=NUM_TIMESTEPS,
        description="style guidance only at timesteps below this, unguided above (guidance limited to an interval, "
        "Kynkaanniemi et al. 2024): the gross motion forms unguided; 1000: guidance at every step",
    )
    keep: Literal["horizontal", "root", "heading", "none"] = Field(
        "horizontal",
        description="content channels kept by inpainting: root xz + yaw velocities (+ height: root); heading: yaw "
        "velocity + height, the pace left to the network (a network trained with content_pace: false)",
    )
    pace: Literal["content", "example"] = Field(
        "content",
        description="the ground speed the kept root path is walked at: the content's; or example, the content's "
        "times the factor the network's pace regressor reads off the content and the style example (a network "
        "trained with pace_steps > 0; augment.methods.umsd.pace), so slow and fast styles change the pace",
    )
    posture: Literal["network", "example"] = Field(
        "network",
        description="example: the root height's and each pose channel's (ric, rot) mean over the output's frames is "
        "set to the content's plus the style example's less its reference's (the pool clip standing in for the "
        "example's content performed plainly): the style's posture taken from the examples, the network's outputs "
        "keeping their motion, so guidance cannot exaggerate a posture into another motion (network: as sampled)",
    )
    amplitude: Literal["network", "example"] = Field(
        "network",
        description="example: each pose, root height and joint velocity channel's variance over the output's "
        "frames is set to the content's plus the style example's less its reference's, floored at "
        "(amplitude_floor x the content's standard deviation)^2, by scaling the output's deviations from its own "
        "mean: what posture: example does for the means, for the size of the motion (AdaIN's second moment, "
        "Huang & Belongie 2017, between the example and its plain stand-in), so a style that shrinks gestures "
        "shrinks them and one that adds swings grows them, and jitter the content lacks is scaled down with the "
        "rest (network: as sampled)",
    )
    amplitude_floor: float = Field(0.25, ge=0.0, le=1.0, description="least std of a channel, x the content's")
    reference_pool: int = Field(
        64, ge=1, description="content clips the plan hands ``prepare`` to pick style-contrast references from"
    )
    smooth_frames: float = Field(
        0.0,
        ge=0.0,
        description="sigma (frames) of a Gaussian over time applied to the output's generated channels but the "
        "foot contacts: removes the frame-to-frame jitter of the network's outputs, which the eye and a content "
        "classifier read as extra motion (0: none)",
    )
    x0_smooth: float = Field(
        0.0,
        ge=0.0,
        description="sigma (frames) of a Gaussian over time applied to every sampling step's x0 prediction at "
        "timesteps >= x0_smooth_from, but in the foot contacts: the network's x0 predictions shake a little from "
        "frame to frame, and each DDIM step feeds that shake back as signal, so it grows over the steps; smoothed "
        "early, the last steps start from a clean motion and keep their own fast detail (0: none)",
    )
    x0_smooth_from: int = Field(0, ge=0, le=NUM_TIMESTEPS, description="lowest timestep x0_smooth applies at")
    ceiling_slack: float = Field(
        0.0,
        ge=0.0,
        description="> 0: each generated channel's power per frequency band from ceiling_from_hz up is capped at "
        "slack^2 times the larger of the content clip's and the style example's (augment.motion.spectrum."
        "spectral_ceiling): removes the jitter at frequencies neither motion has and keeps the fast parts either "
        "has, where a Gaussian over time takes both (0: none)",
    )
    ceiling_from_hz: float = Field(2.5, ge=0.0, description="lowest frequency the ceiling applies to, Hz")

    @property
    def needs_references(self) -> bool:
        """Whether ``prepare`` picks a plain stand-in for each example's content from the content pool."""
        return self.guidance == "style-contrast" or self.posture == "example" or self.amplitude == "example"

    window: int | None = Field(
        None,
        ge=0,
        description="a content clip longer than this is transferred in overlapping windows of this many frames, "
        "blended over their overlaps (None: the network's training crop train.max_frames; 0: whole clips)",
    )
    window_overlap: int = Field(16, ge=0, description="least overlap of two windows, frames (the blend ramp)")
    batch_size: int = Field(16, ge=1, description="windows (clips) per sampling batch")
    bf16: bool | None = Field(False, description="bf16 autocast for sampling (None: where the CPU has bf16 units)")
    min_frames: int = Field(MIN_EXAMPLE_FRAMES, ge=2, description="shorter content clips and examples are rejected")
    caption_variants: int = Field(1, ge=1, description="Revised captions per output clip.")
    seed: int = Field(0, description="added to the workflow's seed for the sampling noise")


class UmsdArtifact(BaseModel):
    """A style's ``artifact.json``: the style and where its normalised examples came from."""

    model_config = ConfigDict(extra="forbid")

    version: int = 1
    method: Literal["umsd"] = METHOD_NAME
    style: StyleSpec
    examples: list[str]
    example_frames: list[int]  # as stored (the middle ``train.max_frames`` of a longer example)
    references: list[str] = []  # per example, the pool clip standing in for its content without the style
    trained_fingerprint: str
    weights_bytes: int


def trained_fingerprint(folder: Path) -> str:
    """Ties a style artefact to the network its examples were normalised for."""
    return files_fingerprint(folder, [META_FILE, WEIGHTS_FILE], "UMSD model file")


class UmsdMethod(LabelledNetworkMethod):
    """UMSD (Qian et al., ACM MM 2025) as a motionaug method."""

    name: ClassVar[str] = METHOD_NAME
    Params: ClassVar[type[BaseModel]] = UmsdParams
    params: UmsdParams
    smoke_params: ClassVar[dict[str, Any]] = {
        "train": {
            "steps": 3,
            "batch_size": 2,
            "max_frames": 40,
            "d_model": 32,
            "n_heads": 2,
            "ff_size": 64,
            "msm_blocks": 1,
            "d_state": 4,
            "log_every": 1,
        },
        "ddim_steps": 4,
        "batch_size": 4,
        "guidance": "style-contrast",  # the plan's pool reaches ``prepare`` and the references the sampler
        "guidance_scale": 2.0,
        "posture": "example",  # and the examples' moments against the references
        "amplitude": "example",
    }

    @property
    def content_pool(self) -> int:  # type: ignore[override]
        """Content clips ``prepare`` sees: style-contrast guidance picks its references from them."""
        return self.params.reference_pool if self.params.needs_references else 0

    # ---- once per run: the network ----------------------------------------------------------------------

    def fit_network(self, clips: list[MotionClip], out: Path, progress: Progress | None) -> Path:
        return train_umsd(clips, out, self.params.train, progress)

    # ---- once per style ---------------------------------------------------------------------------------

    def check_style(self, style: StyleSpec, trained: Path | None, corpus: Path | None = None) -> None:
        """Any style: UMSD takes the style from an example motion (zero-shot, sec. 4.4), not from a label."""

    def prepare(
        self,
        style: StyleSpec,
        examples: Sequence[MotionClip],
        trained: Path | None,
        content: Sequence[MotionClip],
        out: Path,
        seed: int | None = None,
        progress: Progress | None = None,
    ) -> Path:
        """No learning: validate the examples, normalise them for the trained network, store them.

        An example longer than the network's training crop (``train.max_frames``) is cut to its middle that many
        frames: style inputs were never longer in training.
        """
        start = time.perf_counter()
        if trained is None:
            raise MotionDataError(f"{METHOD_NAME} prepare", "needs the trained network (the train step's folder)")
        if not examples:
            raise MotionDataError(f"style {style.name!r}", "no example clips")
        model = load_umsd(trained)
        weights: dict[str, torch.Tensor] = {}
        motions: list[np.ndarray] = []
        for i, example in enumerate(examples):
            motion = self._checked_clip(example, model, f"style {style.name!r} example {example.id}")
            motions.append(motion)
            weights[f"example.{i}"] = self._stored(motion, model)
        references: list[str] = []
        if self.params.needs_references:
            candidates = self._reference_candidates(content, model)
            if not candidates:
                raise MotionDataError(
                    f"style {style.name!r}",
                    "style-contrast guidance and posture or amplitude: example need usable content clips to pick from",
                )
            for i, motion in enumerate(motions):
                reference_id, reference = nearest_root_motion(motion, candidates)
                references.append(reference_id)
                weights[f"reference.{i}"] = self._stored(reference, model)
        info = UmsdArtifact(
            style=style,
            examples=[e.id for e in examples],
            example_frames=[int(weights[f"example.{i}"].shape[0]) for i in range(len(examples))],
            references=references,
            trained_fingerprint=trained_fingerprint(Path(trained)),
            weights_bytes=tensor_bytes(weights),
        )
        write_artifact(Path(out), info, weights)
        seconds = {"prepare_s": time.perf_counter() - start}
        atomic_write_text(Path(out) / RUN_FACTS, json.dumps(seconds) + "\n")  # outside the artefact's checksum
        return Path(out)

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

    def _reference_candidates(self, pool: Sequence[MotionClip], model: UmsdModel) -> dict[str, np.ndarray]:
        """The pool's usable clips by id (an unusable one is rejected again, and reported, by ``transfer``)."""
        found = {}
        for clip in pool:
            try:
                found[clip.id] = self._checked_clip(clip, model, f"clip {clip.id}")
            except MotionDataError:
                continue
        return found

    def _checked_length(self, motion: np.ndarray, model: UmsdModel, source: str) -> np.ndarray:
        if motion.shape[0] < self.params.min_frames:
            raise MotionDataError(source, f"too short: {motion.shape[0]} frames < {self.params.min_frames}")
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
        references = []
        if self.params.needs_references:
            if len(info.references) != len(examples):
                raise MotionDataError(
                    str(artifact),
                    "prepared without references; style-contrast guidance and posture or amplitude: example need them",
                )
            references = [tensors[f"reference.{i}"] for i in range(len(examples))]
        return UmsdStyleModel(info.style, load_umsd(trained), examples, self.params, references)


def with_posture(output: np.ndarray, content: np.ndarray, example: torch.Tensor, reference: torch.Tensor) -> np.ndarray:
    """A normalised output (T, F) whose root height and pose channels' means over frames are the content's + the
    example's - the reference's (``UmsdParams.posture``; a kept root height is restored afterwards)."""
    slices = feature_slices(T2M)
    pose = np.r_[slices["root_y"], slices["ric"], slices["rot"]]
    target = content[:, pose].mean(axis=0) + example.numpy()[:, pose].mean(axis=0) - reference.numpy()[:, pose].mean(0)
    out = output.copy()
    out[:, pose] += (target - output[:, pose].mean(axis=0)).astype(np.float32)
    return out


AMPLITUDE_MOST = 4.0  # the largest factor an output channel's deviations are scaled by (near-still channels)


def with_amplitude(
    output: np.ndarray, content: np.ndarray, example: torch.Tensor, reference: torch.Tensor, floor: float
) -> np.ndarray:
    """A normalised output (T, F) whose root height, pose and joint velocity channels vary over frames as much as
    the content's + the example's - the reference's variance says (``UmsdParams.amplitude``)."""
    slices = feature_slices(T2M)
    cols = np.r_[slices["root_y"], slices["ric"], slices["rot"], slices["local_vel"]]
    target = content[:, cols].var(0) + example.numpy()[:, cols].var(0) - reference.numpy()[:, cols].var(0)
    target = np.maximum(target, floor**2 * content[:, cols].var(axis=0))
    mean = output[:, cols].mean(axis=0)
    scale = np.sqrt(target) / np.maximum(output[:, cols].std(axis=0), 1e-6)
    out = output.copy()
    out[:, cols] = (mean + (output[:, cols] - mean) * np.minimum(scale, AMPLITUDE_MOST)).astype(np.float32)
    return out


def shaped(
    output: np.ndarray,
    content: np.ndarray,
    example: torch.Tensor,
    reference: torch.Tensor | None,
    fps: float,
    params: UmsdParams,
) -> np.ndarray:
    """A sampled normalised output (T, F) after what ``params`` take from the examples (amplitude, then posture:
    ``reference`` is needed for either) and the spectral ceiling; smoothing, in raw units, comes after."""
    if params.amplitude == "example" or params.posture == "example":
        if reference is None:
            raise ValueError("posture or amplitude: example needs the example's reference")
        if params.amplitude == "example":
            output = with_amplitude(output, content, example, reference, params.amplitude_floor)
        if params.posture == "example":
            output = with_posture(output, content, example, reference)
    if params.ceiling_slack > 0:
        output = under_ceiling(output, content, example, fps, params)
    return output


def split_guidance(direction: torch.Tensor, mask: torch.Tensor, posture: float, motion: float) -> torch.Tensor:
    """``posture`` times the direction's mean over each row's valid frames (``mask`` (B, T)) + ``motion`` times the
    rest: (B, T, F)."""
    weight = mask.to(direction.dtype).unsqueeze(-1)
    mean = (direction * weight).sum(dim=1, keepdim=True) / weight.sum(dim=1, keepdim=True).clamp(min=1.0)
    return posture * mean + motion * (direction - mean)


def signal_channels(n_feats: int = T2M.feature_dim) -> list[int]:
    """Every channel but the foot contacts (labels, not signals): what smoothing over time may touch."""
    feet = set(feet_channels())
    return [c for c in range(n_feats) if c not in feet]


def masked_smooth(x: torch.Tensor, mask: torch.Tensor, sigma: float, channels: Sequence[int]) -> torch.Tensor:
    """(B, T, F) ``x`` with ``channels`` Gaussian-filtered over time within each row's valid frames (``mask``
    (B, T), valid first): each row's last valid frame stands in for its padding, as the filter's edge mode would
    for the clip alone, so a row's result does not depend on its batch mates."""
    last = (mask.sum(dim=1, keepdim=True) - 1).clamp(min=0)
    frames = torch.minimum(torch.arange(x.shape[1], device=x.device)[None], last)  # (B, T)
    cols = list(channels)
    extended = torch.gather(x[..., cols], 1, frames[..., None].expand(-1, -1, len(cols)))
    out = x.clone()
    out[..., cols] = torch.where(mask[..., None], gaussian_smooth_time(extended, sigma, time_dim=1), x[..., cols])
    return out


def smoothed(motion: np.ndarray, sigma: float) -> np.ndarray:
    """``motion`` with every channel but the foot contacts (labels, not signals) Gaussian-filtered over time."""
    if sigma <= 0:
        return motion
    signal = signal_channels(motion.shape[1])
    out = motion.copy()
    out[:, signal] = gaussian_smooth_time(torch.from_numpy(motion[:, signal]), sigma, time_dim=0).numpy()
    return out


def under_ceiling(
    output: np.ndarray, content: np.ndarray, example: torch.Tensor, fps: float, params: UmsdParams
) -> np.ndarray:
    """A normalised output (T, F) under the spectral ceiling (``ceiling_slack``) of its normalised content clip and
    style example; the foot contacts, labels rather than signals, untouched."""
    from_band = min(CEILING_BANDS, int(np.ceil(params.ceiling_from_hz / (fps / 2.0 / CEILING_BANDS) - 1e-9)))
    references = [torch.from_numpy(content), example]
    capped = spectral_ceiling(torch.from_numpy(output), references, CEILING_BANDS, from_band, params.ceiling_slack)
    out = capped.numpy().astype(np.float32)
    out[:, feet_channels()] = output[:, feet_channels()]
    return out


def root_motion(motion: np.ndarray) -> np.ndarray:
    """What a clip's root does, a summary that style changes little: the log of its mean ground speed (slow and
    fast styles move a walk's speed by a factor, far less than a walk differs from standing), the direction of its
    mean velocity in the facing frame (sideways, either side, and forwards: a walk is not a sidestep or a backward
    walk), its turning rate (per frame) and the spread of the root height. Not the share of frames with a foot
    down: slow styles raise it as much as standing still does."""
    slices = feature_slices(T2M)
    velocity = motion[:, slices["root_lin_vel"]]
    speed = np.linalg.norm(velocity, axis=1).mean()
    sideways, forwards = velocity.mean(axis=0) / (speed + 1e-6)
    turning = np.abs(motion[:, slices["root_rot_vel"]]).mean()
    return np.array([np.log(speed + 1e-3), abs(sideways), forwards, turning, motion[:, slices["root_y"]].std()])


def nearest_root_motion(example: np.ndarray, candidates: dict[str, np.ndarray]) -> tuple[str, np.ndarray]:
    """The candidate whose ``root_motion`` is nearest the example's, each summary entry scaled by its spread over
    the candidates (ties: the smallest id). A stand-in for the example's content performed without its style."""
    ids = sorted(candidates)
    summaries = np.stack([root_motion(candidates[i]) for i in ids])
    scale = summaries.std(axis=0) + 1e-6
    distance = np.linalg.norm((summaries - root_motion(example)) / scale, axis=1)
    best = ids[int(np.argmin(distance))]
    return best, candidates[best]


def window_spans(frames: int, window: int, params: UmsdParams) -> list[tuple[int, int]]:
    """[start, end) of the sampling windows of a ``frames``-long clip: one when it fits (or ``window`` is 0), else
    the fewest windows of ``window`` frames, evenly spaced, whose neighbours overlap by >= ``window_overlap``."""
    if window <= 0 or frames <= window:
        return [(0, frames)]
    stride = max(1, window - params.window_overlap)
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
    motion: np.ndarray  # validated raw features, paced (``UmsdStyleModel.paced``)
    captions: list[Caption]


class UmsdStyleModel:
    """The trained network and one style's examples; stylizes batches of whole clips (``StyleModel``)."""

    def __init__(
        self,
        style: StyleSpec,
        model: UmsdModel,
        examples: Sequence[torch.Tensor],
        params: UmsdParams,
        references: Sequence[torch.Tensor] = (),
    ):
        if not examples:
            raise MotionDataError(f"style {style.name!r}", "no example motions")
        self.spec = style
        self.style = style.name
        self.model = model
        self.net = model.net.eval().requires_grad_(False)
        self.examples = [e.float() for e in examples]
        self.references = [r.float() for r in references]  # style-contrast guidance: one per example
        self.params = params
        self.vocab = style_vocab(style.words, style.name)
        self.kept = [] if params.keep == "none" else trajectory_channels(params.keep)
        if params.pace == "example" and model.pace is None:
            raise MotionDataError(f"style {style.name!r}", "pace: example needs a UMSD network trained with pace_steps")
        self.schedule = NoiseSchedule.cosine(NUM_TIMESTEPS)  # the training schedule (``skip_x0``)
        self.signal = signal_channels()

    def _job(self, index: int, clip: MotionClip, seed: int) -> _Job:
        source = f"clip {clip.id}"
        motion = check_motion(clip.motion, source, self.model.normalizer.dim, self.params.min_frames)
        if motion.shape[0] > self.net.config.max_len:
            raise MotionDataError(source, f"{motion.shape[0]} frames exceed the network's {self.net.config.max_len}")
        if clip.fps != self.model.info.fps:
            raise MotionDataError(source, UmsdMethod._fps_reason(clip, self.model))
        clip_seed = seed + zlib.crc32(clip.id.encode("utf-8"))
        captions = revised_texts(clip, self.spec.words, self.params.caption_variants, clip_seed, self.vocab)
        return _Job(index, clip, self.paced(clip.id, motion), captions)

    def paced(self, clip_id: str, motion: np.ndarray) -> np.ndarray:
        """The content clip as the transfer keeps it: with ``pace: example`` its root carried at the speed the
        pace regressor gives for this clip and its style example (``augment.methods.umsd.pace``)."""
        if self.params.pace == "content" or self.model.pace is None:
            return motion
        content = self.model.normalizer.normalize(motion).astype(np.float32)
        ratio = pace_ratio(self.model.pace, content, self.examples[self.example_index(clip_id)])
        return paced(motion, ratio)

    def example_index(self, clip_id: str) -> int:
        """Which style example a clip is conditioned on: one per clip, chosen by its id (batch-independent)."""
        return zlib.crc32(clip_id.encode("utf-8")) % len(self.examples)

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
    def sample(
        self,
        content: MotionBatch,
        style: torch.Tensor,
        style_mask: torch.Tensor,
        noise: torch.Tensor,
        reference: tuple[torch.Tensor, torch.Tensor] | None = None,
    ):
        """DDIM from pure noise (or from the content noised to ``transfer_noise_step``) with the condition
        U(content, style) computed once; the kept channels are inpainted from the content. Normalised (B, T, F).
        ``reference`` (motions, mask): the guidance's stand-in for no style (default: the content itself)."""
        p = self.params
        partial = p.transfer_noise_step < NUM_TIMESTEPS
        split = p.guidance_motion_scale is not None and p.guidance != "none"
        guided = p.guidance != "none" and (p.guidance_scale != 1.0 or split)
        off_content = guided and (p.guidance == "style-off-content" or split)  # guidance combined here
        plain = (content.x, content.mask) if reference is None else reference
        with bf16_autocast(p.bf16):
            cond = self.net.condition(content.x, content.mask, style, style_mask)
            own = self.net.condition(content.x, content.mask, *plain) if guided else cond

            skip, free = self.model.info.train.skip, pace_channels(self.model.info.train)
            prior, spectral = self.model.skip_prior, self.model.spectral

            def x0_of(x_t: torch.Tensor, t: torch.Tensor, condition: torch.Tensor) -> torch.Tensor:
                out = self.net.denoise(x_t, t, condition, content.mask).to(x_t.dtype)
                x0 = x0_from_output(skip, self.schedule, x_t, t, out, prior, content.x, spectral, content.mask, free)
                if p.x0_smooth > 0 and int(t[0]) >= p.x0_smooth_from:  # linear: commutes with the guidance
                    x0 = masked_smooth(x0, content.mask, p.x0_smooth, self.signal)
                return x0

            def model_fn(x_t: torch.Tensor, t: torch.Tensor, *, uncond: bool = False) -> torch.Tensor:
                uncond = uncond and int(t[0]) < p.guidance_below  # above the interval x0_u = x0_c: no guidance
                x0_c = x0_of(x_t, t, own if uncond else cond)
                if not off_content or int(t[0]) >= p.guidance_below:
                    return x0_c
                x0_u = x0_of(x_t, t, own)
                if split:
                    return x0_u + split_guidance(x0_c - x0_u, content.mask, p.guidance_scale, p.guidance_motion_scale)
                direction = off_own_motion(x0_c - x0_u, content.x, content.mask)
                return x0_c + (p.guidance_scale - 1.0) * direction

            return ddim_sample(
                model_fn,
                content.x.shape,
                steps=p.ddim_steps,
                eta=p.eta,
                start_step=start_step_for(p.transfer_noise_step, p.ddim_steps) if partial else None,
                x_start=content.x if partial else None,
                noise=noise,
                inpaint=content.inpaint(self.kept) if self.kept else None,
                guidance_scale=p.guidance_scale if guided and not off_content else None,
            ).float()

    def window_size(self) -> int:
        """Frames per sampling window (0: whole clips)."""
        return self.model.info.train.max_frames if self.params.window is None else self.params.window

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
            pieces += [(j, a, b) for a, b in window_spans(job.motion.shape[0], self.window_size(), self.params)]
        motions = [norm.normalize(job.motion).astype(np.float32) for job in jobs]
        noises = [clip_noise((1, *m.shape), [job.clip.id], seed + self.params.seed)[0] for m, job in zip(motions, jobs)]
        sums = [np.zeros_like(m) for m in motions]
        weights = [np.zeros((m.shape[0], 1), np.float32) for m in motions]
        size = self.params.batch_size
        for start in range(0, len(pieces), size):
            chunk = pieces[start : start + size]
            content = MotionBatch.from_motions([motions[j][a:b] for j, a, b in chunk], None)
            picks = [self.example_index(jobs[j].clip.id) for j, _, _ in chunk]
            style, style_mask = pad_batch([self.examples[i] for i in picks])
            contrast = self.references and self.params.guidance == "style-contrast"
            reference = pad_batch([self.references[i] for i in picks]) if contrast else None
            noise, _ = pad_batch([noises[j][a:b] for j, a, b in chunk])
            out = self.sample(content, style, style_mask, noise, reference).numpy()
            for row, (j, a, b) in enumerate(chunk):
                ramp = blend_ramp(a, b, motions[j].shape[0], self.params.window_overlap)
                sums[j][a:b] += out[row, : b - a] * ramp
                weights[j][a:b] += ramp
        return [s / w for s, w in zip(sums, weights)]

    def _transfer_batch(self, jobs: Sequence[_Job], seed: int) -> list[TransferOutput | Reject]:
        norm = self.model.normalizer
        outputs = self._sample_windows(jobs, seed)
        results: list[TransferOutput | Reject] = []
        for i, job in enumerate(jobs):
            picked = self.example_index(job.clip.id)
            content = norm.normalize(job.motion).astype(np.float32)
            reference = self.references[picked] if self.references else None
            output = shaped(outputs[i], content, self.examples[picked], reference, self.model.info.fps, self.params)
            motion = smoothed(norm.denormalize(output).astype(np.float32), self.params.smooth_frames)
            motion[:, self.kept] = job.motion[:, self.kept]  # exactly the content's, not up to rounding
            if not np.isfinite(motion).all():
                results.append(Reject(id=job.clip.id, source=f"clip {job.clip.id}", reason="non-finite UMSD output"))
                continue
            results.append(
                TransferOutput(source_id=job.clip.id, style=self.style, motion=motion, captions=job.captions)
            )
        return results
