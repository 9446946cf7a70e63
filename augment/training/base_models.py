"""The pre-trained models every style-transfer method stands on, as one folder of files.

A base-models folder (written by ``augment.training.pretrain``; ``BaseModels`` documents its files) holds the T2M
diffusion prior, the motion encoder, the content and style classifiers that act as evaluators, the feature
normalisation they were trained with and, for an imported MDM prior, its CLIP text tower. Weights are safetensors
only, so loading never unpickles.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field
from safetensors.torch import load_file, save_file
from torch import nn

from motionaug.augment.io import atomic_path, atomic_write_text, read_json_model
from motionaug.augment.motion.features import Normalizer
from motionaug.models.clip_text import VOCAB_FILE
from motionaug.models.evaluators import ClassifierConfig, MotionClassifier
from motionaug.models.mdm import MDM, MDMConfig
from motionaug.models.motion_encoder import MotionEncoder, MotionEncoderConfig
from motionaug.models.text_encoder import ClipTextEncoder, TextEncoder, make_text_encoder
from motionaug.schemas.errors import MotionDataError

BASE_JSON = "base.json"
PRIOR = "prior"
MOTION_ENCODER = "motion_encoder"
CONTENT_CLASSIFIER = "content_classifier"
STYLE_CLASSIFIER = "style_classifier"
TEXT_ENCODER = "text_encoder"


class BaseModelsInfo(BaseModel):
    """Everything needed to rebuild the networks before loading their weights."""

    model_config = ConfigDict(extra="forbid")

    version: int = 1
    size: str
    text_encoder: str = "minilm"
    text_encoder_options: dict[str, Any] = Field(
        default_factory=dict, description="ClipTextEncoder options, e.g. MDM's raw features and 20-token captions."
    )
    fps: float = 20.0
    max_frames: int = Field(gt=0, description="Longest clip the prior was trained on.")
    prior: dict[str, Any]
    motion_encoder: dict[str, Any]
    content_classifier: dict[str, Any] | None = None
    style_classifier: dict[str, Any] | None = None
    content_labels: list[str] = Field(default_factory=list)
    style_labels: list[str] = Field(default_factory=list)
    corpus_fingerprint: str = ""
    config_hash: str = Field(default="", description="Hash of the PretrainConfig that made these weights.")
    pretrain_config: dict[str, Any] = Field(default_factory=dict, description="The PretrainConfig, for the record.")
    metrics: dict[str, float] = Field(default_factory=dict, description="Held-out figures measured at pretraining.")
    source: dict[str, Any] = Field(default_factory=dict, description="Where the prior came from, when imported.")
    notes: list[str] = Field(default_factory=list, description="What a user should know about these models.")


@dataclass
class BaseModels:
    """Loaded base models. ``text_encoder`` is built on first use (not every caller needs it).

    The folder's files::

        base.json                      BaseModelsInfo: configs, label lists, corpus fingerprint
        prior.safetensors              MDM denoiser (the T2M diffusion prior)
        motion_encoder.safetensors     motion -> text-embedding space (its own copy of the prior's input layer)
        content_classifier.safetensors evaluator: what is done
        style_classifier.safetensors   evaluator: how it is done
        Mean.npy, Std.npy              the feature normalisation the models were trained with
        text_encoder.safetensors       CLIP text tower, when ``text_encoder`` is "clip" (an imported MDM prior)
        bpe_simple_vocab_16e6.txt.gz   its tokenizer vocabulary
    """

    info: BaseModelsInfo
    prior: MDM
    motion_encoder: MotionEncoder
    normalizer: Normalizer
    content_classifier: MotionClassifier | None = None
    style_classifier: MotionClassifier | None = None
    _text_encoder: TextEncoder | None = None
    folder: Path | None = None

    @property
    def text_encoder(self) -> TextEncoder:
        if self._text_encoder is None:
            self._text_encoder = self._build_text_encoder()
        return self._text_encoder

    def _build_text_encoder(self) -> TextEncoder:
        """MiniLM from its package; CLIP from the folder's own copy (the folder is self-contained on any node)."""
        if self.info.text_encoder != "clip":
            return make_text_encoder(self.info.text_encoder)
        if self.folder is None:
            raise MotionDataError("base models", "a CLIP text encoder is read from the base-models folder; none given")
        return ClipTextEncoder(
            self.folder / f"{TEXT_ENCODER}.safetensors", self.folder / VOCAB_FILE, **self.info.text_encoder_options
        )

    def eval(self) -> BaseModels:
        for module in self.modules().values():
            module.eval().requires_grad_(False)
        return self

    def modules(self) -> dict[str, nn.Module]:
        named = {PRIOR: self.prior, MOTION_ENCODER: self.motion_encoder}
        if self.content_classifier is not None:
            named[CONTENT_CLASSIFIER] = self.content_classifier
        if self.style_classifier is not None:
            named[STYLE_CLASSIFIER] = self.style_classifier
        return named

    def save(self, directory: str | Path) -> Path:
        """Write every module and the info atomically (base.json last: it marks a complete folder)."""
        folder = Path(directory)
        for name, module in self.modules().items():
            save_module(module, folder / f"{name}.safetensors")
        self.normalizer.save(folder)
        atomic_write_text(folder / BASE_JSON, self.info.model_dump_json(indent=2))
        return folder

    @classmethod
    def load(cls, directory: str | Path, text_encoder: TextEncoder | None = None) -> BaseModels:
        folder = Path(directory)
        info = read_base_info(folder)
        prior = MDM(MDMConfig(**info.prior))
        encoder = MotionEncoder(MotionEncoderConfig(**info.motion_encoder))
        load_module(prior, folder / f"{PRIOR}.safetensors")
        load_module(encoder, folder / f"{MOTION_ENCODER}.safetensors")
        classifiers = {}
        for name in (CONTENT_CLASSIFIER, STYLE_CLASSIFIER):
            config = getattr(info, name)
            if config is not None:
                classifiers[name] = MotionClassifier(ClassifierConfig(**config))
                load_module(classifiers[name], folder / f"{name}.safetensors")
        return cls(
            info=info,
            prior=prior,
            motion_encoder=encoder,
            normalizer=Normalizer.load(folder),
            content_classifier=classifiers.get(CONTENT_CLASSIFIER),
            style_classifier=classifiers.get(STYLE_CLASSIFIER),
            _text_encoder=text_encoder,
            folder=folder,
        ).eval()


def read_base_info(folder: str | Path) -> BaseModelsInfo:
    """The ``base.json`` of a base-models folder (written last, so its presence marks a complete folder)."""
    return read_json_model(Path(folder) / BASE_JSON, BaseModelsInfo, "a base-models folder (run `motionaug pretrain`)")


def config_dict(config: Any) -> dict[str, Any]:
    """A dataclass config as a JSON-able dict (for ``BaseModelsInfo``)."""
    return dataclasses.asdict(config)


def save_module(module: nn.Module, path: Path) -> None:
    """A module's state dict as safetensors, atomically. Shared tensors are cloned so each is stored once."""
    state = {k: v.detach().contiguous().clone() for k, v in module.state_dict().items()}
    with atomic_path(path) as tmp:
        save_file(state, str(tmp))


def load_module(module: nn.Module, path: Path) -> None:
    if not path.is_file():
        raise MotionDataError(str(path), "weights file is missing")
    try:
        state = load_file(str(path))
    except Exception as err:  # safetensors raises its own error types for corrupt files
        raise MotionDataError(str(path), f"unreadable safetensors ({err})") from None
    missing, unexpected = module.load_state_dict(state, strict=False)
    if missing or unexpected:
        raise MotionDataError(
            str(path), f"weights do not fit the network: missing {missing[:3]}, unexpected {unexpected[:3]}"
        )
