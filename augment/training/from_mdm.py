"""Base models around the official MDM prior (GuyTevet/motion-diffusion-model, HumanML3D ``trans_enc``).

The released prior replaces pre-training stage a, the costliest (Hu et al. 2024, Table 1). Still trained here: the
motion encoder into CLIP ViT-B/32's text space, which MDM conditions on (stage b), and the evaluators the corpus has
labels for (stage c). HumanML3D has no content or style labels, so then no classifier is trained: outputs are judged
by the motion encoder's cosine to their original and styled captions, and CRA, SRA and FMD need evaluators from a
labelled corpus (``motionaug pretrain --evaluators-only``); ``notes`` in base.json says which case applies. The prior
only understands motions normalised with HumanML3D's Mean/Std (the checkpoint holds none), so every model here
normalises with those, and base.json records where they came from and whether the corpus's own differ.
"""

from __future__ import annotations

import hashlib
import logging
import os
import shutil
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from safetensors.torch import load_file, save_file
from torch import Tensor

from motionaug.augment.corpus.fingerprint import corpus_fingerprint
from motionaug.augment.device import pick_device
from motionaug.augment.diffusion import NoiseSchedule
from motionaug.augment.io import atomic_path
from motionaug.augment.motion.features import Normalizer
from motionaug.augment.training.base_models import BASE_JSON, TEXT_ENCODER, BaseModels, BaseModelsInfo, config_dict
from motionaug.augment.training.data import build_motion_set, read_clips, split_ids
from motionaug.augment.training.evaluators import EVALUATORS_DIR, save_evaluators
from motionaug.augment.training.pretrain import (
    CHECKPOINTS,
    LOSS_LOG,
    PretrainConfig,
    ProgressFn,
    Run,
    _complete,
    _stale_checkpoints,
    _threads,
    held_out_prior_mse,
    run_hash,
    skeleton_for,
    train_evaluators,
    train_motion_encoder,
)
from motionaug.models.clip_text import VOCAB_FILE, read_clip_weights, text_state
from motionaug.models.mdm import MDM, MDMConfig
from motionaug.models.mdm_checkpoint import load_official_mdm_state_dict
from motionaug.models.text_encoder import ClipTextEncoder, find_clip_vocab
from motionaug.schemas.errors import MotionDataError

LOG = logging.getLogger(__name__)

MDM_HEADS = 4  # MDM's --num_heads default for trans_enc (model/mdm.py): not readable from the tensors
MDM_MAX_TOKENS = 20  # MDM's encode_text truncates HumanML3D captions to 20 BPE tokens (max_text_len)
MDM_CLIP_OPTIONS = {"normalize": False, "max_tokens": MDM_MAX_TOKENS}  # MDM conditions on raw CLIP features
STATS_TOLERANCE = 1e-3  # in units of the prior's std: below this two statistics are the same
REQUIRED_KEYS = ("input_process.poseEmbedding.weight", "embed_text.weight", "output_process.poseFinal.weight")
OTHER_ARCHS = {"seqTransDecoder.": "trans_dec", "gru.": "gru"}


@dataclass(frozen=True)
class MdmSource:
    """An official checkpoint, the CLIP weights (None: found, see ``clip_text_weights``), and the folder holding
    the Mean.npy/Std.npy the prior was trained with (None: beside the checkpoint, else the corpus's own)."""

    checkpoint: Path
    clip_weights: Path | None = None
    stats: Path | None = None


def source_of(config: PretrainConfig) -> MdmSource:
    """The MDM source a pre-training config names (``from_mdm``, ``clip_weights``, ``mdm_stats``)."""
    if config.from_mdm is None:
        raise MotionDataError("from_mdm", "no MDM checkpoint given")
    optional = lambda value: None if value is None else Path(value)  # noqa: E731
    return MdmSource(Path(config.from_mdm), optional(config.clip_weights), optional(config.mdm_stats))


def default_clip_cache() -> Path:
    """Where the ``clip`` package keeps ``clip.load('ViT-B/32')``'s download (MDM users have it there)."""
    cache = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(cache) / "clip" / "ViT-B-32.pt"


