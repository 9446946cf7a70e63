"""On-the-fly style transfer (Hu et al. 2024): pairs, fine-tuning, transfer, LoRA artefacts, example validation.

Everything runs on tiny random base models and a handful of short synthetic clips so the file stays fast on
2 shared cores. Captions are embedded by a small hashing bag-of-words encoder (a real ``TextEncoder``; MiniLM
would cost seconds to load and is tested elsewhere).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.torch import load_file, save_file

from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.corpus.rejects import Reject
from motionaug.augment.corpus.style_examples import load_style_examples
from motionaug.augment.diffusion import start_step_for
from motionaug.augment.methods.base import ARTIFACT_JSON, ARTIFACT_WEIGHTS
from motionaug.augment.methods.hooks import LossBatch, LossTerm, SamplerCallback, loss_terms, sampler_callbacks
from motionaug.augment.methods.hooks import SamplerStep as HookStep
from motionaug.augment.methods.onthefly import (
    ContentPool,
    MotionBatch,
    OnTheFlyMethod,
    OnTheFlyModel,
    WeightAverage,
    finetune,
    kept_channels,
    make_pairs,
    neutral_twins,
    parse_params,
    resolve_tempo,
    style_vocab,
    trajectory_channels,
)
from motionaug.augment.methods.registry import method_class
from motionaug.augment.motion.features import compute_mean_std
from motionaug.augment.motion.foot_lock import lock_feet
from motionaug.augment.motion.tempo import retime
from motionaug.augment.outputs.shards import TransferOutput
from motionaug.augment.synth import STYLE_WORDS, sample_spec
from motionaug.augment.synth.corpus import spec_to_clip
from motionaug.augment.training.base_models import BaseModels, BaseModelsInfo, config_dict
from motionaug.models.mdm import MDM, MDMConfig
from motionaug.models.motion_encoder import MotionEncoder, MotionEncoderConfig
from motionaug.schemas.captions import Caption
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.styles import StyleExample, StyleSpec, StyleWords

torch.set_num_threads(1)
FRAMES = 40
FIXTURES = Path(__file__).resolve().parent / "fixtures"
PROUD = StyleWords(adjective="proud", adverb="proudly", phrases=("in a proud way", "with pride"))


class HashTextEncoder:
    """Bag of hashed words -> unit vector: deterministic, instant, and different captions differ."""

    def __init__(self, dim: int = 384) -> None:
        self._dim = dim

    @property
    def dim(self) -> int:
        return self._dim

    def encode(self, texts: list[str]) -> torch.Tensor:
        out = torch.zeros(len(texts), self._dim)
        for i, text in enumerate(texts):
            for word in text.lower().replace(".", " ").split():
                out[i, int(hashlib.md5(word.encode()).hexdigest(), 16) % self._dim] += 1.0
        return torch.nn.functional.normalize(out, dim=-1)


def synth_clip(content: str, style: str, seed: int, clip_id: str, frames: int = FRAMES) -> MotionClip:
    spec = sample_spec(np.random.default_rng(seed), content, style, seed=seed)
    clip = spec_to_clip(spec, clip_id)
    clip.motion = clip.motion[:frames].copy()
    return clip


@pytest.fixture(scope="module")
def clips() -> dict[str, MotionClip]:
    made = {
        "proud_walk": synth_clip("walk", "proud", 1, "ex0"),
        "walk": synth_clip("walk", "neutral", 2, "c0"),
        "kick": synth_clip("kick", "neutral", 3, "c1", frames=32),
        "squat": synth_clip("squat", "neutral", 4, "c2", frames=36),
        "angry_run": synth_clip("run", "angry", 5, "c3"),
    }
    made["proud_walk_neutral"] = synth_clip("walk", "neutral", 1, "ex0n")  # same spec, neutral style
    return made


@pytest.fixture(scope="module")
def base_dir(tmp_path_factory: pytest.TempPathFactory, clips: dict[str, MotionClip]) -> Path:
    """Tiny random base models whose Mean/Std come from the test clips."""
    torch.manual_seed(0)
    prior_cfg = MDMConfig.named("tiny", dropout=0.0)
    enc_cfg = MotionEncoderConfig.named("tiny")
    info = BaseModelsInfo(
        size="tiny", max_frames=196, prior=config_dict(prior_cfg), motion_encoder=config_dict(enc_cfg)
    )
    base = BaseModels(
        info=info,
        prior=MDM(prior_cfg),
        motion_encoder=MotionEncoder(enc_cfg),
        normalizer=compute_mean_std([c.motion for c in clips.values()]),
    )
    return base.save(tmp_path_factory.mktemp("base"))


@pytest.fixture(scope="module")
def base(base_dir: Path) -> BaseModels:
    return BaseModels.load(base_dir, text_encoder=HashTextEncoder())


def proud_spec(source: str = "ex0", description: str = "a person walks forward proudly") -> StyleSpec:
    return StyleSpec(name="proud", words=PROUD, examples=[StyleExample(source=source, description=description)])


# fp32: bf16 autocast (the default where the CPU has it) rounds differently with the batch size and padding
FAST = {"pair_steps": 20, "ddim_steps": 20, "batch_size": 4, "lr": 1e-3, "bf16": False}


# ---- parameters ---------------------------------------------------------------------------------------------


def test_params_reject_bad_values_naming_the_field() -> None:
    assert parse_params().transfer_noise_step == 300
    with pytest.raises(MotionDataError, match="transfer_noise_step"):
        parse_params(transfer_noise_step=0)
    with pytest.raises(MotionDataError, match="pair_noise_step"):
        parse_params(pair_noise_step=1001)
    with pytest.raises(MotionDataError, match="lerning_rate"):
        parse_params({"lerning_rate": 0.1})
    with pytest.raises(MotionDataError, match="lambda_rec"):
        parse_params(lambda_rec=0.0, lambda_s=0.0)
    with pytest.raises(MotionDataError, match="batch_size"):
        OnTheFlyMethod({"batch_size": 0})
    with pytest.raises(MotionDataError, match="tempo"):
        parse_params(tempo=9.0)
    with pytest.raises(MotionDataError, match="tempo"):
        parse_params(tempo="fast")
    assert parse_params(tempo=0.8).tempo == 0.8 and parse_params().tempo == "example"
    with pytest.raises(MotionDataError, match="ema_decay"):
        parse_params(ema_decay=1.0)
    with pytest.raises(MotionDataError, match="lora_targets"):
        parse_params(lora_rank=4, lora_targets=[])
    with pytest.raises(MotionDataError, match="style_guidance"):
        parse_params(style_guidance=0.0)


def test_trajectory_channels_are_the_root_blocks() -> None:
    assert trajectory_channels("horizontal") == [0, 1, 2]
    assert trajectory_channels("root") == [0, 1, 2, 3]


# ---- pair generation ----------------------------------------------------------------------------------------


def test_neutral_twin_keeps_trajectory_channels_exactly(base: BaseModels, clips: dict[str, MotionClip]) -> None:
    params = parse_params(FAST, trajectory="root")
    batch = MotionBatch.from_motions([clips["proud_walk"].motion, clips["kick"].motion], base)
    embed = base.text_encoder.encode(["a person walks forward", "a person kicks"])
    twins = neutral_twins(base.prior, batch, embed, params, torch.Generator().manual_seed(0))
    channels = trajectory_channels("root")
    for i, n in enumerate(batch.lengths):
        assert torch.equal(twins[i, :n, channels], batch.x[i, :n, channels])
        other = [c for c in range(twins.shape[2]) if c not in channels]
        assert not torch.allclose(twins[i, :n, other], batch.x[i, :n, other], atol=1e-2)  # the rest was regenerated
    assert torch.isfinite(twins[0]).all()


# ---- fine-tuning ----------------------------------------------------------------------------------------------


def test_finetune_lowers_reconstruction_loss(base: BaseModels, clips: dict[str, MotionClip]) -> None:
    params = parse_params(FAST, lambda_s=0.0, max_steps=40, lr=2e-3)
    generator = torch.Generator().manual_seed(0)
    pairs = make_pairs(base, [clips["proud_walk"]], params, generator, STYLE_WORDS)
    calls: list[tuple[int, int]] = []
    fit = finetune(base, pairs, ContentPool([], []), params, progress=lambda i, n, m: calls.append((i, n)))
    losses = [r["l_rec"] for r in fit.curve]
    assert len(losses) == 40 and calls[0] == (1, 40) and calls[-1] == (40, 40)
    assert np.mean(losses[-5:]) < 0.5 * np.mean(losses[:5])
    prior_weight = base.prior.output_process.poseFinal.weight
    assert not torch.equal(fit.model.output_process.poseFinal.weight, prior_weight)  # a copy was trained
    assert not prior_weight.requires_grad  # the prior itself stays frozen and untouched


def test_transfer_moves_content_toward_the_example(base: BaseModels, clips: dict[str, MotionClip]) -> None:
    """After learning one proud walk, a neutral walk's pose statistics come closer to the example's."""
    example, content = clips["proud_walk"], clips["proud_walk_neutral"]
    method = OnTheFlyMethod(parse_params(FAST, lambda_s=0.0, max_steps=60, lr=2e-3), text_encoder=HashTextEncoder())
    model, fit, _, _ = method.fit(proud_spec(), [example], base, corpus=[])
    (out,) = model.transfer([content])
    assert isinstance(out, TransferOutput)
    pose = slice(4, 263)  # everything but the trajectory

    def distance(motion: np.ndarray) -> float:
        a = base.normalizer.normalize(motion)[:, pose].mean(axis=0)
        b = base.normalizer.normalize(example.motion)[:, pose].mean(axis=0)
        return float(np.linalg.norm(a - b))

    assert distance(out.motion) < 0.7 * distance(content.motion)
    np.testing.assert_array_equal(out.motion[:, :3], content.motion[:, :3])  # the content's path is kept
    assert {"style_score", "content_score", "foot_skating"} <= set(out.scores)
    assert any("proud" in c.text for c in out.captions)


def test_style_guidance_contrasts_the_tuned_model_with_the_base_prior(
    base: BaseModels, clips: dict[str, MotionClip]
) -> None:
    """w = 1 is the tuned model alone; w = 0 is the base prior alone (the same whatever the fine-tune learnt)."""
    example, content = clips["proud_walk"], clips["proud_walk_neutral"]

    def transfer(max_steps: int, w: float | None) -> np.ndarray:
        method = OnTheFlyMethod(
            parse_params(FAST, lambda_s=0.0, max_steps=max_steps, lr=2e-3), text_encoder=HashTextEncoder()
        )
        model, _, _, _ = method.fit(proud_spec(), [example], base, corpus=[])
        model.params = model.params.model_copy(update={"style_guidance": w})  # a transfer-time knob
        (out,) = model.transfer([content])
        assert isinstance(out, TransferOutput)
        np.testing.assert_array_equal(out.motion[:, :3], content.motion[:, :3])  # the path is kept
        return out.motion

    plain = transfer(20, None)
    np.testing.assert_allclose(transfer(20, 1.0), plain, atol=1e-6)
    assert not np.allclose(transfer(20, 1.5), plain, atol=1e-3)
    np.testing.assert_allclose(transfer(2, 0.0), transfer(20, 0.0), atol=1e-5)


def test_foot_lock_rewrites_only_the_root_path_of_the_output(base: BaseModels, clips: dict[str, MotionClip]) -> None:
    method = OnTheFlyMethod(parse_params(FAST, lambda_s=0.0, max_steps=2), text_encoder=HashTextEncoder())
    model, _, _, _ = method.fit(proud_spec(), [clips["proud_walk"]], base, corpus=[])
    (plain,) = model.transfer([clips["walk"]])
    model.params = model.params.model_copy(update={"foot_lock": True})
    (locked,) = model.transfer([clips["walk"]])
    assert isinstance(plain, TransferOutput) and isinstance(locked, TransferOutput)
    np.testing.assert_array_equal(locked.motion, lock_feet(plain.motion))  # the post-process, nothing else
    np.testing.assert_array_equal(locked.motion[:, 4:193], plain.motion[:, 4:193])  # poses untouched


@sampler_callbacks.register("test-halve-x0")
class HalveX0(SamplerCallback):
    """Halves every x0 prediction and counts its calls: a stand-in for a lab sampler callback."""

    calls = 0

    def __call__(self, step: HookStep) -> torch.Tensor:
        HalveX0.calls += 1
        assert step.x0.shape == step.x_t.shape and step.mask.shape == step.x0.shape[:2]
        return step.x0 * 0.5


def test_sampler_callbacks_reach_on_the_flys_transfer(base: BaseModels, clips: dict[str, MotionClip]) -> None:
    """The hooks family UMSD uses plugs into on-the-fly's sampler too: no callback, the same bytes as before."""
    method = OnTheFlyMethod(parse_params(FAST, lambda_s=0.0, max_steps=2), text_encoder=HashTextEncoder())
    model, _, _, _ = method.fit(proud_spec(), [clips["proud_walk"]], base, corpus=[])
    (plain,) = model.transfer([clips["walk"]], seed=3)
    hooked = OnTheFlyModel(
        proud_spec(), base, model.model, model.params.model_copy(update={"callbacks": ["test-halve-x0"]})
    )
    (halved,) = hooked.transfer([clips["walk"]], seed=3)
    steps = start_step_for(model.params.transfer_noise_step, model.params.ddim_steps)
    assert isinstance(plain, TransferOutput) and isinstance(halved, TransferOutput)
    assert HalveX0.calls == steps and not np.allclose(halved.motion, plain.motion, atol=1e-3)
    (again,) = model.transfer([clips["walk"]], seed=3)
    np.testing.assert_array_equal(again.motion, plain.motion)


