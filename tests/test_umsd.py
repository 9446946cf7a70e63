"""UMSD (Qian et al., ACM MM 2025): the network, its training and the method behind the workflow contract.

Everything runs at tiny sizes on a 24-clip synthetic corpus (a few seconds of rendering, shared by the module).
"""

from __future__ import annotations

import copy
import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from pydantic import ValidationError

from motionaug.augment.corpus import Corpus, MotionClip, Reject
from motionaug.augment.methods.base import ARTIFACT_JSON, TrainingSpec
from motionaug.augment.methods.common import feet_channels, trajectory_channels
from motionaug.augment.methods.hooks import (
    LossBatch,
    LossTerm,
    SamplerCallback,
    SamplerStep,
    loss_terms,
    output_shapers,
    sampler_callbacks,
)
from motionaug.augment.methods.shapers import with_amplitude, with_posture
from motionaug.augment.methods.shaping import ShapedModel, nearest_root_motion, read_shaping, write_shaping
from motionaug.augment.methods.umsd import (
    UmsdTrain,
    UmsdTrainConfig,
    UmsdTrainer,
    load_umsd,
    prepare_data,
    read_artifact,
    train_umsd,
)
from motionaug.augment.methods.umsd.method import (
    UmsdMethod,
    UmsdParams,
    blend_ramp,
    window_spans,
)
from motionaug.augment.methods.umsd.pace import pace_ratio
from motionaug.augment.methods.umsd.training import pace_channels, x0_from_output
from motionaug.augment.motion.features import feature_slices
from motionaug.augment.outputs.shards import TransferOutput
from motionaug.augment.synth import generate_corpus, restyled
from motionaug.models.umsd import UmsdConfig, UmsdNet, pack
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.skeleton import T2M
from motionaug.schemas.styles import StyleSpec

TINY = {
    "d_model": 32,
    "n_heads": 2,
    "ff_size": 64,
    "msm_blocks": 2,
    "d_state": 4,
    "max_frames": 40,
    "batch_size": 3,
    "threads": 1,
    "log_every": 1,
}
HELD_OUT = "old"
seen: list[int] = []  # the timesteps the test's sampler callback was called at


@sampler_callbacks.register("test-damp")
class Damp(SamplerCallback):
    """A sampler callback defined by the test: x0 times ``factor`` (1: unchanged); records each step's timestep."""

    def __init__(self, factor: float) -> None:
        self.factor = factor

    def __call__(self, step: SamplerStep) -> torch.Tensor:
        seen.append(step.t)
        return step.x0 if self.factor == 1.0 else step.x0 * self.factor


@loss_terms.register("test-height")
class Height(LossTerm):
    """A loss term defined by the test: the mean predicted root height, metres."""

    def __call__(self, batch: LossBatch) -> torch.Tensor:
        return batch.predicted[:, :, 0, 1].mean()


