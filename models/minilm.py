"""all-MiniLM-L6-v2 in plain PyTorch: a small BERT encoder, mean pooling and L2 normalisation.

Why this exists: importing ``sentence_transformers`` (which pulls in ``transformers``) costs seconds of CPU per
process, and every Ray worker paid it at its first task. This module loads the same ``model.safetensors`` and
``tokenizer.json`` and gives the same embeddings as ``SentenceTransformer("all-MiniLM-L6-v2").encode(texts,
normalize_embeddings=True)`` (Transformer -> mean Pooling -> Normalize), importing only ``torch``,
``safetensors`` and the Rust ``tokenizers`` package. Inference only: no dropout, no training code.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import torch
import torch.nn as nn
import torch.nn.functional as F
from safetensors.torch import load_file
from tokenizers import Encoding, Tokenizer

DEFAULT_MAX_SEQ_LENGTH = 256  # sentence-transformers' max_seq_length for all-MiniLM-L6-v2
UNUSED_KEYS = ("embeddings.position_ids", "pooler.")  # in BERT checkpoints, not used for sentence embeddings


@dataclass(frozen=True)
class BertConfig:
    vocab_size: int = 30522
    hidden_size: int = 384
    num_hidden_layers: int = 6
    num_attention_heads: int = 12
    intermediate_size: int = 1536
    max_position_embeddings: int = 512
    type_vocab_size: int = 2
    layer_norm_eps: float = 1e-12
    hidden_act: str = "gelu"

    @classmethod
    def from_json(cls, path: str | Path) -> BertConfig:
        """Read the fields this encoder uses from a Hugging Face ``config.json``; refuse what it cannot run."""
        raw = json.loads(Path(path).read_text())
        names = cls.__dataclass_fields__
        config = cls(**{k: v for k, v in raw.items() if k in names})
        if config.hidden_act != "gelu":
            raise ValueError(f"{path}: hidden_act {config.hidden_act!r} not supported (only exact 'gelu')")
        if raw.get("position_embedding_type", "absolute") != "absolute":
            raise ValueError(f"{path}: only absolute position embeddings are supported")
        if config.hidden_size % config.num_attention_heads:
            raise ValueError(f"{path}: hidden_size {config.hidden_size} not divisible by the number of heads")
        return config


class BertEmbeddings(nn.Module):
    def __init__(self, config: BertConfig) -> None:
        super().__init__()
        self.word_embeddings = nn.Embedding(config.vocab_size, config.hidden_size)
        self.position_embeddings = nn.Embedding(config.max_position_embeddings, config.hidden_size)
        self.token_type_embeddings = nn.Embedding(config.type_vocab_size, config.hidden_size)
        self.LayerNorm = nn.LayerNorm(config.hidden_size, eps=config.layer_norm_eps)

    def forward(self, input_ids: torch.Tensor) -> torch.Tensor:
        """Single-segment input: every token_type_id is 0, positions count from 0."""
        positions = torch.arange(input_ids.shape[1], device=input_ids.device)
        segment = self.token_type_embeddings.weight[0]
        return self.LayerNorm(self.word_embeddings(input_ids) + self.position_embeddings(positions) + segment)


class DenseAddNorm(nn.Module):
    """BERT's post-LN residual: ``LayerNorm(dense(x) + residual)`` (``attention.output`` and ``output``)."""

    def __init__(self, d_in: int, d_out: int, eps: float) -> None:
        super().__init__()
        self.dense = nn.Linear(d_in, d_out)
        self.LayerNorm = nn.LayerNorm(d_out, eps=eps)

    def forward(self, x: torch.Tensor, residual: torch.Tensor) -> torch.Tensor:
        return self.LayerNorm(self.dense(x) + residual)