def test_inpaint_feet_keeps_the_contents_foot_contacts(base: BaseModels, clips: dict[str, MotionClip]) -> None:
    method = OnTheFlyMethod(
        parse_params(FAST, lambda_s=0.0, max_steps=2, inpaint_feet=True), text_encoder=HashTextEncoder()
    )
    model, _, _, _ = method.fit(proud_spec(), [clips["proud_walk"]], base, corpus=[])
    content = clips["walk"]
    (out,) = model.transfer([content])
    assert isinstance(out, TransferOutput)
    kept = kept_channels(model.params)
    assert kept[-4:] == list(range(259, 263))  # the four foot-contact channels of the t2m layout
    np.testing.assert_array_equal(out.motion[:, kept], content.motion[:, kept])
    assert not np.array_equal(out.motion, content.motion)  # the rest was transferred


def test_the_params_seed_is_used_unless_the_caller_gives_one(base: BaseModels, clips: dict[str, MotionClip]) -> None:
    def curve(params_seed: int, seed: int | None) -> list[float]:
        method = OnTheFlyMethod(
            parse_params(FAST, lambda_s=0.0, max_steps=3, seed=params_seed), text_encoder=HashTextEncoder()
        )
        _, fit, _, _ = method.fit(proud_spec(), [clips["proud_walk"]], base, corpus=[], seed=seed)
        return [r["l_rec"] for r in fit.curve]

    assert curve(1, None) == curve(0, 1) != curve(0, None)


