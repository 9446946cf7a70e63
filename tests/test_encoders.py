"""Text encoders, the motion encoder and the evaluation classifiers."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn as nn
import torch.nn.functional as F
from conftest import FIXTURES, REPO

from motionaug.augment.motion.batch import pad_batch
from motionaug.augment.training.evaluators import classifier_accuracy, classifier_features, fit_classifier
from motionaug.models.evaluators import content_classifier, joints_to_evaluator_input, make_classifier, style_classifier
from motionaug.models.minilm import BertEncoder, load_tokenizer
from motionaug.models.motion_encoder import MotionEncoder, MotionEncoderConfig, semantic_loss
from motionaug.models.text_encoder import (
    CachedTextEncoder,
    ClipTextEncoder,
    MiniLMTextEncoder,
    TextEncoder,
    find_clip_vocab,
    make_text_encoder,
    minilm_model_dir,
)

torch.set_num_threads(1)


# --- text encoders -----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def minilm() -> MiniLMTextEncoder:
    return MiniLMTextEncoder(cache_size=4)


def test_minilm_shapes_dtype_and_norm(minilm: MiniLMTextEncoder) -> None:
    emb = minilm.encode(["a person walks", "a man jumps twice", "a person walks"])
    assert isinstance(minilm, TextEncoder)
    assert minilm.dim == 384
    assert emb.shape == (3, 384) and emb.dtype == torch.float32 and emb.device.type == "cpu"
    assert not emb.requires_grad
    torch.testing.assert_close(emb.norm(dim=-1), torch.ones(3))
    torch.testing.assert_close(emb[0], emb[2])
    assert minilm.encode([]).shape == (0, 384)


def test_minilm_semantics(minilm: MiniLMTextEncoder) -> None:
    walk, walking, dog = minilm.encode(["a person walks", "someone is walking", "a dog barks"])
    assert float(walk @ walking) > float(walk @ dog) + 0.3


def test_minilm_cache_hits_and_is_bounded(minilm: MiniLMTextEncoder) -> None:
    minilm.clear_cache()
    first = minilm.encode(["a person kicks", "a person waves"])
    assert (minilm.cache_info().hits, minilm.cache_info().misses) == (0, 2)
    again = minilm.encode(["a person waves", "a person kicks"])
    assert (minilm.cache_info().hits, minilm.cache_info().misses) == (2, 2)
    torch.testing.assert_close(again, first.flip(0), rtol=0, atol=0)
    minilm.encode(["one", "two", "three", "four", "five"])
    assert minilm.cache_info().size == 4  # cache_size=4: least recently used dropped


class CountingEncoder(CachedTextEncoder):
    """A real, deterministic encoder (character histogram) that counts what reaches the model."""

    def __init__(self, cache_size: int) -> None:
        super().__init__(cache_size)
        self.seen: list[str] = []

    @property
    def dim(self) -> int:
        return 26

    def _encode_uncached(self, texts: list[str]) -> torch.Tensor:
        self.seen.extend(texts)
        rows = [[float(t.count(chr(ord("a") + i))) for i in range(26)] for t in texts]
        return torch.tensor(rows)


def test_cache_sends_each_new_string_to_the_model_once() -> None:
    enc = CountingEncoder(cache_size=2)
    out = enc.encode(["ab", "ab", "cd"])
    assert enc.seen == ["ab", "cd"] and out.shape == (3, 26)
    enc.encode(["cd", "ab"])
    assert enc.seen == ["ab", "cd"]
    enc.encode(["ef"])  # the last call touched cd then ab, so cd is evicted
    enc.encode(["ab"])
    assert enc.seen == ["ab", "cd", "ef"]
    enc.encode(["cd"])
    assert enc.seen == ["ab", "cd", "ef", "cd"]
    with pytest.raises(TypeError, match="list of captions"):
        enc.encode("ab")  # type: ignore[arg-type]


def test_clip_encoder_errors_name_what_is_missing(tmp_path) -> None:
    with pytest.raises(FileNotFoundError, match="ViT-B-32.pt: CLIP ViT-B/32 weights file not found"):
        ClipTextEncoder(tmp_path / "ViT-B-32.pt")
    weights = tmp_path / "ViT-B-32.pt"
    weights.write_bytes(b"not really weights")
    with pytest.raises(ValueError, match="ViT-B-32.pt: not a readable CLIP checkpoint"):
        ClipTextEncoder(weights)
    with pytest.raises(FileNotFoundError, match="vocab.txt.gz: CLIP tokenizer vocabulary"):
        find_clip_vocab(tmp_path / "vocab.txt.gz")
    with pytest.raises(ValueError, match="needs weights="):
        make_text_encoder("clip")
    with pytest.raises(ValueError, match="unknown name 'bert'"):
        make_text_encoder("bert")


def test_minilm_missing_folder_is_a_clear_error(tmp_path) -> None:
    with pytest.raises(FileNotFoundError, match="lacks config.json"):
        MiniLMTextEncoder(model_dir=tmp_path)


def minilm_reference() -> tuple[list[str], torch.Tensor]:
    """Captions and their sentence-transformers 6.2.0 embeddings (see tests/fixtures/README.md)."""
    data = np.load(FIXTURES / "minilm_reference.npz")
    return [str(t) for t in data["texts"]], torch.from_numpy(data["embeddings"])


def test_minilm_reproduces_sentence_transformers() -> None:
    texts, expected = minilm_reference()
    for batch_size in (64, 3):  # one padded batch, and several
        got = MiniLMTextEncoder(batch_size=batch_size, cache_size=0).encode(texts)
        torch.testing.assert_close(got, expected, rtol=0, atol=1e-5)  # measured max |diff|: 2.4e-7


def test_minilm_truncates_to_256_tokens_like_sentence_transformers() -> None:
    texts, _ = minilm_reference()
    longest = max(texts, key=len)
    tokenizer = load_tokenizer(minilm_model_dir() / "tokenizer.json", max_length=256)
    ids = tokenizer.encode(longest).ids
    assert len(ids) == 256 and ids[-1] == tokenizer.token_to_id("[SEP]")  # so the fixture test covers truncation
    assert len(tokenizer.encode("a person walks").ids) == 5  # no padding from tokenizer.json's own settings


def test_minilm_padding_does_not_leak() -> None:
    texts = ["walk", "a person walks forward and then turns around.", "A MAN JUMPS UP AND DOWN!!!", ""]
    encoder = MiniLMTextEncoder(cache_size=0)
    batch = encoder.encode(texts)
    for text, row in zip(texts, batch):
        torch.testing.assert_close(encoder.encode([text])[0], row, rtol=0, atol=1e-6)


def test_bert_encoder_ignores_padded_tokens() -> None:
    model = BertEncoder.from_pretrained(minilm_model_dir())
    ids = torch.tensor([[101, 1037, 2711, 7365, 102, 0, 0], [101, 1037, 2711, 7365, 102, 2342, 999]])
    mask = torch.tensor([[1, 1, 1, 1, 1, 0, 0], [1, 1, 1, 1, 1, 0, 0]])
    with torch.inference_mode():
        hidden = model(ids, mask)
        alone = model(ids[:1, :5], mask[:1, :5])
    assert hidden.shape == (2, 7, 384)
    torch.testing.assert_close(hidden[0, :5], hidden[1, :5], rtol=0, atol=1e-5)  # pad ids differ, states do not
    torch.testing.assert_close(hidden[0, :5], alone[0], rtol=0, atol=1e-5)


def test_bert_encoder_loads_strictly(tmp_path: Path) -> None:
    from safetensors.torch import load_file, save_file

    folder = minilm_model_dir()
    weights = load_file(str(folder / "model.safetensors"))
    del weights["encoder.layer.5.output.dense.bias"]
    (tmp_path / "config.json").write_text((folder / "config.json").read_text())
    save_file(weights, str(tmp_path / "model.safetensors"))
    with pytest.raises(RuntimeError, match="encoder.layer.5.output.dense.bias"):
        BertEncoder.from_pretrained(tmp_path)


def test_minilm_does_not_import_transformers() -> None:
    code = (
        "import sys\n"
        "import models.text_encoder as te\n"
        "te.MiniLMTextEncoder().encode(['a person walks'])\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('transformers', 'sentence_transformers')))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


# --- motion encoder ----------------------------------------------------------------------------

FEATS, TEXT_DIM = 12, 16


def tiny_encoder(embed: nn.Module | None = None, layout: str = "btd") -> MotionEncoder:
    torch.manual_seed(0)
    config = MotionEncoderConfig.named("tiny", input_dim=FEATS, text_dim=TEXT_DIM)
    return MotionEncoder(config, embed, layout).eval()  # type: ignore[arg-type]


def test_motion_encoder_shapes_and_named_sizes() -> None:
    enc = tiny_encoder()
    out = enc(torch.randn(3, 10, FEATS), torch.ones(3, 10, dtype=torch.bool))
    assert out.shape == (3, TEXT_DIM)
    assert MotionEncoderConfig.named("paper").d_model == 512
    with pytest.raises(ValueError, match="unknown 'huge'"):
        MotionEncoderConfig.named("huge")


def test_motion_encoder_ignores_padded_frames() -> None:
    enc = tiny_encoder()
    x = torch.randn(2, 12, FEATS)
    mask = torch.zeros(2, 12, dtype=torch.bool)
    mask[0, :7] = True
    mask[1, :12] = True
    before = enc(x, mask)
    x2 = x.clone()
    x2[0, 7:] = torch.randn(5, FEATS) * 100
    torch.testing.assert_close(enc(x2, mask), before)
    alone = enc(x[:1, :7], mask[:1, :7])  # same clip without padding
    torch.testing.assert_close(alone, before[:1], rtol=1e-4, atol=1e-5)


def test_motion_encoder_shares_the_embedding_parameters() -> None:
    embed = nn.Linear(FEATS, 64)
    enc = tiny_encoder(embed)
    assert enc.embed is embed and enc.embed.weight is embed.weight
    semantic_loss(enc(torch.randn(2, 5, FEATS)), torch.randn(2, TEXT_DIM)).backward()
    assert embed.weight.grad is not None and embed.weight.grad.abs().sum() > 0


def test_motion_encoder_shares_the_mdm_input_layer() -> None:
    from motionaug.models.mdm import MDM, MDMConfig

    mdm = MDM(MDMConfig.named("tiny", n_feats=FEATS, text_dim=TEXT_DIM))
    enc = MotionEncoder(MotionEncoderConfig.named("tiny", input_dim=FEATS, text_dim=TEXT_DIM), mdm.input_process)
    assert enc.embed.poseEmbedding.weight is mdm.input_process.poseEmbedding.weight
    shared = {id(p) for p in enc.parameters()} & {id(p) for p in mdm.parameters()}
    assert shared == {id(p) for p in mdm.input_process.parameters()}
    assert enc(torch.randn(2, 6, FEATS)).shape == (2, TEXT_DIM)


class SeqFirstEmbed(nn.Module):
    """Like MDM's input layer: takes (T, B, D), refuses batch-first input of this test's shape."""

    def __init__(self, linear: nn.Linear, frames: int) -> None:
        super().__init__()
        self.linear, self.frames = linear, frames

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        assert x.shape[0] == self.frames, "expected sequence-first input"
        return self.linear(x)


def test_motion_encoder_accepts_a_sequence_first_embedding() -> None:
    linear = nn.Linear(FEATS, 64)
    x = torch.randn(2, 9, FEATS)
    batch_first = tiny_encoder(linear)(x)
    seq_first = tiny_encoder(SeqFirstEmbed(linear, 9), "tbd")(x)
    torch.testing.assert_close(seq_first, batch_first)


def test_semantic_loss_matches_eq8() -> None:
    m = torch.tensor([[3.0, 4.0], [0.0, 0.0]])
    t = torch.tensor([[3.0, 4.0], [1.0, 0.0]])
    expected = ((1 - 25 / (25 + 1e-6)) + 1.0) / 2  # zero motion vector: cosine 0, loss 1, no NaN
    assert math.isclose(float(semantic_loss(m, t)), expected, rel_tol=1e-6)


def test_motion_encoder_learns_a_toy_pairing() -> None:
    torch.manual_seed(1)
    enc = tiny_encoder().train()
    motions = torch.randn(8, 10, FEATS)
    mask = torch.ones(8, 10, dtype=torch.bool)
    mask[::2, 6:] = False
    texts = F.normalize(torch.randn(8, TEXT_DIM), dim=-1)
    opt = torch.optim.Adam(enc.parameters(), lr=3e-3)
    start = semantic_loss(enc(motions, mask), texts).item()
    for _ in range(100):
        loss = semantic_loss(enc(motions, mask), texts)
        opt.zero_grad()
        loss.backward()
        opt.step()
    end = semantic_loss(enc.eval()(motions, mask), texts).item()
    assert start > 0.6 and end < 0.15 * start


# --- evaluation classifiers ----------------------------------------------------------------------

J = 22


def toy_motions(n: int, seed: int) -> tuple[list[torch.Tensor], torch.Tensor]:
    """Class 0 stands still; class 1 crouches (every joint 0.3 m lower) and moves along +Z at 1.2 m/s."""
    base = torch.randn(1, J, 3, generator=torch.Generator().manual_seed(123)) * 0.3 + torch.tensor([0.0, 1.0, 0.0])
    g = torch.Generator().manual_seed(seed)
    clips, labels = [], []
    for i in range(n):
        frames = 8 + i % 9
        label = i % 2
        pose = base + torch.randn(1, J, 3, generator=g) * 0.02
        joints = pose.repeat(frames, 1, 1) + torch.randn(frames, J, 3, generator=g) * 0.005
        if label:
            joints[..., 1] -= 0.3
            joints[..., 2] += torch.arange(frames).float()[:, None] * 0.06
        clips.append(joints)
        labels.append(label)
    return clips, torch.tensor(labels)


def test_evaluator_input_layout() -> None:
    joints = torch.randn(2, 5, J, 3)
    x = joints_to_evaluator_input(joints)
    assert x.shape == (2, 5, 6 * J + 3)
    local = x[..., : 3 * J].reshape(2, 5, J, 3)
    torch.testing.assert_close(local[..., 0, 0], torch.zeros(2, 5))  # root at ground-plane origin
    torch.testing.assert_close(local[..., 1], joints[..., 1])  # heights kept
    torch.testing.assert_close(x[:, 1:, -3:], (joints[:, 1:, 0] - joints[:, :-1, 0]) * 20.0)
    assert torch.all(x[:, 0, 3 * J :] == 0)


def test_classifier_learns_a_separable_toy_problem() -> None:
    torch.manual_seed(0)
    clips, labels = toy_motions(24, seed=0)
    joints, mask = pad_batch(clips)
    model = content_classifier(2, size="tiny")
    history = fit_classifier(model, (joints, mask, labels), epochs=15, lr=3e-3, batch_size=8)
    assert history[-1] < 0.5 * history[0]
    assert not torch.allclose(model.input_std, torch.ones_like(model.input_std))  # standardised from the data
    test_joints, test_mask = pad_batch(toy_motions(16, seed=1)[0])
    assert classifier_accuracy(model, test_joints, test_mask, toy_motions(16, seed=1)[1]) == 1.0


def test_classifier_pooling_ignores_padding() -> None:
    torch.manual_seed(0)
    model = style_classifier(3, size="tiny").eval()
    clips, _ = toy_motions(3, seed=2)
    joints, mask = pad_batch(clips)
    feats = classifier_features(model, joints, mask)
    assert feats.shape == (3, model.config.feat_dim)
    noisy = joints.clone()
    noisy[~mask] = torch.randn(int((~mask).sum()), J, 3) * 50
    torch.testing.assert_close(classifier_features(model, noisy, mask), feats)
    for i, clip in enumerate(clips):
        alone = model.features(clip[None], torch.ones(1, clip.shape[0], dtype=torch.bool))
        torch.testing.assert_close(alone[0], feats[i], rtol=1e-4, atol=1e-5)
    assert model(joints, mask).shape == (3, 3)


def test_classifier_rejects_bad_shapes() -> None:
    model = make_classifier(2, size="tiny")
    with pytest.raises(ValueError, match=r"expected joints \(B, T, 22, 3\)"):
        model(torch.randn(2, 5, 21, 3))
    with pytest.raises(ValueError, match="mask"):
        model(torch.randn(2, 5, J, 3), torch.ones(2, 4, dtype=torch.bool))