def read_mdm_checkpoint(path: str | Path) -> dict[str, Tensor]:
    """The tensors of an official checkpoint (``model000475000.pt``): a ``weights_only`` load, never unpickling code."""
    path = Path(path)
    if not path.is_file():
        raise MotionDataError(str(path), "MDM checkpoint not found")
    try:
        loaded = load_file(str(path)) if path.suffix == ".safetensors" else torch.load(path, "cpu", weights_only=True)
    except Exception as err:  # torch and safetensors raise several types for an unreadable file
        raise MotionDataError(str(path), f"not a readable MDM checkpoint ({type(err).__name__})") from None
    for wrapper in ("model_avg", "model", "state_dict"):
        if isinstance(loaded, Mapping) and isinstance(loaded.get(wrapper), Mapping):
            loaded = loaded[wrapper]
    if not isinstance(loaded, Mapping):
        raise MotionDataError(str(path), f"not an MDM state dict (holds {type(loaded).__name__})")
    return {k.removeprefix("module."): v for k, v in loaded.items() if isinstance(v, Tensor)}


def _expect(state: Mapping[str, Tensor], key: str, shape: tuple[int, ...], why: str) -> None:
    if tuple(state[key].shape) != shape:
        raise MotionDataError(key, f"shape {tuple(state[key].shape)}, expected {shape} for {why}")


def infer_mdm_config(state: Mapping[str, Tensor], n_feats: int | None = None) -> MDMConfig:
    """MDM's architecture from its tensors: features, latent width, text width, layers and feed-forward width."""
    for prefix, arch in OTHER_ARCHS.items():
        if any(k.startswith(prefix) for k in state):
            raise MotionDataError(f"{prefix}*", f"an MDM '{arch}' checkpoint; only 'trans_enc' is supported")
    for key in REQUIRED_KEYS:
        if key not in state:
            raise MotionDataError(key, "missing: not an MDM trans_enc checkpoint")
    d, feats = state["input_process.poseEmbedding.weight"].shape
    text_dim = state["embed_text.weight"].shape[1]
    if n_feats is not None and feats != n_feats:
        raise MotionDataError(
            "input_process.poseEmbedding.weight", f"reads {feats}-wide features, corpus has {n_feats}"
        )
    layers = sorted({int(k.split(".")[2]) for k in state if k.startswith("seqTransEncoder.layers.")})
    if not layers or layers != list(range(len(layers))):
        raise MotionDataError("seqTransEncoder.layers.*", f"layers {layers[:5]}..., expected 0..N-1")
    ff = state["seqTransEncoder.layers.0.linear1.weight"].shape[0]
    arch = f"a trans_enc with latent_dim {d}, ff_size {ff}"
    _expect(state, "embed_text.weight", (d, text_dim), arch)
    _expect(state, "output_process.poseFinal.weight", (feats, d), arch)
    for i in layers:
        _expect(state, f"seqTransEncoder.layers.{i}.self_attn.in_proj_weight", (3 * d, d), arch)
        _expect(state, f"seqTransEncoder.layers.{i}.linear1.weight", (ff, d), arch)
        _expect(state, f"seqTransEncoder.layers.{i}.linear2.weight", (d, ff), arch)
    if d % MDM_HEADS:
        raise MotionDataError("input_process.poseEmbedding.weight", f"latent_dim {d} is not a multiple of 4 heads")
    return MDMConfig(
        n_feats=feats, latent_dim=d, ff_size=ff, num_layers=len(layers), num_heads=MDM_HEADS, text_dim=text_dim
    )


def load_mdm_prior(state: Mapping[str, Tensor], n_feats: int | None = None) -> MDM:
    """An ``MDM`` sized from the checkpoint and holding its weights (sinusoidal tables checked, CLIP keys skipped)."""
    prior = MDM(infer_mdm_config(state, n_feats))
    load_official_mdm_state_dict(prior, state)
    return prior.eval()


def clip_text_weights(source: MdmSource, state: Mapping[str, Tensor]) -> tuple[dict[str, Tensor], Path]:
    """The CLIP text tower's tensors and the file they came from: ``--clip-weights``, else the checkpoint's own
    ``clip_model.*`` keys, else the ``clip`` package's cache. Never a download."""
    if source.clip_weights is not None:
        path = Path(source.clip_weights)
        try:
            return text_state(read_clip_weights(path)), path
        except (FileNotFoundError, ValueError) as err:
            raise MotionDataError(str(path), str(err).removeprefix(f"{path}: ")) from None
    if any(k.startswith("clip_model.") for k in state):
        return text_state(state), Path(source.checkpoint)
    cached = default_clip_cache()
    if cached.is_file():
        return text_state(read_clip_weights(cached)), cached
    raise MotionDataError(
        "CLIP ViT-B/32 text encoder",
        f"the MDM checkpoint has no clip_model.* keys and {cached} is absent; pass --clip-weights FILE "
        "(OpenAI's ViT-B-32.pt or an open_clip ViT-B-32 checkpoint); nothing is downloaded",
    )