def test_semantic_loss_runs_on_the_corpus_and_is_recorded(base: BaseModels, clips: dict[str, MotionClip]) -> None:
    corpus = [clips["walk"], clips["kick"], clips["squat"], clips["angry_run"]]
    method = OnTheFlyMethod(
        parse_params(FAST, batch_size=2, styled_corpus="neutralise"), text_encoder=HashTextEncoder()
    )
    model, fit, pool, skipped = method.fit(proud_spec(), [clips["proud_walk"]], base, corpus)
    assert len(fit.curve) == 2  # one pass over 4 clips in batches of 2
    assert len(pool) == 4 and skipped == 0  # the angry run was neutralised, not dropped
    assert all(0.0 < r["l_s"] < 2.0 for r in fit.curve)
    assert all(any("proud" in c for c in caps) for caps in pool.captions)
    skipping = OnTheFlyMethod(parse_params(FAST, batch_size=2, max_steps=1), text_encoder=HashTextEncoder())
    _, _, pool, skipped = skipping.fit(proud_spec(), [clips["proud_walk"]], base, corpus)
    assert len(pool) == 3 and skipped == 1  # default: styled corpus clips stay out of the pool


# ---- transfer batches, artefacts ---------------------------------------------------------------------------


def test_batch_with_bad_clips_rejects_only_them(base: BaseModels, clips: dict[str, MotionClip]) -> None:
    method = OnTheFlyMethod(parse_params(FAST, lambda_s=0.0, max_steps=1), text_encoder=HashTextEncoder())
    model, _, _, _ = method.fit(proud_spec(), [clips["proud_walk"]], base, corpus=[])
    nan = clips["walk"].motion.copy()
    nan[5, 10] = np.nan
    batch = [
        clips["walk"],
        MotionClip(id="bad-nan", motion=nan, captions=clips["walk"].captions),
        clips["kick"],
        MotionClip(id="bad-width", motion=np.zeros((30, 251), np.float32), captions=[]),
        MotionClip(id="bad-short", motion=clips["walk"].motion[:5], captions=[]),
        clips["angry_run"],
    ]
    results = model.transfer(batch, seed=3)
    assert [type(r) for r in results] == [TransferOutput, Reject, TransferOutput, Reject, Reject, TransferOutput]
    assert [r.id for r in results if isinstance(r, Reject)] == ["bad-nan", "bad-width", "bad-short"]
    assert "NaN" in results[1].reason and "width" in results[3].reason and "short" in results[4].reason
    outputs = [r for r in results if isinstance(r, TransferOutput)]
    assert [o.motion.shape for o in outputs] == [(FRAMES, 263), (32, 263), (FRAMES, 263)]
    assert all(np.isfinite(o.motion).all() for o in outputs)
    alone = model.transfer([clips["kick"]], seed=3)[0]  # per-clip noise: batch mates do not change a clip
    np.testing.assert_allclose(alone.motion, outputs[1].motion, atol=1e-4)


