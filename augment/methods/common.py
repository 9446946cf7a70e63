"""What every diffusion style-transfer method needs and none of them owns (on-the-fly, Style-ERD, UMSD).

Method-agnostic helpers, in the base models' normalised feature space where they touch motions: threads and
devices (``configure_threads``, ``place_models``, ``module_device``); randomness (``seeded_generator``;
``clip_noise``, a clip's noise from its id, so its output does not depend on its batch mates); batches
(``MotionBatch``, ``trajectory_channels``); captions (the conditioning caption, the style vocabulary, revised
descriptions); tempo (the longest clip, retiming); artefacts (``weights.safetensors`` + ``artifact.json``, the JSON
written last); scores (text-motion cosines, foot skating).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
import uuid
import zlib
from abc import abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Literal, TypeVar

import numpy as np
import torch
from pydantic import BaseModel
from safetensors.torch import load_file, save_file
from torch import Tensor, nn

from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.diffusion import InpaintSpec
from motionaug.augment.io import atomic_path, atomic_write_text, read_json_model
from motionaug.augment.methods.base import (
    ARTIFACT_JSON,
    ARTIFACT_WEIGHTS,
    Progress,
    StyleTransferMethod,
    TrainingSpec,
    TrainProgress,
)
from motionaug.augment.metrics import foot_skating_ratio
from motionaug.augment.motion.batch import pad_batch
from motionaug.augment.motion.features import feature_slices, features_to_joints
from motionaug.augment.motion.tempo import retime, style_tempo
from motionaug.models.motion_encoder import cosine_similarity
from motionaug.schemas.captions import Caption
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.skeleton import T2M
from motionaug.schemas.styles import StyleWords

if TYPE_CHECKING:
    from motionaug.augment.training.base_models import BaseModels

THREADS_ENV = ("MOTIONAUG_TORCH_THREADS", "OMP_NUM_THREADS")
MAX_TEMPO_CANDIDATES = 4096  # corpus clips whose captions are embedded to find the tempo references

A = TypeVar("A", bound=BaseModel)


# ---- threads and randomness -------------------------------------------------------------------------------


def configure_threads() -> int:
    """Apply the thread count the workflow exported (Ray sets it per worker); returns torch's count."""
    for name in THREADS_ENV:
        value = os.environ.get(name, "")
        if value.isdigit() and int(value) > 0:
            torch.set_num_threads(int(value))
            break
    return torch.get_num_threads()


def module_device(module: nn.Module) -> torch.device:
    """Where ``module``'s weights live (CPU for a module without any): tensors it reads are made there."""
    for tensor in module.parameters():
        return tensor.device
    for tensor in module.buffers():
        return tensor.device
    return torch.device("cpu")


def place_models(base: BaseModels, device: torch.device) -> BaseModels:
    """Move every network of ``base`` to ``device`` (the text encoder stays put: its embeddings are moved)."""
    for module in base.modules().values():
        module.to(device)
    return base


def seeded_generator(seed: int) -> torch.Generator:
    """A CPU generator for any integer seed: the workflow derives 64-bit seeds, torch takes them below 2**63.

    Noise is drawn on CPU and then moved, so a seed gives the same noise on every device.
    """
    return torch.Generator().manual_seed(seed % (1 << 63))


def clip_noise(shape: Sequence[int], clip_ids: Sequence[str], seed: int) -> Tensor:
    """Initial noise drawn per clip from (seed, clip id): a clip's output does not depend on its batch mates."""
    rows = []
    for clip_id in clip_ids:
        generator = seeded_generator(seed * 1_000_003 + zlib.crc32(clip_id.encode("utf-8")))
        rows.append(torch.randn(tuple(shape[1:]), generator=generator))
    return torch.stack(rows)


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

    def to(self, device: torch.device) -> MotionBatch:
        """The same batch on ``device`` (itself when already there)."""
        return MotionBatch(self.x.to(device), self.mask.to(device), self.lengths)

    def inpaint(self, channels: Sequence[int], reference: Tensor | None = None) -> InpaintSpec:
        """Keep ``channels`` of ``reference`` (default: these motions) on the real frames."""
        return InpaintSpec(self.x if reference is None else reference, list(channels), frames=self.mask)


