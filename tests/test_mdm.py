"""MDM denoiser: shapes, masks, condition dropping, bf16, official-checkpoint key mapping."""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F
from torch import Tensor

from motionaug.augment.diffusion import NoiseSchedule, bind_model, ddim_sample, x0_training_loss
from motionaug.models.attention import run_encoder
from motionaug.models.lora import apply_lora
from motionaug.models.mdm import MDM, MDMConfig
from motionaug.models.mdm_checkpoint import load_official_mdm_state_dict
from motionaug.schemas.errors import MotionDataError

torch.set_num_threads(1)
B, T = 3, 12


def tiny(**overrides: object) -> MDM:
    torch.manual_seed(0)
    return MDM(MDMConfig.named("tiny", **overrides))


def inputs(model: MDM, seed: int = 0) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    g = torch.Generator().manual_seed(seed)
    x = torch.randn(B, T, model.config.n_feats, generator=g)
    t = torch.randint(0, 1000, (B,), generator=g)
    text = torch.randn(B, model.config.text_dim, generator=g)
    mask = torch.ones(B, T, dtype=torch.bool)
    mask[1, 7:] = False
    mask[2, 3:] = False
    return x, t, text, mask


def test_named_configs() -> None:
    paper = MDMConfig.named("paper", text_dim=512)
    assert (paper.num_layers, paper.latent_dim, paper.ff_size, paper.num_heads) == (8, 512, 1024, 4)
    assert (MDMConfig.named("small").num_layers, MDMConfig.named("small").latent_dim) == (4, 256)
    assert (MDMConfig.named("tiny").num_layers, MDMConfig.named("tiny").latent_dim) == (2, 64)
    with pytest.raises(MotionDataError):
        MDMConfig.named("huge")


def test_output_shape_and_condition_forms() -> None:
    model = tiny().eval()
    x, t, text, mask = inputs(model)
    out = model(x, t, text, mask)
    assert out.shape == x.shape
    assert torch.equal(out, model(x, t, {"text_embed": text}, mask))
    assert torch.allclose(model(x, t, None, mask), model(x, t, text, mask, force_uncond=True))
    assert not torch.allclose(out, model(x, t, text, mask, force_uncond=True))
    per_sample = model(x, t, text, mask, force_uncond=torch.tensor([False, True, False]))
    assert torch.allclose(per_sample[0], out[0], atol=1e-6) and not torch.allclose(per_sample[1], out[1])
    assert model.motion_embed(x).shape == (B, T, 64)
    assert model.input_process.poseEmbedding.weight.shape == (64, 263)


@pytest.mark.parametrize("grad", [False, True])
def test_padding_frames_do_not_reach_valid_frames(grad: bool) -> None:
    """Both attention kernels of ``run_encoder``: SDPA without gradients, the plain one with."""
    model = tiny(dropout=0.0, cond_mask_prob=0.0).train(grad)
    x, t, text, mask = inputs(model)
    x2 = x.clone()
    x2[~mask] = torch.randn(int((~mask).sum()), 263) * 100
    with torch.set_grad_enabled(grad):
        out, out2, unmasked = model(x, t, text, mask), model(x2, t, text, mask), model(x, t, text, None)
    assert torch.allclose(out[mask], out2[mask], atol=1e-5)
    assert not torch.allclose(unmasked[mask], out[mask], atol=1e-4)  # the mask does something


