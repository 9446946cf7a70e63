"""The compute device: base models moved once, samplers run where their inputs are, seeded draws stay on CPU.

Every test runs on CPU; the same checks run on CUDA where a GPU is present (else they skip, "no CUDA device").
The on-the-fly method end to end on each device is in tests/test_onthefly.py.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from torch import nn

from motionaug.augment.diffusion import InpaintSpec, ddim_sample, ddpm_sample
from motionaug.augment.methods.common import module_device, place_models, seeded_generator
from motionaug.augment.motion.features import compute_mean_std
from motionaug.augment.training.base_models import BaseModels, BaseModelsInfo, config_dict
from motionaug.models.lora import apply_lora, lora_state_dict
from motionaug.models.mdm import MDM, MDMConfig
from motionaug.models.motion_encoder import MotionEncoder, MotionEncoderConfig

ROOT = Path(__file__).resolve().parent.parent
DEVICES = [
    "cpu",
    pytest.param("cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")),
]


def tiny_base() -> BaseModels:
    torch.manual_seed(0)
    prior_cfg, enc_cfg = MDMConfig.named("tiny", dropout=0.0), MotionEncoderConfig.named("tiny")
    info = BaseModelsInfo(size="tiny", max_frames=60, prior=config_dict(prior_cfg), motion_encoder=config_dict(enc_cfg))
    motions = [torch.randn(40, 263).numpy() for _ in range(3)]
    return BaseModels(info, MDM(prior_cfg), MotionEncoder(enc_cfg), compute_mean_std(motions)).eval()


def test_module_device_is_where_the_weights_are() -> None:
    assert module_device(nn.Linear(2, 2)) == torch.device("cpu")
    assert module_device(nn.ReLU()) == torch.device("cpu")  # no weights: CPU
    assert module_device(nn.Linear(2, 2).to("meta")) == torch.device("meta")


@pytest.mark.parametrize("device", DEVICES)
def test_place_models_moves_every_network(device: str) -> None:
    base = place_models(tiny_base(), torch.device(device))
    for name, module in base.modules().items():
        assert {t.device.type for t in [*module.parameters(), *module.buffers()]} == {device}, name


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("sampler", [ddpm_sample, ddim_sample])
def test_samplers_run_where_x_start_is_and_draw_seeded_noise_on_cpu(device: str, sampler) -> None:
    """A seed means the same noise on every device: the sampler's own draws equal CPU draws from that seed."""
    base = place_models(tiny_base(), torch.device(device))
    x = torch.randn(2, 30, 263, generator=seeded_generator(1)).to(device)
    mask = torch.ones(2, 30, dtype=torch.bool, device=device)
    text = torch.randn(2, base.prior.config.text_dim, generator=seeded_generator(2)).to(device)
    kw = {"steps": 10, "start_step": 4, "x_start": x, "inpaint": InpaintSpec(x, [0, 1, 2], frames=mask)}
    if sampler is ddim_sample:
        kw["eta"] = 1.0  # draws noise at every step, as DDPM does

    def model_fn(x_t: torch.Tensor, t: torch.Tensor, *, uncond: bool = False) -> torch.Tensor:
        return base.prior(x_t, t, text, mask, force_uncond=uncond)

    drawn = sampler(model_fn, x.shape, generator=seeded_generator(3), **kw)
    assert drawn.device.type == device and torch.isfinite(drawn).all()
    assert torch.equal(drawn[..., :3], x[..., :3])  # inpainted channels are the reference's, bit for bit
    cpu_draws = seeded_generator(3)
    given = sampler(model_fn, x.shape, noise=torch.randn(x.shape, generator=cpu_draws), generator=cpu_draws, **kw)
    assert torch.equal(given, drawn)


@pytest.mark.parametrize("device", DEVICES)
def test_lora_init_from_a_cpu_generator_is_the_same_on_every_device(device: str) -> None:
    cpu, here = MDM(MDMConfig.named("tiny")), MDM(MDMConfig.named("tiny")).to(device)
    for model in (cpu, here):
        apply_lora(model, 2, 2.0, generator=seeded_generator(5))
    mine, theirs = lora_state_dict(here), lora_state_dict(cpu)
    assert set(mine) == set(theirs) and len(mine) > 0
    for key, value in theirs.items():
        assert mine[key].device.type == device and torch.equal(mine[key].cpu(), value), key


@pytest.mark.skipif(torch.cuda.is_available(), reason="CUDA present: the benchmark would run, not skip")
def test_gpu_benchmark_says_it_was_skipped_without_cuda() -> None:
    env = {k: v for k, v in os.environ.items() if k != "MOTIONAUG_DEVICE"}
    done = subprocess.run(
        [sys.executable, str(ROOT / "bench" / "bench_gpu.py")], capture_output=True, text=True, env=env, timeout=120
    )
    assert done.returncode == 0, done.stderr
    assert "bench_gpu: skipped: no CUDA device" in done.stdout


def test_a_device_that_cannot_be_used_is_a_one_line_error(monkeypatch: pytest.MonkeyPatch) -> None:
    from motionaug.augment.device import DEVICE_ENV, pick_device
    from motionaug.schemas.errors import MotionDataError

    monkeypatch.setenv(DEVICE_ENV, "bogus")
    with pytest.raises(MotionDataError, match=r"MOTIONAUG_DEVICE.*not a torch device"):
        pick_device()
    if not torch.cuda.is_available():
        with pytest.raises(MotionDataError, match="no GPU"):
            pick_device("cuda")