def test_lora_artifact_round_trip_gives_identical_transfers(
    base: BaseModels, base_dir: Path, clips: dict[str, MotionClip], tmp_path: Path
) -> None:
    params = parse_params(FAST, lambda_s=0.0, max_steps=4, lora_rank=2)
    method = OnTheFlyMethod(params, text_encoder=HashTextEncoder())
    model, fit, pool, skipped = method.fit(proud_spec(), [clips["proud_walk"]], base, corpus=[])
    prepared = method.save(tmp_path / "style=proud", base_dir, model, fit, pool, skipped)
    out_dir = prepared.folder
    info = json.loads((out_dir / ARTIFACT_JSON).read_text())
    assert info["method"] == "onthefly" and info["weights"] == "lora"
    assert info["weights_bytes"] <= 0.05 * info["full_model_bytes"]
    assert (out_dir / ARTIFACT_WEIGHTS).stat().st_size <= 0.05 * info["full_model_bytes"] + 4096
    assert len(info["loss_curve"]) == 4 and "timings" not in info  # wall-clock facts stay out of the artefact
    assert "finetune_s" in prepared.timings  # the prepare stage writes them to TIMINGS_FILE
    loaded = method.load(out_dir, base_dir)
    content = [clips["walk"], clips["kick"]]
    before, after = model.transfer(content, seed=1), loaded.transfer(content, seed=1)
    for a, b in zip(before, after):
        np.testing.assert_array_equal(a.motion, b.motion)
    merged = method.load_tuned(out_dir, base_dir, merge=True).transfer(content, seed=1)
    for a, b in zip(before, merged):
        np.testing.assert_allclose(a.motion, b.motion, atol=1e-3)