@pytest.mark.parametrize("lora", [False, True])
@pytest.mark.parametrize("grad", [False, True])
def test_run_encoder_equals_pytorch_encoder(grad: bool, lora: bool) -> None:
    """Our layer loop computes what ``nn.TransformerEncoder`` does, LoRA adapters included, values and gradients."""
    model = tiny(dropout=0.0).eval()
    if lora:
        apply_lora(model, rank=2, alpha=4.0, generator=torch.Generator().manual_seed(1))
        for name, p in model.named_parameters():
            if name.endswith("lora_B"):
                with torch.no_grad():
                    p.normal_(0, 0.1)  # non-zero adapters, or LoRA would not be exercised
    encoder = model.seqTransEncoder
    g = torch.Generator().manual_seed(3)
    x = torch.randn(B, T + 1, model.config.latent_dim, generator=g)
    keep = torch.ones(B, T + 1, dtype=torch.bool)
    keep[1, 8:] = False
    keep[2, 2:] = False
    for k in (keep, None):
        mine = x.clone().requires_grad_(grad)
        with torch.set_grad_enabled(grad):
            ours = run_encoder(encoder, mine, k)
            ref_in = x.clone().requires_grad_(grad)
            theirs = encoder(ref_in, src_key_padding_mask=None if k is None else ~k)
        valid = torch.ones(B, T + 1, dtype=torch.bool) if k is None else k
        assert torch.allclose(ours[valid], theirs[valid], atol=1e-5)
        if grad:
            (ours[valid] ** 2).sum().backward()
            (theirs[valid] ** 2).sum().backward()
            assert torch.allclose(mine.grad, ref_in.grad, atol=1e-4)


def test_training_cond_drop_and_masked_loss() -> None:
    model = tiny(dropout=0.0, cond_mask_prob=1.0).train()
    x, t, text, mask = inputs(model)
    dropped = model(x, t, text, mask)
    assert torch.allclose(dropped, model.eval()(x, t, text, mask, force_uncond=True), atol=1e-5)
    model = tiny(dropout=0.0, cond_mask_prob=0.0).train()
    sched = NoiseSchedule.cosine()
    tt, noise = torch.randint(0, 1000, (B,)), torch.randn(x.shape)
    fn = bind_model(model, text, mask)
    loss = x0_training_loss(fn, sched, x, mask, t=tt, noise=noise)
    x2 = x.clone()
    x2[~mask] = float("nan")  # padding must never reach the loss (nor the network)
    loss2 = x0_training_loss(fn, sched, x2, mask, t=tt, noise=noise)
    assert torch.isfinite(loss2) and torch.allclose(loss, loss2, atol=1e-6)
    loss2.backward()
    grads = [p.grad for p in model.parameters() if p.grad is not None]
    assert grads and all(torch.isfinite(g).all() for g in grads)


def test_bad_inputs_raise_motion_data_error() -> None:
    model = tiny().eval()
    x, t, text, mask = inputs(model)
    with pytest.raises(MotionDataError, match="features"):
        model(x[..., :100], t, text, mask)
    with pytest.raises(MotionDataError, match="text embedding"):
        model(x, t, torch.randn(B, 512), mask)
    with pytest.raises(MotionDataError, match="mask"):
        model(x, t, text, mask[:, :5])


def test_bf16_autocast_close_to_fp32() -> None:
    model = tiny().eval()
    x, t, text, mask = inputs(model)
    with torch.no_grad():
        ref = model(x, t, text, mask)
        with torch.autocast("cpu", dtype=torch.bfloat16):
            low = model(x, t, text, mask)
    assert low.dtype == torch.bfloat16
    rel = (low.float() - ref).norm() / ref.norm()
    assert float(rel) < 0.03


def test_sampling_with_tiny_model_end_to_end() -> None:
    model = tiny().eval()
    x, t, text, mask = inputs(model)
    out = ddim_sample(
        bind_model(model, text, mask), x.shape, steps=5, guidance_scale=2.5, generator=torch.Generator().manual_seed(1)
    )
    assert out.shape == x.shape and torch.isfinite(out).all()


# ---------------------------------------------------------------- official checkpoint layout