class SelfAttention(nn.Module):
    def __init__(self, config: BertConfig) -> None:
        super().__init__()
        self.n_head = config.num_attention_heads
        self.query = nn.Linear(config.hidden_size, config.hidden_size)
        self.key = nn.Linear(config.hidden_size, config.hidden_size)
        self.value = nn.Linear(config.hidden_size, config.hidden_size)

    def forward(self, x: torch.Tensor, attend: torch.Tensor) -> torch.Tensor:
        """``attend`` (B, 1, 1, L) bool, True for real tokens: padded keys get no attention weight."""
        b, length, d = x.shape

        def heads(t: torch.Tensor) -> torch.Tensor:
            return t.view(b, length, self.n_head, d // self.n_head).transpose(1, 2)

        y = F.scaled_dot_product_attention(heads(self.query(x)), heads(self.key(x)), heads(self.value(x)), attend)
        return y.transpose(1, 2).reshape(b, length, d)


class Attention(nn.Module):
    def __init__(self, config: BertConfig) -> None:
        super().__init__()
        self.self = SelfAttention(config)  # attribute names follow the checkpoint keys: attention.self.query...
        self.output = DenseAddNorm(config.hidden_size, config.hidden_size, config.layer_norm_eps)

    def forward(self, x: torch.Tensor, attend: torch.Tensor) -> torch.Tensor:
        return self.output(self.self(x, attend), x)


class Intermediate(nn.Module):
    def __init__(self, config: BertConfig) -> None:
        super().__init__()
        self.dense = nn.Linear(config.hidden_size, config.intermediate_size)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.gelu(self.dense(x))  # exact (erf) GELU, as BERT's "gelu"


class Layer(nn.Module):
    def __init__(self, config: BertConfig) -> None:
        super().__init__()
        self.attention = Attention(config)
        self.intermediate = Intermediate(config)
        self.output = DenseAddNorm(config.intermediate_size, config.hidden_size, config.layer_norm_eps)

    def forward(self, x: torch.Tensor, attend: torch.Tensor) -> torch.Tensor:
        x = self.attention(x, attend)
        return self.output(self.intermediate(x), x)


class LayerStack(nn.Module):
    def __init__(self, config: BertConfig) -> None:
        super().__init__()
        self.layer = nn.ModuleList(Layer(config) for _ in range(config.num_hidden_layers))

    def forward(self, x: torch.Tensor, attend: torch.Tensor) -> torch.Tensor:
        for layer in self.layer:
            x = layer(x, attend)
        return x


class BertEncoder(nn.Module):
    """BERT without its pooler; parameter names equal the keys of a Hugging Face ``BertModel`` checkpoint."""

    def __init__(self, config: BertConfig) -> None:
        super().__init__()
        self.config = config
        self.embeddings = BertEmbeddings(config)
        self.encoder = LayerStack(config)

    def forward(self, input_ids: torch.Tensor, attention_mask: torch.Tensor) -> torch.Tensor:
        """``(B, L)`` token ids and 1/0 mask -> last hidden state ``(B, L, H)`` (pad rows are meaningless)."""
        attend = attention_mask.bool()[:, None, None, :]
        return self.encoder(self.embeddings(input_ids), attend)

    @classmethod
    def from_pretrained(cls, model_dir: str | Path) -> BertEncoder:
        """Load ``config.json`` + ``model.safetensors``; strict, so a file for another architecture fails loudly."""
        model_dir = Path(model_dir)
        model = cls(BertConfig.from_json(model_dir / "config.json"))
        weights = load_file(str(model_dir / "model.safetensors"))
        used = {k: v for k, v in weights.items() if not k.startswith(UNUSED_KEYS)}
        model.load_state_dict(used, strict=True)
        return model.eval()


def mean_pool(hidden: torch.Tensor, attention_mask: torch.Tensor) -> torch.Tensor:
    """Average of the real tokens' states (sentence-transformers' ``pooling_mode_mean_tokens``)."""
    mask = attention_mask[..., None].to(hidden.dtype)
    return (hidden * mask).sum(1) / mask.sum(1).clamp(min=1e-9)


def load_tokenizer(path: str | Path, max_length: int) -> Tokenizer:
    """WordPiece tokenizer with [CLS]/[SEP], truncated to ``max_length`` tokens in all; we pad ourselves."""
    tokenizer = Tokenizer.from_file(str(path))
    tokenizer.enable_truncation(max_length=max_length)  # replaces tokenizer.json's own 128-token setting
    tokenizer.no_padding()  # tokenizer.json pads every text to 128; we pad each batch to its longest
    return tokenizer


def pad_batch(encodings: list[Encoding], pad_id: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Right-pad token ids to the longest encoding: ``(input_ids, attention_mask)``, both ``(B, L)`` int64."""
    length = max(len(e.ids) for e in encodings)
    ids = torch.full((len(encodings), length), pad_id, dtype=torch.long)
    mask = torch.zeros(len(encodings), length, dtype=torch.long)
    for i, e in enumerate(encodings):
        ids[i, : len(e.ids)] = torch.tensor(e.ids)
        mask[i, : len(e.ids)] = 1
    return ids, mask


def read_max_seq_length(model_dir: Path) -> int:
    """sentence-transformers' truncation length, from ``sentence_bert_config.json`` when the folder has one."""
    path = model_dir / "sentence_bert_config.json"
    if not path.is_file():
        return DEFAULT_MAX_SEQ_LENGTH
    return int(json.loads(path.read_text()).get("max_seq_length", DEFAULT_MAX_SEQ_LENGTH))


class SentenceEncoder:
    """Captions -> L2-normalised mean-pooled BERT embeddings ``(B, H)`` float32, as all-MiniLM-L6-v2."""

    def __init__(self, model_dir: str | Path, device: str | torch.device = "cpu") -> None:
        model_dir = Path(model_dir)
        self.model = BertEncoder.from_pretrained(model_dir).to(device)
        max_length = min(read_max_seq_length(model_dir), self.model.config.max_position_embeddings)
        self.tokenizer = load_tokenizer(model_dir / "tokenizer.json", max_length)
        self.pad_id = self.tokenizer.token_to_id("[PAD]") or 0  # value is irrelevant: pads are masked out
        self.device = torch.device(device)

    @property
    def dim(self) -> int:
        return self.model.config.hidden_size

    def encode(self, texts: list[str], batch_size: int = 64) -> torch.Tensor:
        """Embeddings in the order of ``texts``; batches are built from length-sorted texts to cut padding."""
        if not texts:
            return torch.empty(0, self.dim, device=self.device)
        encodings = self.tokenizer.encode_batch(texts)
        order = sorted(range(len(texts)), key=lambda i: -len(encodings[i].ids))
        out = torch.empty(len(texts), self.dim, device=self.device)
        for start in range(0, len(order), batch_size):
            rows = order[start : start + batch_size]
            out[rows] = self._embed([encodings[i] for i in rows])
        return out

    @torch.inference_mode()
    def _embed(self, encodings: list[Encoding]) -> torch.Tensor:
        ids, mask = (t.to(self.device) for t in pad_batch(encodings, self.pad_id))
        return F.normalize(mean_pool(self.model(ids, mask), mask), dim=-1)