def test_lora_biases_are_trained_stored_and_reloaded(
    base: BaseModels, base_dir: Path, clips: dict[str, MotionClip], tmp_path: Path
) -> None:
    params = parse_params(FAST, lambda_s=0.0, max_steps=4, lora_rank=2, lora_biases=True)
    method = OnTheFlyMethod(params, text_encoder=HashTextEncoder())
    model, fit, pool, skipped = method.fit(proud_spec(), [clips["proud_walk"]], base, corpus=[])
    out_dir = method.save(tmp_path / "style=proud", base_dir, model, fit, pool, skipped).folder
    stored = load_file(str(out_dir / ARTIFACT_WEIGHTS))
    output_bias = "output_process.poseFinal.bias"
    assert output_bias in stored and "seqTransEncoder.layers.0.linear1.base.bias" in stored
    assert not torch.equal(stored[output_bias], base.prior.output_process.poseFinal.bias)  # trained
    info = json.loads((out_dir / ARTIFACT_JSON).read_text())
    assert info["weights_bytes"] <= 0.05 * info["full_model_bytes"]
    content = [clips["walk"], clips["kick"]]
    before = model.transfer(content, seed=1)
    for merge in (False, True):
        after = method.load_tuned(out_dir, base_dir, merge=merge).transfer(content, seed=1)
        for a, b in zip(before, after):
            np.testing.assert_allclose(a.motion, b.motion, atol=1e-3)
    del stored[output_bias]
    save_file(stored, str(out_dir / ARTIFACT_WEIGHTS))
    with pytest.raises(MotionDataError, match="missing.*poseFinal"):
        method.load(out_dir, base_dir)


def test_weight_average_follows_the_training_and_is_shipped(base: BaseModels, clips: dict[str, MotionClip]) -> None:
    average = WeightAverage([torch.nn.Parameter(torch.zeros(3))], decay=0.5)
    for value in (2.0, 4.0):
        average.params[0].data.fill_(value)
        average.update()
    assert torch.allclose(average.shadow[0], torch.full((3,), 2.5))  # 0 -> 1 -> 2.5
    average.copy_to_params()
    assert torch.equal(average.params[0].data, torch.full((3,), 2.5))
    pairs = make_pairs(base, [clips["proud_walk"]], parse_params(FAST), torch.Generator().manual_seed(0), STYLE_WORDS)
    plain = finetune(base, pairs, ContentPool([], []), parse_params(FAST, lambda_s=0.0, max_steps=6))
    smooth = finetune(base, pairs, ContentPool([], []), parse_params(FAST, lambda_s=0.0, max_steps=6, ema_decay=0.5))
    assert [r["l_rec"] for r in plain.curve] == [r["l_rec"] for r in smooth.curve]  # averaging never feeds back
    w_prior, w_last, w_avg = (m.output_process.poseFinal.weight for m in (base.prior, plain.model, smooth.model))
    assert 0 < (w_avg - w_prior).norm() < (w_last - w_prior).norm()  # between the start and the last step