def trajectory_channels(mode: str = "horizontal") -> list[int]:
    """Feature channels that carry the root trajectory: rotation velocity + xz velocity (+ height for ``root``);
    ``heading``: rotation velocity + height (the path's turns, not its pace)."""
    slices = feature_slices(T2M)
    if mode == "heading":
        return [c for block in ("root_rot_vel", "root_y") for c in range(slices[block].start, slices[block].stop)]
    blocks = ["root_rot_vel", "root_lin_vel"] + (["root_y"] if mode == "root" else [])
    return [c for block in blocks for c in range(slices[block].start, slices[block].stop)]


def feet_channels() -> list[int]:
    """The foot-contact channels (inpainted too when a method keeps the content's gait phase)."""
    feet = feature_slices(T2M)["feet"]
    return list(range(feet.start, feet.stop))


# ---- caption handling (augment.text.caption_revision) ----------------------------------------------------------


def caption_text(clip: MotionClip) -> str:
    """The caption a clip is conditioned on: its first whole-clip caption, else its first; never its labels."""
    for caption in clip.captions:
        if caption.whole_clip:
            return caption.text
    if clip.captions:
        return clip.captions[0].text
    return "a person moves"


def style_vocab(words: StyleWords, name: str) -> dict[str, Any]:
    """The built-in styles' words plus this style's own, so a user-defined style is neutralised too."""
    from motionaug.augment.synth.styles import STYLE_WORDS

    return {**STYLE_WORDS, name: words}


def neutral_text(text: str, vocab: dict[str, Any]) -> str:
    """The description with every known style word removed (the prior's condition for the neutral twin)."""
    from motionaug.augment.text.caption_revision import neutral_description

    return neutral_description(text, vocab)


def carries_style(text: str, vocab: dict[str, Any]) -> bool:
    from motionaug.augment.text.caption_revision import has_style_words

    return bool(has_style_words(text, vocab))


def revised_texts(
    clip: MotionClip, words: StyleWords, n_variants: int, seed: int, vocab: dict[str, Any]
) -> list[Caption]:
    """Several phrasings of the clip's captions in the target style (their old style words removed first)."""
    from motionaug.augment.text.caption_revision import revised_captions

    captions = clip.captions or [Caption(text=caption_text(clip))]
    try:
        revised = revised_captions(list(captions), words, n_variants, seed, vocab=vocab)
    except MotionDataError as err:
        raise MotionDataError(f"clip {clip.id}", f"caption revision failed: {err}") from None
    if not revised:
        raise MotionDataError(f"clip {clip.id}", "no revised caption")
    return revised


# ---- tempo (augment.motion.tempo) ---------------------------------------------------------------------------------


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
    base: BaseModels,
    corpus: Sequence[MotionClip],
    descriptions: Sequence[str],
    vocab: dict[str, Any],
    k: int,
    seed: int,
) -> list[MotionClip]:
    """The ``k`` neutral corpus clips whose captions are nearest (text embedding) to the examples' neutral
    descriptions."""
    candidates = [c for c in corpus if not carries_style(caption_text(c), vocab) and np.isfinite(c.motion).all()]
    if len(candidates) > MAX_TEMPO_CANDIDATES:
        order = torch.randperm(len(candidates), generator=seeded_generator(seed)).tolist()
        candidates = [candidates[i] for i in order[:MAX_TEMPO_CANDIDATES]]
    if not candidates:
        return []
    query = base.text_encoder.encode(list(descriptions)).mean(dim=0, keepdim=True)
    keys = base.text_encoder.encode([caption_text(c) for c in candidates])
    similarity = torch.nn.functional.cosine_similarity(keys, query, dim=-1)
    return [candidates[i] for i in similarity.argsort(descending=True)[:k].tolist()]


def tempo_setting(
    tempo: Literal["example", "content"] | float,
    references: int,
    seed: int,
    base: BaseModels,
    examples: Sequence[MotionClip],
    corpus: Sequence[MotionClip],
    vocab: dict[str, Any],
) -> tuple[float, str]:
    """(tempo, how it was set) for a method's ``tempo`` param: ``"content"`` keeps the clock, a number sets it,
    ``"example"`` measures it from the examples against ``references`` neutral corpus clips described alike
    (``augment.motion.tempo.style_tempo``); 1.0 when it cannot be measured."""
    if tempo == "content":
        return 1.0, "content clock kept (tempo='content')"
    if not isinstance(tempo, str):
        return float(tempo), "set in the params"
    descriptions = [neutral_text(caption_text(e), vocab) for e in examples]
    found = tempo_references(base, corpus, descriptions, vocab, references, seed)
    measured, why = style_tempo([(e.motion, e.fps) for e in examples], [(c.motion, c.fps) for c in found])
    if measured is None:
        return 1.0, f"content clock kept: {why}"
    return measured, f"tempo {measured:.3f} from {why}"


