"""CLIP ViT-B/32's text tower and BPE tokenizer in plain PyTorch, loaded from a local file, never downloaded.

Written out (as ``models.minilm`` is for MiniLM) so the official MDM prior's text condition needs neither the
``clip`` nor the ``open_clip`` package (both import torchvision, which has no build for a CPU-only torch here).
Parameter names are OpenAI's (``clip/model.py``), which open_clip keeps for its text tower and which an MDM
checkpoint stores under ``clip_model.``; the architecture (pre-norm blocks, QuickGELU, causal mask, the EOT token's
feature times ``text_projection``) is OpenAI's, read from the tensors' shapes. The tokenizer is OpenAI's
``SimpleTokenizer`` rebuilt on the ``tokenizers`` package from ``bpe_simple_vocab_16e6.txt.gz``.
"""

from __future__ import annotations

import gzip
import warnings
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import torch
from safetensors.torch import load_file
from tokenizers import Regex, Tokenizer, models, normalizers, pre_tokenizers
from torch import Tensor, nn

VOCAB_FILE = "bpe_simple_vocab_16e6.txt.gz"
SOT, EOT = "<|startoftext|>", "<|endoftext|>"
# OpenAI SimpleTokenizer's word pattern (clip/simple_tokenizer.py)
WORDS = r"""<\|startoftext\|>|<\|endoftext\|>|'s|'t|'re|'ve|'m|'ll|'d|[\p{L}]+|[\p{N}]|[^\s\p{L}\p{N}]+"""
TEXT_KEYS = ("token_embedding.", "positional_embedding", "transformer.", "ln_final.", "text_projection")
WRAPPER_PREFIXES = ("module.", "clip_model.", "model.")