def test_full_finetune_artifact_and_base_mismatch(
    base: BaseModels, base_dir: Path, clips: dict[str, MotionClip], tmp_path: Path
) -> None:
    method = OnTheFlyMethod(parse_params(FAST, lambda_s=0.0, max_steps=2), text_encoder=HashTextEncoder())
    lookup = {"ex0": clips["proud_walk"]}
    examples = load_style_examples(proud_spec(), lookup)
    out_dir = method.prepare(proud_spec(), examples, base_dir, [], tmp_path / "full").folder
    info = json.loads((out_dir / ARTIFACT_JSON).read_text())
    assert info["weights"] == "full" and info["weights_bytes"] == info["full_model_bytes"]
    (out,) = method.load(out_dir, base_dir).transfer([clips["walk"]])
    assert out.motion.shape == (FRAMES, 263)
    (fast,) = method.load_tuned(out_dir, base_dir, bf16=True).transfer([clips["walk"]])  # bf16 autocast serving
    assert np.isfinite(fast.motion).all() and not np.array_equal(fast.motion, out.motion)
    np.testing.assert_array_equal(fast.motion[:, :3], clips["walk"].motion[:, :3])
    other = tmp_path / "other-base"
    other.mkdir()
    for f in base_dir.iterdir():
        (other / f.name).write_bytes(f.read_bytes())
    torch.manual_seed(9)
    from motionaug.augment.training.base_models import save_module

    save_module(MDM(MDMConfig.named("tiny", dropout=0.0)), other / "prior.safetensors")
    with pytest.raises(MotionDataError, match="tuned from base models"):
        method.load(out_dir, other)


# ---- tempo ----------------------------------------------------------------------------------------------------


def test_tempo_retimes_content_and_its_caption_segments_and_is_kept_in_the_artifact(
    base: BaseModels, base_dir: Path, clips: dict[str, MotionClip], tmp_path: Path
) -> None:
    method = OnTheFlyMethod(parse_params(FAST, lambda_s=0.0, max_steps=2, tempo=0.5), text_encoder=HashTextEncoder())
    examples = load_style_examples(proud_spec(), {"ex0": clips["proud_walk"]})
    out_dir = method.prepare(proud_spec(), examples, base_dir, [], tmp_path / "slow").folder
    info = json.loads((out_dir / ARTIFACT_JSON).read_text())
    assert info["tempo"] == 0.5 and info["tempo_note"] == "set in the params"
    walk = clips["walk"]
    segment = Caption(text="a person walks forward", start=0.5, end=1.5)
    clip = MotionClip(id="seg", motion=walk.motion, captions=[segment], fps=walk.fps)
    (out,) = method.load(out_dir, base_dir).transfer([clip])
    assert isinstance(out, TransferOutput) and out.motion.shape == (2 * FRAMES, 263)  # half the pace: twice the frames
    assert {(c.start, c.end) for c in out.captions} == {(1.0, 3.0)}  # the segment moved with the clock
    np.testing.assert_array_equal(out.motion[:, :3], retime(walk.motion, 0.5, 1000)[:, :3])  # its (retimed) path kept
    kept = OnTheFlyMethod(
        parse_params(FAST, lambda_s=0.0, max_steps=2, tempo="content"), text_encoder=HashTextEncoder()
    )
    model, _, _, _ = kept.fit(proud_spec(), [clips["proud_walk"]], base, corpus=[walk])
    assert model.tempo == 1.0 and model.transfer([walk])[0].motion.shape == (FRAMES, 263)


def test_tempo_is_measured_from_the_example_against_neutral_corpus_clips(base: BaseModels) -> None:
    """Proud walks (rendered at 0.82x the neutral clock) against neutral walks of the corpus.

    One walk's cadence also follows its own speed (about +-10% here), so three examples give the median."""
    examples = [synth_clip("walk", "proud", seed, f"ex{seed}", frames=160) for seed in (10, 11, 12)]
    walks = [synth_clip("walk", "neutral", seed, f"w{seed}", frames=160) for seed in range(20, 26)]
    others = [synth_clip("wave", "neutral", 30, "o0"), synth_clip("squat", "neutral", 31, "o1")]
    params = parse_params(FAST, tempo_references=6)
    tempo, note = resolve_tempo(params, base, examples, walks + others, style_vocab(PROUD, "proud"))
    assert tempo == pytest.approx(0.82, rel=0.1)
    assert "3 of 3 examples" in note and "of 6 references" in note
    still = MotionClip(id="still", motion=np.repeat(examples[0].motion[:1], 80, axis=0), captions=examples[0].captions)
    tempo, note = resolve_tempo(params, base, [still], walks, style_vocab(PROUD, "proud"))
    assert tempo == 1.0 and "content clock kept" in note and "do not repeat" in note