@pytest.fixture(scope="module", autouse=True)
def one_thread():
    """Tiny tensors: one thread is fastest, and two spin-waiting threads crawl on a busy 2-core machine."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("umsd") / "corpus"
    generate_corpus(root, 24, seed=0)
    return root


@pytest.fixture(scope="module")
def clips(corpus: Path) -> list[MotionClip]:
    return list(Corpus(corpus, split="train"))


# ---- network ---------------------------------------------------------------------------------------------------


def _padded_batch(seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    x, c, s = (torch.randn(3, n, 263, generator=g) for n in (17, 13, 9))
    x_mask, c_mask, s_mask = (torch.ones(t.shape[:2], dtype=torch.bool) for t in (x, c, s))
    x_mask[1, 11:] = False  # odd lengths, padding in every part
    c_mask[0, 5:] = False
    s_mask[2, 3:] = False
    return x, torch.tensor([0, 517, 999]), c, c_mask, s, s_mask, x_mask


@pytest.mark.parametrize(
    "variant",
    [{}, {"use_ssm": False}, {"use_mha": False}, {"denoiser": "transformer"}, {"align_content": True}],
    ids=["msm", "no_ssm", "no_mha", "transformer", "aligned"],
)
def test_network_shapes_masks_and_batch_independence(variant: dict) -> None:
    torch.manual_seed(0)
    net = UmsdNet(UmsdConfig(d_model=32, n_heads=2, ff_size=64, msm_blocks=2, d_state=4, **variant)).eval()
    x, t, c, cm, s, sm, xm = _padded_batch()
    with torch.no_grad():
        y = net(x, t, c, cm, s, sm, xm)
        assert y.shape == x.shape and torch.isfinite(y).all()
        assert y[1, 11:].abs().max() == 0  # padded frames of x_t are zero
        # each sample alone, without padding, gives its rows of the padded batch: padding never leaks in
        alone = [
            net(x[0:1], t[0:1], c[0:1, :5], None, s[0:1], None)[0],
            net(x[1:2, :11], t[1:2], c[1:2], None, s[1:2], None)[0],
            net(x[2:3], t[2:3], c[2:3], None, s[2:3, :3], None)[0],
        ]
        for i, a in enumerate(alone):
            torch.testing.assert_close(y[i, : a.shape[0]], a, atol=1e-5, rtol=1e-4)
        # the condition matters: another style example (or content) changes the prediction
        assert (net(x, t, c, cm, s.flip(0), sm.flip(0), xm) - y).abs().max() > 1e-3
        assert (net(x, t, c.flip(0), cm.flip(0), s, sm, xm) - y).abs().max() > 1e-3
        assert (net(x, t.flip(0), c, cm, s, sm, xm) - y).abs().max() > 1e-3
    net.train()
    net(x, t, c, cm, s, sm, xm).square().mean().backward()
    assert all(p.grad is not None and torch.isfinite(p.grad).all() for p in net.parameters())


def test_ablation_flags_change_the_network() -> None:
    base = UmsdNet(UmsdConfig(d_model=32, n_heads=2, ff_size=64, msm_blocks=2, d_state=4))
    names = {n for n, _ in base.named_parameters()}
    assert any("forward_ssm" in n for n in names) and any("denoiser.attn." in n for n in names)
    no_ssm = {n for n, _ in UmsdNet(UmsdConfig(d_model=32, n_heads=2, msm_blocks=2, use_ssm=False)).named_parameters()}
    no_mha = {n for n, _ in UmsdNet(UmsdConfig(d_model=32, n_heads=2, msm_blocks=2, use_mha=False)).named_parameters()}
    assert not any("_ssm" in n for n in no_ssm) and not any("denoiser.attn." in n for n in no_mha)
    transformer = UmsdNet(UmsdConfig(d_model=32, n_heads=2, msm_blocks=2, denoiser="transformer"))
    assert len(transformer.denoiser.encoder.layers) == 3
    aligned_net = UmsdNet(UmsdConfig(d_model=32, n_heads=2, ff_size=64, msm_blocks=2, d_state=4, align_content=True))
    aligned = {n for n, _ in aligned_net.named_parameters()}
    assert aligned - names == {"align.weight", "align.bias"} and not any(n.startswith("align.") for n in names)
    with pytest.raises(ValueError, match="denoiser"):
        UmsdConfig(denoiser="unet")
    with pytest.raises(MotionDataError, match="no real frame"):
        x = torch.zeros(1, 5, 263)
        base(x, torch.zeros(1, dtype=torch.long), x, torch.zeros(1, 5, dtype=torch.bool), x, None)


def test_pack_keeps_order_and_puts_padding_last() -> None:
    a = torch.arange(1, 7, dtype=torch.float32).view(2, 3, 1)
    b = torch.arange(11, 15, dtype=torch.float32).view(2, 2, 1)
    am = torch.tensor([[True, True, False], [True, True, True]])
    bm = torch.tensor([[True, True], [True, False]])
    packed, mask, position = pack([a, b], [am, bm])
    assert packed[..., 0].tolist() == [[1, 2, 11, 12], [4, 5, 6, 13]]
    assert mask.tolist() == [[True, True, True, True], [True, True, True, True]]
    assert position[0, :2].tolist() == [0, 1] and position[0, 3:].tolist() == [2, 3]  # a's padding moved last


# ---- training ------------------------------------------------------------------------------------------------


def _clip(cid: str, style: str, content: str, spec: dict | None = None) -> MotionClip:
    rng = np.random.default_rng(len(cid) + sum(map(ord, cid)))
    motion = rng.normal(size=(30, 263)).astype(np.float32)
    meta = {} if spec is None else {"spec": json.dumps(spec)}
    return MotionClip(id=cid, motion=motion, captions=[], content=content, style=style, meta=meta)


def test_pairs_prefer_same_spec_renderings_and_other_content_style_mates() -> None:
    spec = {"content": "walk", "seed": 3, "speed": 1.1, "style": "neutral", "intensity": 1.0}
    clips = [
        _clip("a", "neutral", "walk", spec),
        _clip("b", "proud", "walk", {**spec, "style": "proud", "intensity": 0.9}),  # a re-rendered proudly
        _clip("c", "proud", "walk", {**spec, "seed": 4, "style": "proud"}),  # another proud walk
        _clip("d", "proud", "kick"),
        _clip("e", "neutral", "kick"),
    ]
    data = prepare_data(clips, UmsdTrainConfig(**TINY))
    assert data.same_motion[0] == [1]  # the same spec in another style wins over other proud walks
    assert data.same_motion[2] == [0]  # no spec twin: same content label, another style
    assert data.same_style[1] == [3]  # style mates with other content first
    assert data.summary()["spec_pairs"] == 2
    held = prepare_data(clips, UmsdTrainConfig(**TINY, exclude_styles=("proud",)))
    assert set(held.styles) == {"neutral"} and held.dropped["held_out"] == 3
    only_rec = prepare_data(clips, UmsdTrainConfig(**TINY, use_dcc=False, use_dsc=False))
    assert set(only_rec.eligible) == {"rec"}
    with pytest.raises(MotionDataError, match="style label"):
        prepare_data([_clip("x", "", "walk")], UmsdTrainConfig(**TINY))


def test_synthetic_pairs_render_each_motion_in_a_partner_style(clips: list[MotionClip]) -> None:
    config = UmsdTrainConfig(**TINY, synthetic_pairs=True, exclude_styles=(HELD_OUT,))
    data = prepare_data(clips, config)
    kept = [c for c in clips if c.style != HELD_OUT]
    assert data.rendered == len(kept) and len(data.ids) == 2 * len(kept)
    assert HELD_OUT not in data.styles  # a held-out style is never rendered
    by_id = dict(zip(data.ids, range(len(data.ids))))
    for clip in kept:
        twin = by_id[next(i for i in data.ids if i.startswith(f"{clip.id}_"))]
        i = by_id[clip.id]
        assert data.spec_keys[twin] == data.spec_keys[i] and data.same_motion[i] == [twin]
        assert (data.styles[twin] == "neutral") == (clip.style != "neutral")
        assert len(data.motions[twin]) == len(data.motions[i])  # the same duration, frame for frame
    trainer = UmsdTrainer(data, config)
    styled = next(i for i, s in enumerate(data.styles) if s != "neutral" and "_" not in data.ids[i])
    x0, content, _ = trainer._row("rec", styled)

    def starts(motion: np.ndarray, window: np.ndarray) -> list[int]:
        return [k for k in range(len(motion) - len(window) + 1) if np.array_equal(motion[k : k + len(window)], window)]

    twin_starts = starts(data.motions[data.same_motion[styled][0]], content)
    assert set(starts(data.motions[styled], x0)) & set(twin_starts)  # rec's content: the twin at the target's frames
    assert "synthetic_pairs" not in UmsdTrainConfig(**TINY).model_dump()  # model keys made before it stay
    with pytest.raises(MotionDataError, match="clip x.*no synthetic motion spec"):
        restyled(_clip("x", "proud", "walk"), "neutral")


def test_a_loss_term_named_in_the_config_is_added_with_its_weight(clips: list[MotionClip]) -> None:
    plain = UmsdTrainConfig(**TINY)
    config = plain.model_copy(update={"loss_terms": ({"name": "test-height", "weight": 0.5},)})
    assert "loss_terms" not in plain.model_dump()  # model keys made before it stay
    losses = {}
    for name, cfg in (("plain", plain), ("term", config)):
        torch.manual_seed(0)
        trainer = UmsdTrainer(prepare_data(clips, cfg), cfg)
        losses[name] = trainer.evaluate(trainer.sample())
    assert losses["term"]["test-height"] > 0.5  # the root is around a metre up
    expected = losses["plain"]["total"] + 0.5 * losses["term"]["test-height"]
    assert losses["term"]["total"] == pytest.approx(expected, rel=1e-5)
    with pytest.raises(MotionDataError, match=r"train\.loss_terms: .*unknown loss term 'nope'"):
        UmsdMethod.parse_params({"train": {"loss_terms": ["nope"]}})


def test_the_product_training_settings_expand_into_the_recipe() -> None:
    train = UmsdTrain(steps=7, skip="content", w_dsc=0.0)
    small, tiny = train.recipe("small", 3), train.recipe("tiny", 0)
    assert small.steps == 7 and small.skip == "content" and small.w_dsc == 0.0 and small.seed == 3
    assert small.d_model == UmsdTrainConfig().d_model and tiny.d_model == 32 and tiny.msm_blocks == 1
    assert train.recipe().model_dump() == UmsdTrainConfig(steps=7, skip="content", w_dsc=0.0).model_dump()
    assert len(UmsdTrain.model_fields) <= 15 and len(UmsdParams.model_fields) <= 10
    with pytest.raises(MotionDataError, match=r"config base_models\.size: UMSD has no network size 'huge'"):
        train.recipe("huge")
    with pytest.raises(MotionDataError, match=r"config method\.params\.train\.d_model: umsd: removed; .*base_models"):
        UmsdMethod.parse_params({"train": {"d_model": 32}})
    with pytest.raises(MotionDataError, match=r"config method\.params\.train\.w_acc: umsd: removed; .*acceleration"):
        UmsdMethod.parse_params({"train": {"w_acc": 0.1}})


def test_a_training_step_lowers_the_loss(clips: list[MotionClip]) -> None:
    config = UmsdTrainConfig(**TINY, lr=2e-3)
    data = prepare_data(clips, config)
    torch.manual_seed(0)
    trainer = UmsdTrainer(data, config)
    batch = trainer.sample()
    assert set(batch.kinds) == {"rec", "dcc", "dsc"} and len(batch.kinds) == 3 * config.batch_size
    before = trainer.evaluate(batch)
    assert set(before) == {"rec", "dcc", "dsc", "pos", "vel", "foot", "total"}
    assert all(np.isfinite(v) and v > 0 for v in before.values())
    trainer.train_step(batch)
    after = trainer.evaluate(batch)
    assert after["total"] < before["total"]


def test_the_spectrum_term_forgets_phase_and_charges_a_missing_rhythm(clips: list[MotionClip]) -> None:
    config = UmsdTrainConfig(**TINY, lr=2e-3, w_spec=3.0)
    assert "w_spec" not in UmsdTrainConfig(**TINY).model_dump()  # model keys made before it stay
    torch.manual_seed(0)
    trainer = UmsdTrainer(prepare_data(clips, config), config)
    frames = 40
    keep = torch.ones(2, frames, 1)
    keep[1, 33:] = 0  # a padded row
    swing = torch.zeros(2, frames, trainer.mean.numel())
    phase = torch.arange(frames) * (2 * torch.pi * 4 / frames)  # four cycles: one frequency bin
    channel = trainer.ric.start + 5
    amplitude = 0.06  # metres
    swing[:, :, channel] = amplitude * torch.sin(phase) / trainer.std[channel]
    rest = (torch.zeros_like(swing) - trainer.mean) / trainer.std  # every channel still at zero metres
    target, shifted = rest + swing, rest + swing.roll(3, dims=1)
    spectrum = trainer._spectrum_l1
    assert spectrum(target, target, keep[:1].expand(2, -1, -1)).item() < 1e-6
    assert spectrum(shifted[:1], target[:1], keep[:1]).item() < 1e-4  # the same rhythm at another phase: free
    channels = 1 + trainer.ric.stop - trainer.ric.start
    missing = spectrum(rest[:1], target[:1], keep[:1]).item() * channels
    assert missing == pytest.approx(amplitude / 2, rel=0.05)  # a sinusoid of amplitude A peaks at A / 2
    assert spectrum(rest, target, keep).item() > 0  # the padded row too
    batch = trainer.sample()
    before = trainer.evaluate(batch)
    assert before["spec"] > 0 and before["total"] > before["rec"] + before["dcc"] + before["dsc"]
    trainer.train_step(batch)
    assert trainer.evaluate(batch)["total"] < before["total"]


def _one_step_lowers_the_loss(clips: list[MotionClip], config: UmsdTrainConfig) -> tuple[UmsdTrainer, Any]:
    """A trainer seeded 0, after one step that must lower the loss on its own batch; the trainer and that batch."""
    torch.manual_seed(0)
    trainer = UmsdTrainer(prepare_data(clips, config), config)
    batch = trainer.sample()
    before = trainer.evaluate(batch)
    trainer.train_step(batch)
    assert trainer.evaluate(batch)["total"] < before["total"]
    return trainer, batch


@pytest.mark.parametrize("skip", ["covariance", "content"])
def test_skips_lower_the_loss_and_the_content_skip_starts_from_the_content(clips: list[MotionClip], skip: str) -> None:
    config = UmsdTrainConfig(**TINY, lr=2e-3, skip=skip)
    trainer, batch = _one_step_lowers_the_loss(clips, config)
    # at pure noise a zero residual predicts the prior mean: the content frame by frame (zeros past its end)
    x_t = torch.randn(batch.x0.shape)
    t = torch.full((len(batch.kinds),), 999)
    x0 = x0_from_output(skip, trainer.schedule, x_t, t, torch.zeros_like(x_t), trainer.skip_prior(), batch.content)
    frames = min(batch.x0.shape[1], batch.content.shape[1])
    if skip == "content":
        torch.testing.assert_close(x0[:, :frames], batch.content[:, :frames], atol=0.05, rtol=0)
        assert (x0[:, frames:].abs() < 0.05).all()
    else:
        assert x0.abs().max() < 0.05


def test_without_the_content_pace_the_skip_leaves_the_ground_velocity_to_the_network(clips: list[MotionClip]) -> None:
    assert "content_pace" not in UmsdTrainConfig().model_dump()  # the keys of models trained before it stay the same
    assert pace_channels(UmsdTrainConfig(skip="covariance", content_pace=False)) == []  # only the content skip
    config = UmsdTrainConfig(**TINY, lr=2e-3, skip="content", content_pace=False)
    free = pace_channels(config)
    assert free == [1, 2] and trajectory_channels("heading") == [0, 3]  # xz velocity free; yaw and height kept
    trainer, batch = _one_step_lowers_the_loss(clips, config)
    # at pure noise a zero residual predicts the content frame by frame, but the data mean for the ground velocity
    x_t = torch.randn(batch.x0.shape)
    t = torch.full((len(batch.kinds),), 999)
    zero = torch.zeros_like(x_t)
    x0 = x0_from_output("content", trainer.schedule, x_t, t, zero, trainer.skip_prior(), batch.content, free=free)
    frames = min(batch.x0.shape[1], batch.content.shape[1])
    body = [c for c in range(263) if c not in free]
    torch.testing.assert_close(x0[:, :frames, body], batch.content[:, :frames, body], atol=0.05, rtol=0)
    assert x0[..., free].abs().max() < 0.05 and batch.content[:, :frames, free].abs().max() > 0.5


def test_the_spectral_skip_trains_and_its_prior_goes_with_the_weights(clips: list[MotionClip], tmp_path: Path) -> None:
    with pytest.raises(ValidationError, match="skip_time 'spectral' needs a skip"):
        UmsdTrainConfig(skip="none", skip_time="spectral")
    assert "skip_time" not in UmsdTrainConfig().model_dump()  # the keys of models trained before it stay the same
    config = UmsdTrainConfig(**TINY, lr=2e-3, skip="content", skip_time="spectral")
    trainer, _ = _one_step_lowers_the_loss(clips, config)
    assert trainer.spectral is not None and trainer.spectral.bases.shape == (32, 263, 263)
    model = load_umsd(train_umsd(clips, tmp_path / "s", config.model_copy(update={"steps": 1})))
    assert model.spectral is not None
    torch.testing.assert_close(model.spectral.variances, trainer.spectral.variances)


def test_training_is_deterministic_and_loads(clips: list[MotionClip], tmp_path: Path) -> None:
    config = UmsdTrainConfig(**TINY, steps=2, skip="covariance")
    first = train_umsd(clips, tmp_path / "a", config)
    second = train_umsd(clips, tmp_path / "b", config)
    other = train_umsd(clips, tmp_path / "c", config.model_copy(update={"seed": 1}))
    blob = lambda folder: (folder / "umsd.safetensors").read_bytes()  # noqa: E731
    assert blob(first) == blob(second) and blob(first) != blob(other)
    info = read_artifact(first)
    assert info.history == read_artifact(second).history and len(info.history) == 2
    assert info.data["eligible"] and set(info.final) >= {"total", "rec", "dcc", "dsc"}
    model = load_umsd(first)
    assert not model.net.training and model.net.config.d_model == TINY["d_model"]
    basis, var = model.skip_prior  # the covariance skip's data prior travels with the weights
    assert basis.shape == (263, 263) and var.shape == (263,) and bool((var >= 0).all())
    assert torch.allclose(basis.T @ basis, torch.eye(263), atol=1e-4)
    x = torch.from_numpy(model.normalizer.normalize(clips[0].motion[:20]))[None]
    with torch.no_grad():
        y = model.net(x, torch.tensor([10]), x, None, x, None)
    assert y.shape == x.shape and torch.isfinite(y).all()
    assert not list(tmp_path.glob(".*.tmp"))  # no temporary folder left behind


def test_the_pace_regressor_learns_the_styles_speeds_and_leaves_the_diffusion_weights(
    clips: list[MotionClip], tmp_path: Path
) -> None:
    config = UmsdTrainConfig(**TINY, steps=2, synthetic_pairs=True)
    plain = load_umsd(train_umsd(clips, tmp_path / "plain", config))
    folder = train_umsd(clips, tmp_path / "paced", config.model_copy(update={"pace_steps": 300}))
    model = load_umsd(folder)
    assert plain.pace is None and model.pace is not None and not model.pace.training
    for name, tensor in plain.net.state_dict().items():  # the fit runs after, on its own generators
        torch.testing.assert_close(model.net.state_dict()[name], tensor, rtol=0, atol=0)
    final = read_artifact(folder).final
    assert final["pace_final"] < 0.5 * final["pace_first"]
    assert read_artifact(folder).train.model_dump() != config.model_dump()  # a model of its own key
    assert "pace_steps" not in config.model_dump()  # older configs keep theirs

    # a slow style's example slows the content's root, a fast one's speeds it; the path keeps its heading
    neutral = next(c for c in clips if c.style == "neutral" and spec_of(c)["content"] == "walk")
    norm = model.normalizer
    content = norm.normalize(neutral.motion).astype(np.float32)
    ratios = {}
    for style in ("old", "childlike"):
        example = restyled(neutral, style)
        ratios[style] = pace_ratio(model.pace, content, torch.from_numpy(norm.normalize(example.motion)))
    assert ratios["old"] < 0.8 < 1.25 < ratios["childlike"]


def spec_of(clip: MotionClip) -> dict[str, Any]:
    return json.loads(clip.meta["spec"])


# ---- the method --------------------------------------------------------------------------------------------------


def test_params() -> None:
    UmsdMethod.parse_params(UmsdMethod.smoke_params)
    with pytest.raises(MotionDataError, match=r"config method\.params\.train"):
        UmsdMethod.parse_params({"train": {"steps": 1, "wall_seconds": 3}})
    with pytest.raises(MotionDataError, match=r"config method\.params\.guidance"):
        UmsdMethod.parse_params({"guidance": 2.5})
    # a setting that left the product is one line saying what to do instead
    with pytest.raises(MotionDataError, match=r"config method\.params\.posture: umsd: removed; .*shapers: \[moments\]"):
        UmsdMethod.parse_params({"posture": "example", "amplitude": "example"})
    with pytest.raises(MotionDataError, match=r"config method\.params\.x0_smooth: umsd: removed; .*lab/README\.md"):
        UmsdMethod.parse_params({"x0_smooth": 1.0})
    with pytest.raises(MotionDataError, match=r"config method\.params\.shapers: umsd: removed; .* method\.shapers"):
        UmsdMethod.parse_params({"shapers": ["moments"]})
    with pytest.raises(MotionDataError, match=r"config method\.params\.callbacks: .*unknown sampler callback"):
        UmsdMethod.parse_params({"callbacks": [{"name": "nope", "sigma": 1}]})
    # a field added later is left out of the dump at its default: older configs (and model keys) stay the same
    assert "align_content" not in UmsdTrainConfig().model_dump()
    aligned = UmsdTrainConfig(align_content=True)
    assert UmsdTrainConfig.model_validate_json(aligned.model_dump_json()) == aligned and aligned.network().align_content


def test_windows_cover_long_clips_and_blend_to_one() -> None:
    assert window_spans(30, 40, 4) == [(0, 30)] and window_spans(90, 0, 4) == [(0, 90)]
    spans = window_spans(90, 40, 4)
    assert spans[0][0] == 0 and spans[-1][1] == 90 and all(b - a == 40 for a, b in spans)
    assert all(b1 - a2 >= 4 for (_, b1), (a2, _) in zip(spans, spans[1:]))  # neighbours overlap
    total = np.zeros((90, 1), np.float32)
    for a, b in spans:
        ramp = blend_ramp(a, b, 90, 4)
        assert ramp.min() > 0 and ramp.max() == 1
        total[a:b] += ramp
    assert total.min() >= 1  # every frame is covered by a full-weight part of some window


def test_the_contrast_reference_is_the_pool_clip_whose_root_moves_like_the_example() -> None:
    rng = np.random.default_rng(0)

    def clip(speed: float, bob: float, contact: float, sideways: float = 0.0, sway: float = 0.0) -> np.ndarray:
        motion = rng.normal(0, 0.01, (60, 263)).astype(np.float32)
        motion[:, 0:3] = [0.0, sideways, speed]  # no turning (root_rot_vel), velocity in the facing frame (x, z)
        motion[:, 2] += sway * np.sin(np.linspace(0, 12, 60))  # back and forth on the spot
        motion[:, 3] = 0.95 + bob * np.sin(np.linspace(0, 12, 60))  # root_y
        motion[:, 259:] = float(contact)
        return motion

    pool = {
        "b_walk": clip(0.05, 0.02, 0.6),
        "a_stand": clip(0.0, 0.0, 1.0),
        "c_jump": clip(0.0, 0.15, 0.3),
        "d_back": clip(-0.05, 0.02, 0.6),
        "e_side": clip(0.0, 0.02, 0.6, sideways=0.05),
        "f_kick": clip(0.002, 0.005, 0.8, sway=0.01),
    }
    assert nearest_root_motion(clip(0.03, 0.015, 0.7), pool)[0] == "b_walk"  # a slower walk: still the walk
    assert nearest_root_motion(clip(0.012, 0.02, 0.85), pool)[0] == "b_walk"  # 4x slower, feet down longer
    assert nearest_root_motion(clip(-0.03, 0.02, 0.6), pool)[0] == "d_back"  # same speed, other direction
    assert nearest_root_motion(clip(0.0, 0.02, 0.6, sideways=-0.04), pool)[0] == "e_side"
    assert nearest_root_motion(clip(0.0, 0.12, 0.4), pool)[0] == "c_jump"
    np.testing.assert_array_equal(nearest_root_motion(clip(0.0, 0.0, 1.0), pool)[1], pool["a_stand"])
    assert nearest_root_motion(pool["b_walk"], {"z": pool["b_walk"], "y": pool["b_walk"]})[0] == "y"  # ties: id


def test_the_posture_from_the_examples_moves_the_pose_means_and_keeps_the_motion() -> None:
    rng = np.random.default_rng(0)
    output, content = rng.normal(size=(40, 263)).astype(np.float32), rng.normal(size=(50, 263)).astype(np.float32)
    example, reference = rng.normal(size=(30, 263)).astype(np.float32) + 0.5, rng.normal(size=(35, 263))
    out = with_posture(output, content, example, reference)
    slices = feature_slices(T2M)
    pose = np.r_[slices["root_y"], slices["ric"], slices["rot"]]
    expected = content[:, pose].mean(0) + example[:, pose].mean(0) - reference[:, pose].mean(0)
    np.testing.assert_allclose(out[:, pose].mean(0), expected, atol=1e-5)
    moving = out[:, pose] - out[:, pose].mean(0)
    np.testing.assert_allclose(moving, output[:, pose] - output[:, pose].mean(0), atol=1e-5)
    others = [c for c in range(263) if c not in set(pose)]
    np.testing.assert_array_equal(out[:, others], output[:, others])


def test_the_amplitude_from_the_examples_scales_the_motion_around_its_mean() -> None:
    rng = np.random.default_rng(1)
    output, content = rng.normal(size=(40, 263)).astype(np.float32), rng.normal(size=(50, 263)).astype(np.float32)
    example, reference = 0.5 * rng.normal(size=(30, 263)), rng.normal(size=(35, 263))  # a style half as big as plain
    out = with_amplitude(output, content, example, reference, 0.25)
    slices = feature_slices(T2M)
    cols = np.r_[slices["root_y"], slices["ric"], slices["rot"], slices["local_vel"]]
    target = content[:, cols].var(0) + example[:, cols].var(0) - reference[:, cols].var(0)
    target = np.maximum(target, 0.25**2 * content[:, cols].var(0))
    np.testing.assert_allclose(out[:, cols].var(0), target, rtol=1e-4)
    assert out[:, cols].var(0).mean() < 0.5 * output[:, cols].var(0).mean()  # the motion shrank
    np.testing.assert_allclose(out[:, cols].mean(0), output[:, cols].mean(0), atol=1e-5)  # around its own mean
    others = [c for c in range(263) if c not in set(cols)]
    np.testing.assert_array_equal(out[:, others], output[:, others])
    still = output.copy()
    still[:, cols] = 1.0 + 1e-3 * rng.normal(size=(40, len(cols)))  # a near-still output is not blown up
    assert np.abs(with_amplitude(still, content, example, reference, 0.25)[:, cols] - 1.0).max() < 0.05


def test_zero_shot_transfer_of_a_held_out_style(corpus: Path, tmp_path: Path) -> None:
    params = copy.deepcopy(UmsdMethod.smoke_params)
    params["train"] = {**params["train"], "exclude_styles": [HELD_OUT]}
    # guidance and the moments shaper are each checked against the plain transfer
    params.update(guidance="none", guidance_scale=1.0)
    method = UmsdMethod(params)
    spec = TrainingSpec(size="tiny", seed=0)
    trained = method.train(corpus, tmp_path / "trained", spec)
    assert method.is_trained(trained)
    stamp = (trained / "umsd.safetensors").stat().st_mtime_ns
    assert method.train(corpus, tmp_path / "trained", spec) == trained  # reused: same corpus and config
    assert (trained / "umsd.safetensors").stat().st_mtime_ns == stamp
    info = read_artifact(trained)
    assert HELD_OUT not in info.data["styles"] and info.data["dropped"]["held_out"] > 0

    everything = {c.id: c for c in Corpus(corpus)}
    example = next(c for c in everything.values() if c.style == HELD_OUT)
    style = StyleSpec(
        name=HELD_OUT,
        words={"adjective": "old", "phrases": ["like an old person"]},
        examples=[{"source": example.id, "description": "a person walks like an old person"}],
    )
    method.check_style(style, trained)  # any style is allowed
    artifact = method.prepare(style, [example], trained, [], tmp_path / "style").folder
    record = json.loads((artifact / ARTIFACT_JSON).read_text(encoding="utf-8"))
    longest = params["train"]["max_frames"]  # a longer example is cut to the middle of the training crop
    assert record["examples"] == [example.id] and record["example_frames"] == [min(example.n_frames, longest)]

    model = method.load(artifact, trained)
    content = [c for c in everything.values() if c.style == "neutral"][:2]
    broken = MotionClip(id="broken", motion=np.full((30, 263), np.nan, np.float32), captions=[])
    outputs = model.transfer([content[0], broken, content[1]], seed=3)
    assert isinstance(outputs[1], Reject) and outputs[1].id == "broken"
    kept = trajectory_channels("horizontal")
    for out, clip in zip([outputs[0], outputs[2]], content):
        assert isinstance(out, TransferOutput) and out.source_id == clip.id and out.style == HELD_OUT
        assert out.motion.shape == clip.motion.shape and out.motion.dtype == np.float32
        assert np.isfinite(out.motion).all()
        np.testing.assert_array_equal(out.motion[:, kept], clip.motion[:, kept])  # the root path is the content's
        assert not np.allclose(out.motion, clip.motion, atol=1e-3)  # but the body moves differently
        assert out.captions and any("old" in c.text for c in out.captions)
    # a clip's output depends on the seed and its id, not on its batch mates
    alone = model.transfer([content[1]], seed=3)[0]
    np.testing.assert_allclose(alone.motion, outputs[2].motion, atol=1e-4)
    assert not np.allclose(model.transfer([content[1]], seed=4)[0].motion, alone.motion)
    # a sampler callback sees every step's x0 prediction and what it returns is the step's x0
    seen.clear()
    damped = UmsdMethod({**params, "callbacks": [{"name": "test-damp", "factor": 0.0}]}).load(artifact, trained)
    still = damped.transfer([content[1]], seed=3)[0].motion
    assert seen == sorted(seen, reverse=True) and len(seen) == params["ddim_steps"] and seen[-1] < seen[0]
    feet = feet_channels()
    moving = [c for c in range(263) if c not in set(feet) | set(kept)]
    assert np.abs(still[:, moving] - alone.motion[:, moving]).mean() > 1e-3
    np.testing.assert_array_equal(still[:, kept], content[1].motion[:, kept])  # inpainting still applies
    same = UmsdMethod({**params, "callbacks": [{"name": "test-damp", "factor": 1.0}]}).load(artifact, trained)
    np.testing.assert_array_equal(same.transfer([content[1]], seed=3)[0].motion, alone.motion)
    # style guidance: stronger than the plain transfer, and a no-op when the example is the content itself
    guided = UmsdMethod({**params, "guidance": "style", "guidance_scale": 2.0})
    stronger = guided.load(artifact, trained).transfer([content[1]], seed=3)[0]
    assert np.isfinite(stronger.motion).all() and not np.allclose(stronger.motion, alone.motion, atol=1e-3)
    short = dataclasses.replace(content[1], id="short", motion=content[1].motion[:longest])
    itself = guided.prepare(style, [short], trained, [], tmp_path / "itself").folder
    plain = method.load(itself, trained).transfer([short], seed=3)[0].motion
    np.testing.assert_allclose(guided.load(itself, trained).transfer([short], seed=3)[0].motion, plain, atol=1e-4)
    # the moments shaper, the run's for any method: the references are picked from the pool, one per example
    with pytest.raises(MotionDataError, match="need usable plain pool clips to pick the references from"):
        write_shaping(tmp_path, HELD_OUT, [example], [broken], ["moments"])
    write_shaping(tmp_path, HELD_OUT, [example], [broken, *content], ["moments"])
    examples, references = read_shaping(tmp_path)
    assert len(references) == 1 and any(np.array_equal(references[0], c.motion) for c in content)
    moved = ShapedModel(model, [output_shapers.create("moments")], examples, references)
    shaped = moved.transfer([content[1], broken], seed=3)
    assert isinstance(shaped[1], Reject) and np.isfinite(shaped[0].motion).all()
    assert np.abs(shaped[0].motion - alone.motion).mean() > 1e-3
    with pytest.raises(MotionDataError, match="the artefact has no references"):
        ShapedModel(model, [output_shapers.create("moments")], examples)

    (trained / "umsd.json").write_text((trained / "umsd.json").read_text() + " ", encoding="utf-8")
    with pytest.raises(MotionDataError, match="prepared for UMSD network"):
        method.load(artifact, trained)