def install_clip(
    source: MdmSource, state: Mapping[str, Tensor], out: Path, text_dim: int, device: str = "cpu"
) -> ClipTextEncoder:
    """Copy the CLIP text tower and its vocabulary into ``out`` (so the folder works on any node) and load it
    on ``device`` (the corpus's captions are encoded once, here)."""
    weights, origin = clip_text_weights(source, state)
    try:
        vocab = find_clip_vocab(None, origin)
    except FileNotFoundError as err:
        raise MotionDataError(VOCAB_FILE, str(err).removeprefix(f"{VOCAB_FILE}: ")) from None
    with atomic_path(out / f"{TEXT_ENCODER}.safetensors") as tmp:
        save_file({k: v.contiguous() for k, v in weights.items()}, str(tmp))
    if vocab.resolve() != (out / VOCAB_FILE).resolve():
        with atomic_path(out / VOCAB_FILE) as tmp:
            shutil.copyfile(vocab, tmp)
    try:
        encoder = ClipTextEncoder(
            out / f"{TEXT_ENCODER}.safetensors", out / VOCAB_FILE, device=device, **MDM_CLIP_OPTIONS
        )
    except ValueError as err:
        raise MotionDataError(str(origin), str(err)) from None
    if encoder.dim != text_dim:
        raise MotionDataError("embed_text.weight", f"expects {text_dim}-wide text features, CLIP gives {encoder.dim}")
    return encoder


def stats_folder(source: MdmSource, corpus: Path) -> Path:
    """``--mdm-stats``, else the checkpoint's folder when it holds Mean.npy, else the corpus."""
    beside = Path(source.checkpoint).parent
    return Path(source.stats or (beside if (beside / "Mean.npy").is_file() else corpus))


def prior_normalizer(source: MdmSource, corpus: Path) -> tuple[Normalizer, Path, list[str]]:
    """The prior's Mean/Std, the folder they came from, and a note when the corpus's own differ."""
    folder = stats_folder(source, corpus)
    if not (Path(folder) / "Mean.npy").is_file():
        raise MotionDataError(
            str(Path(folder) / "Mean.npy"),
            "missing; the official MDM prior needs HumanML3D's Mean.npy/Std.npy (its checkpoint holds none): "
            "put them in the corpus folder or pass --mdm-stats DIR",
        )
    prior = Normalizer.load(folder)
    notes = [f"normalisation: the MDM prior's Mean/Std from {folder}"]
    if Path(folder).resolve() != corpus.resolve() and (corpus / "Mean.npy").is_file():
        own = Normalizer.load(corpus)
        if own.dim != prior.dim:
            raise MotionDataError(str(corpus / "Mean.npy"), f"{own.dim} wide, the prior's Mean/Std {prior.dim}")
        gap = max(
            float(np.abs(own.mean - prior.mean).max() / prior.std.min()), float(np.abs(own.std / prior.std - 1).max())
        )
        if gap > STATS_TOLERANCE:
            notes.append(f"the corpus's own Mean/Std differ from the prior's (by up to {gap:.3g}); unused")
            LOG.warning("%s: Mean/Std differ from the MDM prior's; every model normalises with the prior's", corpus)
    return prior, Path(folder), notes


def _digest(paths: list[Path]) -> str:
    digest = hashlib.sha256()
    for path in paths:
        with open(path, "rb") as handle:
            while chunk := handle.read(1 << 22):
                digest.update(chunk)
    return digest.hexdigest()[:32]


def _label_notes(run: Run) -> list[str]:
    """How outputs are judged when the corpus lacks labels (HumanML3D has none)."""
    notes = []
    if len(run.train.content_labels) < 2:
        notes.append(
            "content: no content labels, so no content classifier (CRA not measured); each output's content_score "
            "(motion-encoder cosine to its original caption in CLIP space) judges content"
        )
    if len(run.train.style_labels) < 2:
        notes.append(
            "style: no style labels (HumanML3D has none), so no style classifier (SRA and FMD omitted); each "
            "output's style_score (cosine to its styled caption) judges style; for SRA train evaluators on a "
            "labelled corpus (`motionaug pretrain --evaluators-only`) for `motionaug evaluate --base-models`"
        )
    return notes