# ---- style examples -------------------------------------------------------------------------------------------


def _spec(source: str, description: str = "a person walks proudly", joint_map: str | None = None) -> StyleSpec:
    example = StyleExample(source=source, description=description, joint_map=joint_map)
    return StyleSpec(name="proud", words=PROUD, examples=[example])


def test_style_examples_load_from_clip_id_and_npy(tmp_path: Path, clips: dict[str, MotionClip]) -> None:
    np.save(tmp_path / "ex.npy", clips["proud_walk"].motion)
    spec = StyleSpec(
        name="proud",
        words=PROUD,
        examples=[
            StyleExample(source="ex0", description="a man walks with pride"),
            StyleExample(source="ex.npy", description="a proud person walks"),
        ],
    )
    loaded = load_style_examples(spec, {"ex0": clips["proud_walk"]}.get, root=tmp_path)
    assert [c.motion.shape for c in loaded] == [(FRAMES, 263), (FRAMES, 263)]
    assert loaded[0].captions[0].text == "a man walks with pride" and loaded[1].style == "proud"


def test_style_examples_load_a_bvh() -> None:
    bvh = next((FIXTURES / "bvh" / "dataset-1" / "data").glob("*walk*.bvh"))
    (clip,) = load_style_examples(_spec(str(bvh)))
    assert clip.motion.shape[1] == 263 and clip.n_frames >= 20 and np.isfinite(clip.motion).all()


@pytest.mark.parametrize(
    ("make", "description", "reason"),
    [
        (lambda d: np.zeros((10, 263), np.float32), "a person walks proudly", "too short"),
        (lambda d: np.full((30, 263), np.nan, np.float32), "a person walks proudly", "NaN"),
        (lambda d: np.zeros((30, 251), np.float32), "a person walks proudly", "width 251"),
        (lambda d: np.zeros((30, 263), np.float32), "a person walks", "names no style word"),
    ],
)
def test_style_example_errors_name_the_example(tmp_path: Path, make, description: str, reason: str) -> None:
    np.save(tmp_path / "bad.npy", make(None))
    with pytest.raises(MotionDataError, match=reason) as err:
        load_style_examples(_spec("bad.npy", description), root=tmp_path)
    assert "example 0 (bad.npy)" in err.value.source


def test_style_example_unknown_id_and_foreign_bvh(tmp_path: Path) -> None:
    with pytest.raises(MotionDataError, match="unknown clip id"):
        load_style_examples(_spec("000123"), {})
    foreign = tmp_path / "robot.bvh"
    foreign.write_text(
        "HIERARCHY\nROOT Base\n{\n OFFSET 0 0 0\n CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation\n"  # noqa: E501 (BVH lines)
        " JOINT Arm\n {\n  OFFSET 0 10 0\n  CHANNELS 3 Zrotation Xrotation Yrotation\n  End Site\n  {\n   OFFSET 0 5 0\n  }\n }\n}\n"  # noqa: E501 (BVH lines)
        "MOTION\nFrames: 2\nFrame Time: 0.0333333\n0 0 0 0 0 0 0 0 0\n0 0 0 0 0 0 0 0 0\n"
    )
    with pytest.raises(MotionDataError, match="no joint map") as err:
        load_style_examples(_spec(str(foreign)))
    assert "robot.bvh" in err.value.source


def test_workflow_sized_seeds_draw_noise() -> None:
    """The workflow derives 64-bit seeds per unit; torch refuses seeds of 2**63 and above unless they are folded."""
    from motionaug.augment.methods.onthefly import clip_noise

    big = (1 << 64) - 5
    noise = clip_noise((2, 10, 4), ["a", "b"], big)
    assert noise.shape == (2, 10, 4) and torch.isfinite(noise).all()
    assert torch.equal(noise, clip_noise((2, 10, 4), ["a", "b"], big))


# ---- the compute device -------------------------------------------------------------------------------------------