@dataclass(frozen=True)
class ClipTextConfig:
    vocab_size: int = 49408
    context_length: int = 77
    width: int = 512
    layers: int = 12
    heads: int = 8
    embed_dim: int = 512  # output width (text_projection's columns)

    @classmethod
    def from_state_dict(cls, state: Mapping[str, Tensor]) -> ClipTextConfig:
        """Shapes as OpenAI's ``build_model`` reads them (heads = width / 64)."""
        for key in ("token_embedding.weight", "positional_embedding", "text_projection", "ln_final.weight"):
            if key not in state:
                raise ValueError(f"{key}: missing from the CLIP weights (not a CLIP text tower)")
        vocab, width = state["token_embedding.weight"].shape
        layers = len({k.split(".")[2] for k in state if k.startswith("transformer.resblocks.")})
        return cls(
            vocab_size=vocab,
            context_length=state["positional_embedding"].shape[0],
            width=width,
            layers=layers,
            heads=max(width // 64, 1),
            embed_dim=state["text_projection"].shape[1],
        )


class QuickGELU(nn.Module):
    def forward(self, x: Tensor) -> Tensor:
        return x * torch.sigmoid(1.702 * x)


class ResidualAttentionBlock(nn.Module):
    def __init__(self, width: int, heads: int) -> None:
        super().__init__()
        self.attn = nn.MultiheadAttention(width, heads, batch_first=True)
        self.ln_1 = nn.LayerNorm(width)
        self.mlp = nn.Sequential()
        self.mlp.add_module("c_fc", nn.Linear(width, width * 4))
        self.mlp.add_module("gelu", QuickGELU())
        self.mlp.add_module("c_proj", nn.Linear(width * 4, width))
        self.ln_2 = nn.LayerNorm(width)

    def forward(self, x: Tensor, causal: Tensor) -> Tensor:
        h = self.ln_1(x)
        x = x + self.attn(h, h, h, attn_mask=causal, need_weights=False)[0]
        return x + self.mlp(self.ln_2(x))


class Transformer(nn.Module):
    def __init__(self, width: int, layers: int, heads: int) -> None:
        super().__init__()
        self.resblocks = nn.ModuleList(ResidualAttentionBlock(width, heads) for _ in range(layers))


class ClipTextTower(nn.Module):
    """Token ids ``(B, L)`` (SOT ... EOT, zero-padded) and EOT positions ``(B,)`` -> features ``(B, embed_dim)``."""

    def __init__(self, config: ClipTextConfig) -> None:
        super().__init__()
        self.config = config
        self.token_embedding = nn.Embedding(config.vocab_size, config.width)
        self.positional_embedding = nn.Parameter(torch.empty(config.context_length, config.width))
        self.transformer = Transformer(config.width, config.layers, config.heads)
        self.ln_final = nn.LayerNorm(config.width)
        self.text_projection = nn.Parameter(torch.empty(config.width, config.embed_dim))
        nn.init.normal_(self.token_embedding.weight, std=0.02)
        nn.init.normal_(self.positional_embedding, std=0.01)
        nn.init.normal_(self.text_projection, std=config.width**-0.5)

    def forward(self, tokens: Tensor, eot: Tensor) -> Tensor:
        length = tokens.shape[1]
        x = self.token_embedding(tokens) + self.positional_embedding[:length]  # (B, L, W)
        causal = torch.full((length, length), float("-inf"), device=x.device).triu(1)
        for block in self.transformer.resblocks:
            x = block(x, causal)
        x = self.ln_final(x)
        return x[torch.arange(x.shape[0], device=x.device), eot] @ self.text_projection

    @classmethod
    def from_state_dict(cls, state: Mapping[str, Tensor]) -> ClipTextTower:
        """The tower with these weights (float32); a key that does not fit is one ``ValueError`` line."""
        text = text_state(state)
        tower = cls(ClipTextConfig.from_state_dict(text))
        ours = tower.state_dict()
        for key, value in text.items():
            if key not in ours:
                raise ValueError(f"{key}: not a parameter of the CLIP text tower")
            if value.shape != ours[key].shape:
                raise ValueError(f"{key}: shape {tuple(value.shape)} != expected {tuple(ours[key].shape)}")
        missing = sorted(set(ours) - set(text))
        if missing:
            raise ValueError(f"{missing[0]}: missing from the CLIP weights ({len(missing)} keys missing)")
        tower.load_state_dict({k: v.float() for k, v in text.items()})
        return tower.eval().requires_grad_(False)


def text_state(state: Mapping[str, Tensor]) -> dict[str, Tensor]:
    """The text-tower entries of a CLIP (or MDM) state dict, wrapper prefixes stripped; vision keys dropped."""
    out = {}
    for key, value in state.items():
        for prefix in WRAPPER_PREFIXES:
            key = key.removeprefix(prefix)
        if key.startswith(TEXT_KEYS) and isinstance(value, Tensor):
            out[key] = value
    return out


def read_clip_weights(path: str | Path) -> dict[str, Tensor]:
    """A CLIP checkpoint's tensors: safetensors, a plain state dict (``weights_only`` load), or OpenAI's
    TorchScript ``ViT-B-32.pt`` (``torch.jit.load``: TorchScript runs no pickled Python)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: CLIP ViT-B/32 weights file not found (the encoder never downloads)")
    if path.suffix == ".safetensors":
        return load_file(str(path))
    if zipfile.is_zipfile(path) and any(n.endswith("constants.pkl") for n in zipfile.ZipFile(path).namelist()):
        with warnings.catch_warnings():  # torch 2.13 calls jit.load deprecated; it is the only reader of this format
            warnings.simplefilter("ignore", DeprecationWarning)
            return dict(torch.jit.load(str(path), map_location="cpu").state_dict())
    try:
        loaded = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # torch raises several types for a file that is not a checkpoint
        raise ValueError(f"{path}: not a readable CLIP checkpoint ({type(err).__name__})") from None
    if isinstance(loaded, Mapping) and isinstance(loaded.get("state_dict"), Mapping):
        loaded = loaded["state_dict"]
    if not isinstance(loaded, Mapping):
        raise ValueError(f"{path}: not a CLIP state dict (holds {type(loaded).__name__})")
    return dict(loaded)


def _bytes_to_unicode() -> dict[int, str]:
    """GPT-2's reversible byte -> printable-character table, which CLIP's BPE is written in."""
    printable = list(range(ord("!"), ord("~") + 1)) + list(range(ord("¡"), ord("¬") + 1))
    printable += list(range(ord("®"), ord("ÿ") + 1))
    chars, extra = list(printable), 0
    for byte in range(256):
        if byte not in printable:
            printable.append(byte)
            chars.append(256 + extra)
            extra += 1
    return dict(zip(printable, map(chr, chars)))


class ClipTokenizer:
    """OpenAI CLIP's tokenizer: lower-cased, whitespace-collapsed, byte-level BPE with ``</w>`` word ends.

    ``encode`` gives SOT + at most ``max_tokens`` BPE ids + EOT per caption (``clip.tokenize(truncate=True)``).
    OpenAI also runs ``ftfy.fix_text`` and HTML unescaping first; for captions with clean text that is a no-op.
    """

    def __init__(self, vocab_file: str | Path) -> None:
        lines = gzip.open(vocab_file, "rt", encoding="utf-8").read().split("\n")
        merges = [tuple(line.split()) for line in lines[1 : 49152 - 256 - 2 + 1] if line.strip()]
        symbols = list(_bytes_to_unicode().values())
        vocab = symbols + [s + "</w>" for s in symbols] + ["".join(m) for m in merges] + [SOT, EOT]
        bpe = models.BPE({t: i for i, t in enumerate(vocab)}, merges, end_of_word_suffix="</w>")
        self._tok = Tokenizer(bpe)
        self._tok.normalizer = normalizers.Sequence(
            [normalizers.NFC(), normalizers.Replace(Regex(r"\s+"), " "), normalizers.Lowercase()]
        )
        self._tok.pre_tokenizer = pre_tokenizers.Sequence(
            [
                pre_tokenizers.Split(Regex(WORDS), behavior="removed", invert=True),
                pre_tokenizers.ByteLevel(add_prefix_space=False, use_regex=False),
            ]
        )
        self.sot, self.eot, self.vocab_size = len(vocab) - 2, len(vocab) - 1, len(vocab)

    def ids(self, text: str) -> list[int]:
        return self._tok.encode(text.strip(), add_special_tokens=False).ids

    def encode(self, texts: list[str], max_tokens: int) -> tuple[Tensor, Tensor]:
        """Zero-padded ids ``(B, L)`` (L = longest in the batch) and each caption's EOT position ``(B,)``."""
        rows = [[self.sot, *self.ids(t)[:max_tokens], self.eot] for t in texts]
        tokens = torch.zeros(len(rows), max(len(r) for r in rows), dtype=torch.long)
        for i, row in enumerate(rows):
            tokens[i, : len(row)] = torch.tensor(row)
        return tokens, torch.tensor([len(r) - 1 for r in rows])