def official_state_dict(
    d: int = 512, ff: int = 1024, layers: int = 8, feats: int = 263, text: int = 512
) -> dict[str, Tensor]:
    """Random tensors in the official MDM HumanML3D trans_enc key layout and shapes."""
    g = torch.Generator().manual_seed(42)
    rnd = lambda *shape: torch.randn(*shape, generator=g) * 0.05  # noqa: E731
    sd = {
        "input_process.poseEmbedding.weight": rnd(d, feats),
        "input_process.poseEmbedding.bias": rnd(d),
        "embed_timestep.time_embed.0.weight": rnd(d, d),
        "embed_timestep.time_embed.0.bias": rnd(d),
        "embed_timestep.time_embed.2.weight": rnd(d, d),
        "embed_timestep.time_embed.2.bias": rnd(d),
        "embed_text.weight": rnd(d, text),
        "embed_text.bias": rnd(d),
        "output_process.poseFinal.weight": rnd(feats, d),
        "output_process.poseFinal.bias": rnd(feats),
        "clip_model.positional_embedding": rnd(77, 512),
        "clip_model.token_embedding.weight": rnd(10, 512),
    }
    position = torch.arange(5000, dtype=torch.float32)[:, None]
    div = torch.exp(torch.arange(0, d, 2).float() * (-math.log(10000.0) / d))
    pe = torch.zeros(5000, d)
    pe[:, 0::2], pe[:, 1::2] = torch.sin(position * div), torch.cos(position * div)
    sd["sequence_pos_encoder.pe"] = pe[:, None, :]  # (5000, 1, d)
    sd["embed_timestep.sequence_pos_encoder.pe"] = pe[:, None, :]
    for i in range(layers):
        p = f"seqTransEncoder.layers.{i}."
        sd |= {
            p + "self_attn.in_proj_weight": rnd(3 * d, d),
            p + "self_attn.in_proj_bias": rnd(3 * d),
            p + "self_attn.out_proj.weight": rnd(d, d),
            p + "self_attn.out_proj.bias": rnd(d),
            p + "linear1.weight": rnd(ff, d),
            p + "linear1.bias": rnd(ff),
            p + "linear2.weight": rnd(d, ff),
            p + "linear2.bias": rnd(d),
            p + "norm1.weight": 1 + rnd(d),
            p + "norm1.bias": rnd(d),
            p + "norm2.weight": 1 + rnd(d),
            p + "norm2.bias": rnd(d),
        }
    return sd