def _tiny_run(
    base_dir: Path, clips: dict[str, MotionClip], out: Path, lora_rank: int = 2, bf16: bool | None = False
) -> dict[str, np.ndarray]:
    """prepare (pairs, L_rec + L_s over a pool with a neutralised styled clip) -> load -> transfer, as arrays."""
    raw = dict(FAST, max_steps=2, lambda_s=0.5, styled_corpus="neutralise", lora_rank=lora_rank, bf16=bf16)
    raw["lora_biases"] = lora_rank > 0
    method = OnTheFlyMethod(parse_params(raw), text_encoder=HashTextEncoder())
    examples = load_style_examples(proud_spec(), {"ex0": clips["proud_walk"]})
    pool = [clips["walk"], clips["kick"], clips["angry_run"]]
    artifact = method.prepare(proud_spec(), examples, base_dir, pool, out).folder
    arrays = {f"w/{k}": v.numpy() for k, v in load_file(str(artifact / ARTIFACT_WEIGHTS)).items()}
    loaded = method.load(artifact, base_dir)
    arrays["device"] = np.array(loaded.device.type)
    for o in loaded.transfer([clips["walk"], clips["kick"], clips["angry_run"]], seed=7):
        assert isinstance(o, TransferOutput)
        arrays[o.source_id] = o.motion
        arrays[f"{o.source_id}/scores"] = np.array([o.scores[k] for k in sorted(o.scores)])
    return arrays


@pytest.mark.skipif(torch.cuda.is_available(), reason="the default device is CUDA here: the CUDA test compares them")
def test_explicit_cpu_device_gives_the_default_paths_arrays(
    base_dir: Path, clips: dict[str, MotionClip], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("MOTIONAUG_DEVICE", raising=False)
    default = _tiny_run(base_dir, clips, tmp_path / "default")
    monkeypatch.setenv("MOTIONAUG_DEVICE", "cpu")
    explicit = _tiny_run(base_dir, clips, tmp_path / "cpu")
    assert explicit["device"] == "cpu" and set(default) == set(explicit) and len(default) > 10
    for key, value in default.items():
        np.testing.assert_array_equal(explicit[key], value, err_msg=key)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
@pytest.mark.parametrize("lora_rank", [0, 2])
def test_cuda_finetune_and_transfer_match_cpu(
    base_dir: Path, clips: dict[str, MotionClip], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, lora_rank: int
) -> None:
    """Same seed, same noise (drawn on CPU): fp32 on CUDA lands close to CPU; bf16 (CUDA's default) stays finite."""
    monkeypatch.setenv("MOTIONAUG_DEVICE", "cpu")
    cpu = _tiny_run(base_dir, clips, tmp_path / "cpu", lora_rank)
    monkeypatch.setenv("MOTIONAUG_DEVICE", "cuda")
    cuda = _tiny_run(base_dir, clips, tmp_path / "cuda", lora_rank)
    assert cuda["device"] == "cuda" and set(cuda) == set(cpu)
    for key, value in cpu.items():
        if key == "device":
            continue
        assert np.isfinite(cuda[key]).all(), key
        scale = max(1.0, float(np.abs(value).max()))
        assert float(np.abs(cuda[key] - value).max()) <= 0.02 * scale, key
    kept = trajectory_channels("horizontal")
    np.testing.assert_array_equal(cuda["c0"][:, kept], clips["walk"].motion[:, kept])  # inpainted exactly
    fast = _tiny_run(base_dir, clips, tmp_path / "bf16", lora_rank, bf16=None)  # None: bf16 autocast on CUDA
    assert all(np.isfinite(v).all() for k, v in fast.items() if k != "device")


@loss_terms.register("test-joint-l1")
class JointL1(LossTerm):
    """A loss term as the lab writes one: mean distance of the predicted joints from the target's, metres."""

    def __call__(self, batch: LossBatch) -> torch.Tensor:
        return (batch.predicted - batch.target).norm(dim=-1)[batch.mask].mean()


def test_a_registered_loss_term_joins_the_fine_tuning_loss(base: BaseModels, clips: dict[str, MotionClip]) -> None:
    """``loss_terms`` (a hook point, like ``callbacks``) add to L_rec on its path's last x0, in global joints."""
    term = {"name": "test-joint-l1", "weight": 1.0}
    params = parse_params(FAST, lambda_s=0.0, max_steps=12, lr=2e-3, loss_terms=[term])
    pairs = make_pairs(base, [clips["proud_walk"]], params, torch.Generator().manual_seed(0), STYLE_WORDS)
    curve = finetune(base, pairs, ContentPool([], []), params).curve
    first = curve[0]
    assert first["total"] == pytest.approx(first["l_rec"] + first["test-joint-l1"], rel=1e-5)
    assert np.mean([r["test-joint-l1"] for r in curve[-3:]]) < first["test-joint-l1"]
    assert "test-joint-l1" not in finetune(base, pairs, ContentPool([], []), parse_params(FAST, max_steps=1)).curve[0]
    with pytest.raises(MotionDataError, match=r"method\.params\.loss_terms: .*unknown loss term 'nope'"):
        method_class("onthefly").parse_params({"loss_terms": ["nope"]})