def pretrain_from_mdm(
    corpus_dir: str | Path,
    out_dir: str | Path,
    source: MdmSource,
    config: PretrainConfig | None = None,
    progress: ProgressFn | None = None,
) -> BaseModelsInfo:
    """Import the prior, train the motion encoder (CLIP space) and the labelled evaluators; save base models.

    Everything runs on ``pick_device()`` (chosen once here); the saved weights come back to CPU.
    """
    config = config or PretrainConfig.for_size("paper")
    corpus, out = Path(corpus_dir), Path(out_dir)
    _threads(config)
    device = pick_device()
    state = read_mdm_checkpoint(source.checkpoint)
    normalizer, stats_dir, notes = prior_normalizer(source, corpus)
    prior = load_mdm_prior(state, normalizer.dim).to(device)
    out.mkdir(parents=True, exist_ok=True)
    (out / BASE_JSON).unlink(missing_ok=True)  # base.json marks a complete folder; this one is not, until the end
    text = install_clip(source, state, out, prior.config.text_dim, str(device))
    fingerprint = mdm_fingerprint(corpus, source)
    train_clips = read_clips(corpus, split_ids(corpus, "train"))
    train = build_motion_set(train_clips, normalizer, text)
    test_clips = read_clips(corpus, split_ids(corpus, "test"))
    test = build_motion_set(test_clips, normalizer, text, train.content_labels, train.style_labels)
    run = Run(
        config=config,
        out_dir=out,
        normalizer=normalizer,
        skeleton=skeleton_for(normalizer.dim),
        train=train,
        test=test,
        run_hash=run_hash(config, fingerprint),
        progress=progress,
        device=device,
    )
    run.metrics["prior_test_mse"] = held_out_prior_mse(prior, NoiseSchedule.cosine(), run)
    motion_encoder = train_motion_encoder(run, prior)
    classifiers = train_evaluators(run)
    labels = {"content": run.train.content_labels, "style": run.train.style_labels}
    save_evaluators(out / EVALUATORS_DIR, classifiers, labels, fingerprint, run.metrics)
    info = BaseModelsInfo(
        size=config.size,
        text_encoder="clip",
        text_encoder_options=MDM_CLIP_OPTIONS,
        max_frames=config.max_frames,
        prior=config_dict(prior.config),
        motion_encoder=config_dict(motion_encoder.config),
        corpus_fingerprint=fingerprint,
        config_hash=config.config_hash(),
        pretrain_config=config.model_dump(),
        metrics=dict(sorted(run.metrics.items())),
        source={"from_mdm": str(source.checkpoint), "stats": str(stats_dir)},
        notes=notes + _label_notes(run),
    )
    BaseModels(info=info, prior=prior.cpu(), motion_encoder=motion_encoder.cpu(), normalizer=normalizer).save(out)
    return info


def mdm_fingerprint(corpus: Path, source: MdmSource) -> str:
    """The corpus's fingerprint joined with the checkpoint's and CLIP weights' contents: what the folder depends on."""
    stats = [stats_folder(source, corpus) / name for name in ("Mean.npy", "Std.npy")]
    files = [Path(source.checkpoint), *(p for p in stats if p.is_file())]
    files += [Path(source.clip_weights)] if source.clip_weights else []
    joined = f"{corpus_fingerprint(corpus)}:{_digest(files)}"
    return hashlib.sha256(joined.encode()).hexdigest()[:32]


def ensure_from_mdm(
    corpus_dir: str | Path,
    out_dir: str | Path,
    source: MdmSource,
    config: PretrainConfig | None = None,
    progress: ProgressFn | None = None,
) -> Path:
    """``out_dir`` if it holds base models made from this checkpoint, corpus and config; else build them there."""
    config = config or PretrainConfig.for_size("paper")
    out = Path(out_dir)
    fingerprint = mdm_fingerprint(Path(corpus_dir), source)
    if _complete(out, fingerprint, config.config_hash()):
        return out
    if (out / BASE_JSON).is_file():  # never replace models silently: say why they are made again
        LOG.warning("%s: base models there were made from other files or another config; importing again", out)
    if _stale_checkpoints(out, run_hash(config, fingerprint)):
        shutil.rmtree(out / CHECKPOINTS, ignore_errors=True)
        (out / LOSS_LOG).unlink(missing_ok=True)
    pretrain_from_mdm(corpus_dir, out, source, config, progress)
    return out