def official_forward(sd: dict[str, Tensor], x: Tensor, t: Tensor, text: Tensor, heads: int, layers: int) -> Tensor:
    """MDM trans_enc forward written out from the tensors, sequence-first like the official code."""
    lin = lambda h, name: F.linear(h, sd[name + ".weight"], sd[name + ".bias"])  # noqa: E731
    pe = sd["sequence_pos_encoder.pe"]  # (5000, 1, d)
    emb = lin(F.silu(lin(pe[t], "embed_timestep.time_embed.0")), "embed_timestep.time_embed.2").permute(1, 0, 2)
    emb = emb + lin(text, "embed_text")  # (1, B, d)
    frames = lin(x.permute(1, 0, 2), "input_process.poseEmbedding")  # (T, B, d)
    h = torch.cat([emb, frames], 0) + pe[: x.shape[1] + 1]  # (T+1, B, d)
    seq, batch, d = h.shape
    for i in range(layers):
        p = f"seqTransEncoder.layers.{i}."
        q, k, v = F.linear(h, sd[p + "self_attn.in_proj_weight"], sd[p + "self_attn.in_proj_bias"]).chunk(3, dim=-1)
        split = lambda z: z.reshape(seq, batch, heads, d // heads).permute(1, 2, 0, 3)  # noqa: E731
        att = torch.softmax(split(q) @ split(k).transpose(-1, -2) / math.sqrt(d // heads), dim=-1) @ split(v)
        att = lin(att.permute(2, 0, 1, 3).reshape(seq, batch, d), p + "self_attn.out_proj")
        h = F.layer_norm(h + att, (d,), sd[p + "norm1.weight"], sd[p + "norm1.bias"])
        ff = lin(F.gelu(lin(h, p + "linear1")), p + "linear2")
        h = F.layer_norm(h + ff, (d,), sd[p + "norm2.weight"], sd[p + "norm2.bias"])
    return lin(h[1:], "output_process.poseFinal").permute(1, 0, 2)  # (B, T, F)


def test_load_official_checkpoint_and_match_forward() -> None:
    sd = official_state_dict()
    model = MDM(MDMConfig.named("paper", text_dim=512))
    report = load_official_mdm_state_dict(model.eval(), sd)
    assert report.missing == () and report.unexpected == ()
    assert set(report.skipped) == {
        "clip_model.positional_embedding",
        "clip_model.token_embedding.weight",
        "sequence_pos_encoder.pe",
        "embed_timestep.sequence_pos_encoder.pe",
    }
    assert torch.equal(model.seqTransEncoder.layers[3].linear1.weight, sd["seqTransEncoder.layers.3.linear1.weight"])
    g = torch.Generator().manual_seed(3)
    x, text = torch.randn(2, 10, 263, generator=g), torch.randn(2, 512, generator=g)
    t = torch.tensor([0, 731])
    mask = torch.ones(2, 10, dtype=torch.bool)
    mask[1, 6:] = False
    with torch.no_grad():
        want = official_forward(sd, x, t, text, heads=4, layers=8)
        want_short = official_forward(sd, x[1:, :6], t[1:], text[1:], heads=4, layers=8)  # sample 1 cut to 6 frames
        got = model(x, t, text)
        got_masked = model(x, t, text, mask)
    assert torch.allclose(got, want, atol=1e-4), float((got - want).abs().max())
    assert torch.allclose(got_masked[0], want[0], atol=1e-4)
    assert torch.allclose(got_masked[1, :6], want_short[0], atol=1e-4)  # padding == the clip being shorter


def test_load_official_checkpoint_rejects_mismatch() -> None:
    sd = official_state_dict(d=64, ff=128, layers=2, text=384)
    model = tiny()
    wrapped = {"model_avg": sd}
    assert load_official_mdm_state_dict(model, wrapped).missing == ()
    bad = dict(sd)
    bad["embed_text.weight"] = torch.zeros(64, 512)
    with pytest.raises(MotionDataError, match="embed_text.weight"):
        load_official_mdm_state_dict(model, bad)
    extra = dict(sd) | {"some.other.weight": torch.zeros(1)}
    with pytest.raises(MotionDataError, match="unexpected"):
        load_official_mdm_state_dict(model, extra)
    report = load_official_mdm_state_dict(model, extra, strict=False)
    assert report.unexpected == ("some.other.weight",)
    partial = {k: v for k, v in sd.items() if not k.startswith("output_process")}
    assert set(load_official_mdm_state_dict(model, partial, strict=False).missing) == {
        "output_process.poseFinal.weight",
        "output_process.poseFinal.bias",
    }


# ---------------------------------------------------------------- device choice


def test_pick_device_follows_what_is_present(monkeypatch: pytest.MonkeyPatch) -> None:
    from motionaug.augment.device import bf16_autocast, pick_device

    monkeypatch.delenv("MOTIONAUG_DEVICE", raising=False)
    assert pick_device().type == ("cuda" if torch.cuda.is_available() else "cpu")
    monkeypatch.setenv("MOTIONAUG_DEVICE", "cpu")
    assert pick_device() == torch.device("cpu")
    if not torch.cuda.is_available():
        with pytest.raises(MotionDataError, match="'cuda'.*CUDA was asked for but torch sees no GPU"):
            pick_device("cuda")
    assert bf16_autocast(True).fast_dtype == torch.bfloat16 and not bf16_autocast(False)._enabled


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device: the GPU path is not exercised here")
def test_paper_mdm_runs_on_cuda_under_bf16_autocast() -> None:
    from motionaug.augment.device import bf16_autocast, pick_device

    device = pick_device()
    assert device.type == "cuda" and bf16_autocast(None, device)._enabled  # CUDA gets bf16 unless asked not to
    model = MDM(MDMConfig.named("paper", text_dim=512)).to(device).eval()
    x, text = torch.randn(4, 60, 263, device=device), torch.randn(4, 512, device=device)
    t = torch.tensor([0, 10, 500, 999], device=device)
    with torch.no_grad():
        ref = model(x, t, text)
        with bf16_autocast(None, device):
            low = model(x, t, text)
    assert low.dtype == torch.bfloat16 and float((low.float() - ref).norm() / ref.norm()) < 0.03
