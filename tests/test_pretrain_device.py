"""Pre-training on the chosen device: CPU as it always was, CUDA (where present) from the same seeded draws.

The CUDA tests skip without a GPU ("no CUDA device"). Equality on CPU is bit for bit; on CUDA the first step's
loss matches CPU's to 1% (same initial weights, batch and noise, all drawn on CPU; a wrong draw is off by far more),
later ones drift with kernel order.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

from motionaug.augment.device import DEVICE_ENV
from motionaug.augment.synth import generate_corpus
from motionaug.augment.training.pretrain import CHECKPOINTS, LOSS_LOG, PretrainConfig, pretrain
from motionaug.models.text_encoder import make_text_encoder
from motionaug.schemas.errors import MotionDataError

MODULES = ("prior", "motion_encoder", "evaluators/content_classifier", "evaluators/style_classifier")
needs_cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")


class Interrupt(Exception):
    """Raised from the progress callback to stop a run mid-stage."""


def config(**overrides: object) -> PretrainConfig:
    defaults = {
        "prior_steps": 6,
        "encoder_steps": 4,
        "classifier_epochs": 1,
        "checkpoint_every": 3,
        "threads": 1,
        "log_every": 1,
        "bf16": False,
        "max_frames": 60,
    }
    return PretrainConfig.for_size("tiny", **{**defaults, **overrides})


@pytest.fixture(scope="module")
def text_encoder():
    return make_text_encoder("minilm")


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("pretrain_device") / "corpus"
    generate_corpus(root, 24, seed=0)
    return root


def weights(out: Path) -> dict[str, dict[str, torch.Tensor]]:
    return {name: load_file(str(out / f"{name}.safetensors")) for name in MODULES}


def first_loss(out: Path, stage: str) -> float:
    rows = [json.loads(line) for line in (out / LOSS_LOG).read_text(encoding="utf-8").splitlines()]
    return next(r["loss"] for r in rows if r["stage"] == stage and r["step"] == 1)


def checkpoint_tensors(out: Path) -> list[torch.Tensor]:
    """Every tensor of every stage's optimizer/RNG state, loaded without moving anything."""
    found: list[torch.Tensor] = []

    def walk(value: object) -> None:
        if isinstance(value, torch.Tensor):
            found.append(value)
        elif isinstance(value, dict):
            for item in value.values():
                walk(item)
        elif isinstance(value, list | tuple):
            for item in value:
                walk(item)

    for path in (out / CHECKPOINTS).glob("*/step_*/state.pt"):
        walk(torch.load(path, weights_only=True))
    return found


def test_device_from_the_environment_trains_the_weights_of_an_explicit_device(
    corpus: Path, text_encoder, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``MOTIONAUG_DEVICE=cpu`` is the same run as ``device=cpu``, and, without CUDA, as the default."""
    monkeypatch.setenv(DEVICE_ENV, "cpu")
    pretrain(corpus, tmp_path / "env", config(), text_encoder=text_encoder)
    monkeypatch.delenv(DEVICE_ENV)
    chosen = None if not torch.cuda.is_available() else torch.device("cpu")
    pretrain(corpus, tmp_path / "arg", config(), text_encoder=text_encoder, device=chosen)
    env, arg = weights(tmp_path / "env"), weights(tmp_path / "arg")
    for name in MODULES:
        assert env[name].keys() == arg[name].keys()
        assert all(torch.equal(env[name][k], arg[name][k]) for k in env[name]), name
    assert all(t.device.type == "cpu" for t in checkpoint_tensors(tmp_path / "env"))


@pytest.mark.skipif(torch.cuda.is_available(), reason="a CUDA device is present")
def test_cuda_asked_for_without_a_gpu_is_refused_before_training(
    corpus: Path, text_encoder, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv(DEVICE_ENV, "cuda")
    with pytest.raises(MotionDataError, match="CUDA was asked for but torch sees no GPU"):
        pretrain(corpus, tmp_path / "out", config(), text_encoder=text_encoder)
    assert not (tmp_path / "out" / LOSS_LOG).exists()


@needs_cuda
def test_cuda_pretrain_starts_from_the_cpu_draws_and_saves_cpu_weights(
    corpus: Path, text_encoder, tmp_path: Path
) -> None:
    cpu, gpu = tmp_path / "cpu", tmp_path / "cuda"
    pretrain(corpus, cpu, config(), text_encoder=text_encoder, device=torch.device("cpu"))
    pretrain(corpus, gpu, config(), text_encoder=text_encoder, device=torch.device("cuda"))
    for stage in ("prior", "motion_encoder"):  # same init, batch and noise: only kernel rounding differs
        assert first_loss(gpu, stage) == pytest.approx(first_loss(cpu, stage), rel=1e-2), stage
    saved = weights(gpu)
    assert all(t.device.type == "cpu" and bool(torch.isfinite(t).all()) for m in saved.values() for t in m.values())
    assert all(t.device.type == "cpu" for t in checkpoint_tensors(gpu))


@needs_cuda
def test_cuda_run_with_bf16_autocast_resumes_on_the_gpu(corpus: Path, text_encoder, tmp_path: Path) -> None:
    """bf16 autocast on (the CUDA default) and a stop mid-prior: the resumed run loads its checkpoint onto the GPU."""
    out, cfg = tmp_path / "out", config(bf16=None)

    def stop(stage: str, step: int, total: int, metrics: dict[str, float]) -> None:
        if (stage, step) == ("prior", 4):
            raise Interrupt

    with pytest.raises(Interrupt):
        pretrain(corpus, out, cfg, progress=stop, text_encoder=text_encoder, device=torch.device("cuda"))
    info = pretrain(corpus, out, cfg, text_encoder=text_encoder, device=torch.device("cuda"))
    assert info is not None and all(torch.isfinite(t).all() for t in weights(out)["prior"].values())
    rows = [json.loads(line) for line in (out / LOSS_LOG).read_text(encoding="utf-8").splitlines()]
    steps = [r["step"] for r in rows if r["stage"] == "prior" and "loss" in r]
    assert steps == [1, 2, 3, 4, 4, 5, 6]  # stopped after step 4, resumed from the step-3 checkpoint