# ---- artefacts ----------------------------------------------------------------------------------------------


def tensor_bytes(state: dict[str, Tensor]) -> int:
    return sum(t.numel() * t.element_size() for t in state.values())


def files_fingerprint(folder: Path, names: Sequence[str], what: str = "file") -> str:
    """sha256 (16 hex digits) of the named files of ``folder``, in order: ties an artefact to what it was made
    from."""
    digest = hashlib.sha256()
    for name in names:
        path = Path(folder) / name
        if not path.is_file():
            raise MotionDataError(str(path), f"{what} missing")
        with path.open("rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                digest.update(block)
    return digest.hexdigest()[:16]


def write_artifact(out_dir: Path, info: BaseModel, weights: dict[str, Tensor]) -> Path:
    """Write ``weights.safetensors`` then ``artifact.json`` (last: it marks a complete artefact), each atomically."""
    out_dir.mkdir(parents=True, exist_ok=True)
    with atomic_path(out_dir / ARTIFACT_WEIGHTS) as tmp:
        save_file(weights, str(tmp))
    atomic_write_text(out_dir / ARTIFACT_JSON, info.model_dump_json(indent=2))
    return out_dir


def read_artifact_json(artifact_dir: Path, model: type[A], method: str, what: str) -> A:
    """``artifact.json`` as ``model`` (whose ``method`` field must be ``method``), or a one-line error."""
    path = Path(artifact_dir) / ARTIFACT_JSON
    info = read_json_model(path, model, what)
    found = getattr(info, "method", None)
    if found != method:
        raise MotionDataError(str(path), f"artefact of method {found!r}, not {method!r}")
    return info


def read_tensors(path: Path) -> dict[str, Tensor]:
    """A safetensors file's tensors, or a one-line error naming it."""
    try:
        return load_file(str(path))
    except Exception as err:  # safetensors has its own error types
        raise MotionDataError(str(path), f"unreadable safetensors ({err})") from None


# ---- outputs ------------------------------------------------------------------------------------------------


def output_scores(
    base: BaseModels, out: Tensor, mask: Tensor, style_embed: Tensor, clips: Sequence[MotionClip]
) -> list[dict[str, float]]:
    """Per clip of a transferred batch ``out`` (B, T, D, normalised): cosine to its revised caption's embedding
    (style), to its original caption (content), and its foot skating. Encodes on ``out``'s device, the rest on CPU."""
    originals = [caption_text(c) for c in clips]
    with torch.no_grad():
        feats = base.motion_encoder(out, mask)
        style = cosine_similarity(feats, style_embed.to(feats.device)).tolist()
        content = cosine_similarity(feats, base.text_encoder.encode(originals).to(feats.device)).tolist()
    joints = features_to_joints(out.cpu(), T2M, base.normalizer.mean, base.normalizer.std)
    lengths = mask.sum(dim=1).tolist()
    skate = [foot_skating_ratio(joints[i, :n].numpy(), T2M, c.fps) for i, (c, n) in enumerate(zip(clips, lengths))]
    return [{"style_score": s, "content_score": c, "foot_skating": f} for s, c, f in zip(style, content, skate)]


def output_motion(base: BaseModels, out: Tensor, reference: np.ndarray, channels: Sequence[int]) -> np.ndarray:
    """One transferred clip (T, D, normalised) as float32 features, ``channels`` copied from ``reference`` exactly
    (not just up to normalise/denormalise rounding)."""
    motion = base.normalizer.denormalize(out.cpu().numpy()).astype(np.float32)
    motion[:, channels] = reference[:, channels]
    return motion


# ---- networks trained once on a labelled style corpus (Style-ERD, UMSD) ---------------------------------------

TRAINED_JSON = "trained.json"


def labelled_training_clips(corpus: Path, neutral_style: str, neutral: str = "neutral") -> list[MotionClip]:
    """The labelled corpus's train split (all of it without split files), its neutral style named ``neutral``."""
    from motionaug.augment.corpus import Corpus

    reader = Corpus(corpus, split="train") if (Path(corpus) / "train.txt").is_file() else Corpus(corpus)
    clips = list(reader)
    for clip in clips:
        if clip.style == neutral_style:
            clip.style = neutral
    return clips


def training_record(corpus: Path, config: BaseModel, neutral_style: str) -> dict[str, Any]:
    """What a trained folder was made from: it is reused only while all of it is the same."""
    from motionaug.augment.corpus.fingerprint import corpus_fingerprint

    return {
        "corpus_fingerprint": corpus_fingerprint(corpus),
        "train": config.model_dump(mode="json"),
        "neutral_style": neutral_style,
    }


def trained_with(folder: Path, record: dict[str, Any]) -> bool:
    marker = Path(folder) / TRAINED_JSON
    try:
        return json.loads(marker.read_text(encoding="utf-8")) == record
    except (OSError, ValueError):
        return False


def mark_trained(folder: Path, record: dict[str, Any]) -> None:
    """Written last: its presence marks a complete trained folder."""
    atomic_write_text(Path(folder) / TRAINED_JSON, json.dumps(record, indent=1, sort_keys=True) + "\n")


def write_model_folder(out: Path, tensors: dict[str, dict[str, Tensor]], texts: dict[str, str]) -> Path:
    """Safetensors files and text files written into a temporary sibling, renamed into place when complete.

    An older folder at ``out`` is replaced only then, so a crash leaves either the old model or the new one.
    """
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.{os.getpid()}.{uuid.uuid4().hex[:12]}.tmp")
    tmp.mkdir()
    try:
        for name, state in tensors.items():
            save_file({k: v.contiguous() for k, v in state.items()}, str(tmp / name))
        for name, text in texts.items():
            (tmp / name).write_text(text, encoding="utf-8")
        old = None
        if out.exists():
            old = out.with_name(f".{out.name}.{uuid.uuid4().hex[:12]}.old")
            os.replace(out, old)
        os.replace(tmp, out)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return out


class CorpusTrainedMethod(StyleTransferMethod):
    """A method whose network is trained once per run on a labelled style corpus (Style-ERD, UMSD).

    ``train`` fits ``fit_network`` on the corpus's train split (its neutral style renamed ``neutral``) and reuses a
    folder made from the same corpus and training config. Params must have ``train`` and ``neutral_style``.
    """

    trains: ClassVar[bool] = True

    def training_config(self, spec: TrainingSpec) -> BaseModel:
        """The full training config ``fit_network`` reads and the trained folder records (default ``params.train``)."""
        params: Any = self.params
        return params.train

    def check_training(self, spec: TrainingSpec) -> None:
        self.training_config(spec)

    @abstractmethod
    def fit_network(self, clips: list[MotionClip], out: Path, config: Any, progress: Progress | None) -> Path:
        """Train the network on labelled clips into the folder ``out`` with ``config`` (``training_config``)."""

    def is_trained(self, folder: Path) -> bool:
        return (Path(folder) / TRAINED_JSON).is_file()

    def train(self, corpus: Path, out: Path, spec: TrainingSpec, progress: TrainProgress | None = None) -> Path:
        """Fit on the labelled corpus's train split; a folder made from the same corpus and config is reused."""
        params: Any = self.params
        config = self.training_config(spec)
        record = training_record(corpus, config, params.neutral_style)
        if trained_with(out, record):
            return Path(out)
        clips = labelled_training_clips(corpus, params.neutral_style)
        report = None if progress is None else (lambda step, total, metrics: progress(self.name, step, total, metrics))
        self.fit_network(clips, Path(out), config, report)
        mark_trained(out, record)
        return Path(out)


def run_steps(
    step: Callable[[], dict[str, float]],
    steps: int,
    log_every: int,
    what: str,
    progress: Progress | None = None,
    done: int = 0,
    total: int | None = None,
) -> list[dict[str, float]]:
    """``steps`` training steps; returns the loss history averaged over each ``log_every`` window.

    A non-finite loss stops training with one line naming ``what`` and the step. ``progress`` sees
    ``done + step`` of ``total`` (default ``steps``): a training with an earlier phase counts on from it.
    """
    history: list[dict[str, float]] = []
    window: dict[str, float] = {}
    for n in range(steps):
        metrics = step()
        if not all(math.isfinite(v) for v in metrics.values()):
            raise MotionDataError(f"{what} training", f"non-finite loss at step {n + 1}: {metrics}")
        for k, v in metrics.items():
            window[k] = window.get(k, 0.0) + v
        if (n + 1) % log_every == 0 or n + 1 == steps:
            count = (n % log_every) + 1
            history.append({"step": float(n + 1)} | {k: v / count for k, v in window.items()})
            window = {}
        if progress is not None:
            progress(done + n + 1, total or steps, metrics)
    return history
