"""LoRA adapters on MDM: identity at init, only adapters train, safetensors round trip, merge, artefact size."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file, save_file
from torch import Tensor, nn

from motionaug.models.lora import (
    LoRALinear,
    apply_lora,
    base_state_dict,
    count_lora_bytes,
    load_lora_state_dict,
    lora_state_dict,
    merge_lora,
)
from motionaug.models.mdm import MDM, MDMConfig
from motionaug.schemas.errors import MotionDataError

torch.set_num_threads(1)
FEATS, TEXT = 12, 16


def tiny_mdm(seed: int = 0) -> MDM:
    torch.manual_seed(seed)
    cfg = MDMConfig.named("tiny", n_feats=FEATS, text_dim=TEXT, dropout=0.0, cond_mask_prob=0.0, max_len=1100)
    return MDM(cfg)


def frozen_base() -> MDM:
    """The reference for bitwise comparisons: frozen like an adapted model's base, because ATen picks a
    different (equally exact, differently rounded) linear kernel when a weight requires grad."""
    return tiny_mdm().requires_grad_(False)


def batch(seed: int = 1) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    g = torch.Generator().manual_seed(seed)
    x = torch.randn(3, 8, FEATS, generator=g)
    t = torch.randint(0, 1000, (3,), generator=g)
    text = torch.randn(3, TEXT, generator=g)
    mask = torch.ones(3, 8, dtype=torch.bool)
    mask[1, 5:] = False
    return x, t, text, mask


def run(model: nn.Module, sdpa: bool, mask: bool = True) -> Tensor:
    """Eval forward through either attention kernel of ``models.attention.run_encoder``: SDPA (no gradients)
    or the plain matmul-softmax one (gradients on)."""
    x, t, text, m = batch()
    with torch.set_grad_enabled(not sdpa):
        return model.eval()(x, t, text, m if mask else None).detach()


def train_adapters(model: MDM, steps: int = 25) -> list[float]:
    """A toy regression: pull the output toward a fixed random target; returns the losses."""
    x, t, text, mask = batch()
    target = torch.randn(x.shape, generator=torch.Generator().manual_seed(9))
    params = [p for p in model.parameters() if p.requires_grad]
    opt = torch.optim.Adam(params, lr=1e-2)
    model.train()
    losses = []
    for _ in range(steps):
        loss = torch.nn.functional.mse_loss(model(x, t, text, mask), target)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    return losses


def trained_adapted(rank: int = 4) -> MDM:
    model = tiny_mdm()
    apply_lora(model, rank=rank, alpha=8)
    train_adapters(model, steps=5)
    return model


def test_lora_linear_equals_base_at_init_and_merges() -> None:
    torch.manual_seed(0)
    base = nn.Linear(10, 6)
    lora = LoRALinear(base, rank=3, alpha=6.0)
    x = torch.randn(4, 10)
    assert torch.equal(lora(x), base(x))
    assert not base.weight.requires_grad and lora.lora_A.requires_grad and lora.lora_B.requires_grad
    with torch.no_grad():
        lora.lora_B.normal_()
    assert not torch.allclose(lora(x), base(x))
    torch.testing.assert_close(lora.merged()(x), lora(x), rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(torch.nn.functional.linear(x, lora.weight, lora.bias), lora(x), rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("rank", [0, 7])
def test_bad_rank_is_a_clear_error(rank: int) -> None:
    with pytest.raises(MotionDataError, match="LoRA rank"):
        LoRALinear(nn.Linear(6, 4), rank=rank)


def test_apply_lora_names_and_identity_at_init_on_both_kernels() -> None:
    base = frozen_base()
    model = tiny_mdm()
    names = apply_lora(model, rank=4)
    assert len(names) == 2 * 4  # 2 layers x (in_proj, out_proj, linear1, linear2)
    assert "seqTransEncoder.layers.0.self_attn.in_proj_weight" in names
    assert "seqTransEncoder.layers.1.linear2" in names
    for fast in (True, False):
        assert torch.equal(run(model, fast), run(base, fast))
    with pytest.raises(MotionDataError, match="already has LoRA"):
        apply_lora(model)
    with pytest.raises(MotionDataError, match="no Linear or MultiheadAttention"):
        apply_lora(tiny_mdm(), targets=("nothing_here",))


def test_both_attention_kernels_see_the_adapters() -> None:
    model = trained_adapted()
    with torch.profiler.profile() as prof:
        fast = run(model, sdpa=True, mask=False)
    assert any("scaled_dot_product" in e.name for e in prof.events())  # the SDPA kernel ran
    slow = run(model, sdpa=False, mask=False)
    torch.testing.assert_close(fast, slow, rtol=1e-4, atol=1e-4)
    assert not torch.allclose(slow, run(tiny_mdm(), sdpa=False, mask=False), atol=1e-4)  # adapters changed it
    torch.testing.assert_close(run(model, True), run(model, False), rtol=1e-4, atol=1e-4)  # padded batch too


def test_training_moves_only_adapters_and_lowers_loss() -> None:
    model = tiny_mdm()
    before = {k: v.clone() for k, v in model.state_dict().items()}
    apply_lora(model, rank=4, alpha=8)
    trainable = {n for n, p in model.named_parameters() if p.requires_grad}
    assert trainable and all(n.rpartition(".")[2] in ("lora_A", "lora_B") for n in trainable)
    losses = train_adapters(model, steps=25)
    assert losses[-1] < 0.8 * losses[0]
    after = base_state_dict(model)
    assert set(after) == set(before)
    assert all(torch.equal(after[k], before[k]) for k in before)
    assert any(v.abs().sum() > 0 for k, v in lora_state_dict(model).items() if k.endswith("lora_B"))
    grads = [p.grad for n, p in model.named_parameters() if not p.requires_grad]
    assert all(g is None for g in grads)


def test_a_seeded_generator_makes_the_adapters_independent_of_the_global_rng() -> None:
    states = []
    for global_seed in (1, 2):
        model = tiny_mdm()
        torch.manual_seed(global_seed)  # what ran before in a worker must not change the artefact
        apply_lora(model, rank=2, alpha=4.0, generator=torch.Generator().manual_seed(7))
        states.append(lora_state_dict(model))
    assert states[0].keys() == states[1].keys() and len(states[0]) > 0
    assert all(torch.equal(states[0][k], states[1][k]) for k in states[0])
    unseeded = tiny_mdm()
    apply_lora(unseeded, rank=2, alpha=4.0)
    assert any(not torch.equal(v, lora_state_dict(unseeded)[k]) for k, v in states[0].items())


def test_safetensors_round_trip_into_a_fresh_model(tmp_path: Path) -> None:
    model = trained_adapted()
    state = lora_state_dict(model)
    assert all(k.rpartition(".")[2].startswith("lora_") for k in state)
    save_file(state, tmp_path / "style.safetensors")
    fresh = tiny_mdm()
    apply_lora(fresh, rank=4, alpha=8)
    load_lora_state_dict(fresh, load_file(tmp_path / "style.safetensors"))
    assert torch.equal(run(fresh, False), run(model, False))
    assert count_lora_bytes(fresh) == sum(t.numel() * t.element_size() for t in state.values())


def test_loading_mismatched_adapters_is_a_clear_error() -> None:
    state = lora_state_dict(trained_adapted(rank=4))
    other = tiny_mdm()
    apply_lora(other, rank=2)
    with pytest.raises(MotionDataError, match="shape"):
        load_lora_state_dict(other, state)
    partial = tiny_mdm()
    apply_lora(partial, rank=4, targets=("linear1",))
    with pytest.raises(MotionDataError, match="keys differ"):
        load_lora_state_dict(partial, state)
    with pytest.raises(MotionDataError, match="call apply_lora first"):
        load_lora_state_dict(tiny_mdm(), state)


def test_merge_equals_unmerged_and_restores_plain_keys() -> None:
    model = trained_adapted()
    unmerged = run(model, False)
    merged = merge_lora(model)
    assert not any(isinstance(m, LoRALinear) for m in merged.modules())
    assert set(merged.state_dict()) == set(tiny_mdm().state_dict())
    torch.testing.assert_close(run(merged, False), unmerged, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(run(merged, True), unmerged, rtol=1e-4, atol=1e-4)


def test_other_targets_wrap_linears_inside_containers() -> None:
    model = tiny_mdm()
    names = apply_lora(model, rank=2, targets=("time_embed", "poseFinal"))
    assert names == ["embed_timestep.time_embed.0", "embed_timestep.time_embed.2", "output_process.poseFinal"]
    assert torch.equal(run(model, False), run(frozen_base(), False))


def test_small_config_adapters_under_five_percent() -> None:
    torch.manual_seed(0)
    model = MDM(MDMConfig.named("small"))
    full = sum(t.numel() * t.element_size() for t in model.state_dict().values())
    apply_lora(model, rank=8)
    fraction = count_lora_bytes(model) / full
    assert 0.01 < fraction <= 0.05, fraction
