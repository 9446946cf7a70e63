"""Style-ERD: network shapes, batched == streaming, lag and reset, blending, training, determinism, bad input."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest
import torch
from pydantic import ValidationError

from motionaug.augment.methods.erd import (
    ErdTrain,
    ErdTrainConfig,
    ErdTrainer,
    StreamingStylizer,
    load_erd,
    prepare_data,
    read_artifact,
    rederive_forward,
    train_erd,
    transfer,
)
from motionaug.augment.methods.hooks import LossBatch, LossTerm, loss_terms
from motionaug.augment.motion.features import compute_mean_std, feature_slices
from motionaug.augment.synth import sample_spec
from motionaug.augment.synth.corpus import spec_to_clip
from motionaug.models.style_erd import (
    ContentClassifier,
    ErdNetwork,
    FtAttDiscriminator,
    StyleErdConfig,
    frame_slices,
)
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.skeleton import T2M

STYLES = ("neutral", "proud", "old", "angry")
CONTENTS = ("jump", "walk")
TINY = dict(
    latent=8,
    enc_hidden=16,
    neutral_layers=2,
    style_layers=1,
    dec_hidden=(16, 32),
    disc_channels=(16, 16),
    cls_channels=(16, 16),
    window_s=0.6,
    batch_size=6,
    classifier_batch_size=6,
    threads=1,
)


@pytest.fixture(scope="module", autouse=True)
def one_thread():
    """Tiny tensors: one thread is fastest, and two spin-waiting threads crawl on a busy 2-core machine."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def clips():
    """Six rendered synthetic clips: two contents x three styles (about 3 s of rendering)."""
    rng = np.random.default_rng(0)
    return [
        spec_to_clip(sample_spec(rng, content, style, seed=10 * i + j), f"{content}_{style}")
        for i, content in enumerate(CONTENTS)
        for j, style in enumerate(STYLES[:3])
    ]


def make_net(clips, **sizes) -> ErdNetwork:
    torch.manual_seed(0)
    net = ErdNetwork(StyleErdConfig(styles=STYLES, contents=CONTENTS, **sizes))
    # the output offset starts at zero (identity); give it weights, as training would
    torch.nn.init.normal_(net.decoder.layers[-1].weight, std=0.1)
    norm = compute_mean_std(c.motion for c in clips)
    net.set_normalizer(torch.from_numpy(norm.mean), torch.from_numpy(norm.std))
    return net.eval()


def run_stream(stylizer: StreamingStylizer, motion: np.ndarray, switch: dict[int, dict] | None = None) -> np.ndarray:
    out = []
    for t, frame in enumerate(motion):
        if switch and t in switch:
            stylizer.set_style(**switch[t])
        y = stylizer.step(frame)
        if t < stylizer.lag:
            assert y is None
        else:
            out.append(y)
    last = stylizer.flush()
    if stylizer.lag:
        out.append(last)
    else:
        assert last is None
    return np.stack(out)


# ---- network --------------------------------------------------------------------------------------------


def test_frame_layout_matches_features() -> None:
    assert frame_slices(22) == feature_slices(T2M)
    assert StyleErdConfig().frame_dim == T2M.feature_dim == 263
    with pytest.raises(ValueError, match="neutral"):
        StyleErdConfig(styles=("proud", "neutral"))


def test_shapes(clips) -> None:
    net = make_net(clips)
    cfg = net.config
    b, t = 3, 11
    x = torch.randn(b, t, cfg.frame_dim)
    src = net.style_onehot(torch.tensor([0, 1, 2]))
    con = net.content_onehot(torch.tensor([0, 1, cfg.unknown_content]))
    tgt = net.style_onehot(torch.tensor([1, 0, 3]))
    y, state = net(x, src, con, tgt)
    assert y.shape == (b, t, cfg.frame_dim)
    assert state.h.shape == (cfg.style_layers, cfg.n_styles, b, cfg.latent)
    assert state.h_top.shape == (cfg.neutral_layers - cfg.style_layers, b, cfg.latent)
    y1, state1 = net.step(x[:, 0], net.initial_state(con), src, con, tgt)
    assert y1.shape == (b, cfg.frame_dim) and state1.c.shape == state.c.shape
    disc = FtAttDiscriminator(cfg)
    assert disc(torch.randn(b, cfg.disc_window, cfg.frame_dim), src, con).shape == (b,)
    with pytest.raises(ValueError, match="window"):
        disc(torch.randn(b, cfg.disc_window + 1, cfg.frame_dim), src, con)
    cls = ContentClassifier(cfg)
    assert cls(x).shape == (b, len(CONTENTS))
    assert cls.features(x).shape == (b, cfg.cls_channels[1], t)


def test_batched_forward_equals_single_steps(clips) -> None:
    """Paper-size network; per-row, per-frame targets incl. a mid-sequence switch and blends (sec. 4.4)."""
    net = make_net(clips)
    cfg = net.config
    g = torch.Generator().manual_seed(1)
    b, t = 3, 40
    x = torch.randn(b, t, cfg.frame_dim, generator=g)
    src = net.style_onehot(torch.tensor([0, 2, 1]))
    con = net.content_onehot(torch.tensor([1, 0, cfg.unknown_content]))
    target = torch.zeros(b, t, cfg.n_styles)
    target[0, :, 1] = 1.0
    target[1, :20, 0], target[1, 20:, 3] = 1.0, 1.0  # switch neutral -> angry at frame 20
    target[2] = torch.softmax(torch.randn(t, cfg.n_styles, generator=g), -1)
    with torch.no_grad():
        y, final = net(x, src, con, target)
        state, steps = net.initial_state(con), []
        for i in range(t):
            yi, state = net.step(x[:, i], state, src, con, target[:, i])
            steps.append(yi)
    torch.testing.assert_close(torch.stack(steps, 1), y, atol=1e-5, rtol=0)
    for a, b_ in zip(final, state):
        torch.testing.assert_close(a, b_, atol=1e-5, rtol=0)
    # skipping idle branches changes nothing for the output
    with torch.no_grad():
        y_skip, _ = net(x, src, con, target, skip_idle=True)
    torch.testing.assert_close(y_skip, y, atol=1e-6, rtol=0)
    # and the residual branches matter: a different target gives a different output
    with torch.no_grad():
        y_other, _ = net(x, src, con, net.style_onehot(torch.tensor([2, 2, 2])))
    assert (y_other - y).abs().max() > 1e-3


def test_stream_equals_transfer_after_one_frame_lag(clips) -> None:
    net = make_net(clips)
    motion = clips[1].motion
    offline = transfer(net, [clips[0].motion, motion], "old", source_style="proud", source_content="walk")[1]
    stream = StreamingStylizer(net, "old", source_style="proud", source_content="walk")
    assert stream.lag == 1
    online = run_stream(stream, motion)
    assert online.shape == offline.shape == motion.shape
    np.testing.assert_allclose(online, offline, atol=1e-5, rtol=0)
    # re-derived channels are consistent with the stylized poses: frame t's local_vel from poses t, t+1
    np.testing.assert_allclose(rederive_forward(online[:-1], online[1:]), online[:-1], atol=1e-5, rtol=0)
    # without re-derivation there is no lag, and the network's own velocities come out
    raw = run_stream(StreamingStylizer(net, "old", 1.0, "proud", "walk", rederive_velocities=False), motion)
    offline_raw = transfer(net, [motion], "old", "proud", "walk", rederive_velocities=False)[0]
    np.testing.assert_allclose(raw, offline_raw, atol=1e-5, rtol=0)
    assert np.abs(raw[:-1] - online[:-1]).max() > 1e-4  # the two modes really differ
    np.testing.assert_allclose(raw[-1], online[-1], atol=1e-5, rtol=0)  # flush: predicted velocities


def test_set_style_mid_stream_matches_batched_schedule(clips) -> None:
    net = make_net(clips)
    motion = clips[3].motion[:30]
    switch = {12: {"style": "angry"}, 20: {"style": "proud", "blend_with": "old", "alpha": 0.3, "intensity": 0.7}}
    online = run_stream(StreamingStylizer(net, "old", rederive_velocities=False), motion, switch)
    schedule = torch.zeros(1, len(motion), net.config.n_styles)
    schedule[0, :12] = net.mixture("old")
    schedule[0, 12:20] = net.mixture("angry")
    schedule[0, 20:] = net.mixture("proud", 0.7, "old", 0.3)
    src = net.style_onehot(torch.tensor([0]))
    con = net.content_onehot(torch.tensor([net.config.unknown_content]))
    with torch.no_grad():
        y, _ = net(net.normalize(torch.from_numpy(motion))[None], src, con, schedule)
    expected = net.denormalize(y)[0].numpy()
    rot = feature_slices(T2M)["rot"]
    keep = np.ones(motion.shape[1], bool)
    keep[rot] = False  # the stream projects rotations; compare the rest exactly
    np.testing.assert_allclose(online[:, keep], expected[:, keep], atol=1e-5, rtol=0)


def test_reset_restores_initial_state(clips) -> None:
    net = make_net(clips)
    motion = clips[2].motion[:25]
    stream = StreamingStylizer(net, "proud", source_content="jump")
    fresh = [s.clone() for s in stream.state]
    first = run_stream(stream, motion)
    assert any((a - b).abs().max() > 1e-4 for a, b in zip(stream.state, fresh))
    stream.step(motion[0])  # leave a frame pending too
    stream.reset()
    assert stream.frames_seen == 0 and stream.flush() is None
    for a, b in zip(stream.state, fresh):
        torch.testing.assert_close(a, b, atol=0, rtol=0)
    np.testing.assert_array_equal(run_stream(stream, motion), first)


def test_blending_and_intensity(clips) -> None:
    net = make_net(clips)
    motion = clips[0].motion[:30]

    def out(style, **kw):
        return transfer(net, [motion], style, **kw)[0]

    pure = out("proud")
    np.testing.assert_array_equal(out("proud", blend_with="old", alpha=1.0), pure)
    np.testing.assert_array_equal(out("old", blend_with="proud", alpha=0.0), pure)
    np.testing.assert_array_equal(out("proud", intensity=0.0), out("neutral"))
    half = out("proud", blend_with="old", alpha=0.5)
    assert np.abs(half - pure).max() > 1e-4 and np.abs(half - out("old")).max() > 1e-4
    # the same in a stream
    stream = StreamingStylizer(net, "angry")
    stream.set_style("proud", blend_with="old", alpha=1.0)
    np.testing.assert_allclose(run_stream(stream, motion), pure, atol=1e-5, rtol=0)


def test_rederived_velocities_match_the_extractor(clips) -> None:
    sl = feature_slices(T2M)
    for clip in clips:
        m = clip.motion
        r = rederive_forward(m[:-1], m[1:])
        np.testing.assert_allclose(r[:, sl["local_vel"]], m[:-1, sl["local_vel"]], atol=1e-5, rtol=0)
        np.testing.assert_array_equal(r[:, sl["feet"]], m[:-1, sl["feet"]])
        np.testing.assert_array_equal(r[:, : sl["local_vel"].start], m[:-1, : sl["local_vel"].start])


# ---- training -------------------------------------------------------------------------------------------


def test_training_steps_lower_generator_and_critic_losses(clips) -> None:
    """Each player's real update lowers its own loss on a fixed batch; a few full steps lower reconstruction.

    The paper's decoder (no output skip), whose reconstruction starts far from zero."""
    config = ErdTrainConfig(
        steps=1, classifier_steps=1, lr_generator=3e-3, lr_discriminator=3e-3, residual_output=False, **TINY
    )
    torch.manual_seed(0)
    trainer = ErdTrainer(prepare_data(clips, config=config), config)
    batch = trainer.sample()
    assert set(batch["target"][batch["style"] == 0].tolist()) <= {1, 2}  # neutral -> another style
    assert set(batch["target"][batch["style"] != 0].tolist()) <= {0}  # other styles -> neutral
    before = trainer.losses(batch)
    for _ in range(4):
        trainer.critic_step(batch)
    mid = trainer.losses(batch)
    assert mid["dis"] < before["dis"], (before, mid)
    assert mid["rec"] == before["rec"]  # the critic's update leaves the generator alone
    critic = {k: v.clone() for k, v in trainer.disc.state_dict().items()}
    for _ in range(4):
        trainer.generator_step(batch)
    after = trainer.losses(batch)
    assert after["gen"] < mid["gen"], (mid, after)
    assert all(torch.equal(v, trainer.disc.state_dict()[k]) for k, v in critic.items())  # and vice versa
    for _ in range(4):
        trainer.train_step(batch)
    assert trainer.losses(batch)["rec"] < before["rec"]


def test_style_supervision_lowers_moment_and_style_losses(clips) -> None:
    """The shipped recipe: output skip (starts as the identity), neutral-heavy batches, moment + style losses."""
    config = ErdTrainConfig(
        steps=1, classifier_steps=20, lr_generator=3e-3, neutral_share=0.5, w_moments=1.0, w_style=0.5, **TINY
    )
    torch.manual_seed(0)
    trainer = ErdTrainer(prepare_data(clips, config=config), config)
    info = trainer.train_classifier()
    assert 0.0 <= info["style_accuracy"] <= 1.0
    batch = trainer.sample()
    assert int((batch["style"] == 0).sum()) == 3  # half of the 6 rows from neutral clips
    before = trainer.losses(batch)
    assert before["rec"] < 1e-10  # the skip starts as the identity: style -> same style is exact
    for _ in range(8):
        trainer.generator_step(batch)
    after = trainer.losses(batch)
    assert after["moments"] < before["moments"] and after["style"] < before["style"], (before, after)
    mu, sd = trainer.moments
    assert mu.shape == sd.shape == (3, len(CONTENTS) + 1, 263)


def test_table1_ablation_switches(clips) -> None:
    """w/o attention: a multi-class critic (one head per style); w/o learnt initial states: zero states that stay."""
    config = ErdTrainConfig(steps=1, classifier_steps=1, attention=False, learned_init=False, **TINY)
    torch.manual_seed(0)
    trainer = ErdTrainer(prepare_data(clips, config=config), config)
    assert trainer.disc.style_heads is not None
    batch = trainer.sample()
    for _ in range(2):
        trainer.train_step(batch)
    rec = trainer.net.recurrent
    for p in (rec.h0_neutral, rec.c0_neutral, rec.h0_style, rec.c0_style):
        assert not p.requires_grad and not p.any()


def test_training_is_deterministic_and_loads(clips, tmp_path) -> None:
    config = ErdTrainConfig(steps=3, classifier_steps=2, log_every=2, **TINY)
    metrics: list[tuple[int, int]] = []
    a = train_erd(clips, tmp_path / "a", config, progress=lambda s, n, m: metrics.append((s, n)))
    b = train_erd(clips, tmp_path / "b", config)
    c = train_erd(clips, tmp_path / "c", config.model_copy(update={"seed": 1}))
    digest = {k: hashlib.sha256((p / "erd.safetensors").read_bytes()).hexdigest() for k, p in zip("abc", (a, b, c))}
    assert digest["a"] == digest["b"] != digest["c"]
    assert metrics == [(i, 5) for i in range(1, 6)]
    art = read_artifact(a)
    assert art.styles == ["neutral", "old", "proud"] and art.contents == list(CONTENTS)
    assert [h["step"] for h in art.history] == [2.0, 3.0] and art.data["disc_window_frames"] == 8
    assert art.history == read_artifact(b).history
    assert not list(tmp_path.glob(".*"))  # no temporary folders left behind
    net = load_erd(a)
    assert not net.training and net.config.styles == ("neutral", "old", "proud")
    np.testing.assert_allclose(net.mean.numpy(), art.normalizer["mean"])
    y = transfer(net, [clips[0].motion], "old", source_content="jump")[0]
    assert y.shape == clips[0].motion.shape and np.isfinite(y).all()
    train_erd(clips, a, config.model_copy(update={"seed": 1}))  # replacing an existing folder
    assert hashlib.sha256((a / "erd.safetensors").read_bytes()).hexdigest() == digest["c"]


def test_config_rejects_unknown_fields() -> None:
    with pytest.raises(ValidationError):
        ErdTrainConfig(stepz=10)
    with pytest.raises(ValidationError):
        ErdTrainConfig(window_s=0.2, disc_window_s=0.4)


# ---- bad input ------------------------------------------------------------------------------------------


def test_bad_stream_input_raises_motion_data_error(clips) -> None:
    net = make_net(clips, latent=8, neutral_layers=2, style_layers=1)
    stream = StreamingStylizer(net, "proud")
    frame = clips[0].motion[0]
    stream.step(frame)
    cases = [
        (lambda: stream.step(frame[:-1]), "expected shape"),
        (lambda: stream.step(frame[None]), "expected shape"),
        (lambda: stream.step(np.where(np.arange(263) == 5, np.nan, frame)), "NaN"),
        (lambda: stream.set_style("zombie"), "unknown style"),
        (lambda: stream.set_style("proud", blend_with="zombie"), "unknown style"),
        (lambda: stream.set_style("proud", intensity=1.5), "outside"),
        (lambda: StreamingStylizer(net, "zombie"), "unknown style"),
        (lambda: StreamingStylizer(net, "proud", source_content="swim"), "unknown content"),
        (lambda: transfer(net, [np.full((4, 263), np.nan, np.float32)], "proud"), "NaN"),
        (lambda: transfer(net, [frame], "proud"), "expected"),
    ]
    for call, words in cases:
        with pytest.raises(MotionDataError, match=words) as err:
            call()
        assert "\n" not in str(err.value)
    assert stream.frames_seen == 1 and stream.style == "proud"  # bad input left the stream as it was
    assert stream.step(frame) is not None


@loss_terms.register("test-joint-l1")
class JointL1(LossTerm):
    """A loss term as the lab writes one: mean distance of the predicted joints from the target's, metres."""

    def __call__(self, batch: LossBatch) -> torch.Tensor:
        return (batch.predicted - batch.target).norm(dim=-1)[batch.mask].mean()


def test_a_registered_loss_term_joins_the_generator_loss(clips) -> None:
    """``train.loss_terms`` plug into Style-ERD's generator loss on its reconstruction's joints (a hook, not a
    setting: with none, the config's dump is the one models were trained and keyed with before)."""
    assert "loss_terms" not in ErdTrainConfig(**TINY).model_dump()
    term = {"name": "test-joint-l1", "weight": 2.0}
    config = ErdTrainConfig(steps=1, lr_generator=3e-3, residual_output=False, loss_terms=(term,), **TINY)
    assert ErdTrain(loss_terms=(term,)).recipe().loss_terms == (term,)
    torch.manual_seed(0)
    trainer = ErdTrainer(prepare_data(clips, config=config), config)
    batch = trainer.sample()
    before = trainer.losses(batch)
    assert before["test-joint-l1"] > 0
    for _ in range(6):
        trainer.generator_step(batch)
    assert trainer.losses(batch)["test-joint-l1"] < before["test-joint-l1"]
    with pytest.raises(ValueError, match="unknown loss term 'nope'"):
        ErdTrainConfig(loss_terms=("nope",))


# ---- a style the network was not trained on ------------------------------------------------------------------


def test_a_new_style_is_a_branch_fitted_from_its_examples_with_every_trained_part_kept(clips, tmp_path) -> None:
    """``old`` is absent from training; its branch is fitted from its clips alone, the trained styles keep their
    outputs bit for bit, the moment loss falls, the fit repeats exactly and its saved weights rebuild it."""
    from safetensors.torch import load_file

    from motionaug.augment.methods.erd.branch import ErdBranchFit, apply_branch, branch_tensors, fit_branch

    seen = [c for c in clips if c.style != "old"]
    folder = train_erd(seen, tmp_path / "erd", ErdTrainConfig(steps=3, classifier_steps=2, **TINY))
    net = load_erd(folder)
    assert "old" not in net.config.styles
    examples = [c.motion for c in clips if c.style == "old"]
    pool = {c.id: c.motion for c in clips if c.style == "neutral"}
    critics = load_file(str(folder / "critics.safetensors"))
    art = read_artifact(folder)
    fit = ErdBranchFit(steps=20, batch_size=4)
    args = (critics, "old", examples, pool, fit, art.data["window_frames"], 4, 0)
    grown, history = fit_branch(net, *args)
    again, _ = fit_branch(load_erd(folder), *args)

    assert grown.config.styles == (*net.config.styles, "old")
    assert history[-1]["moments"] < history[0]["moments"]
    before = transfer(net, [clips[0].motion], "proud")[0]
    # kept up to float rounding: the grown network stacks one more branch, so its batched matmuls have other shapes
    # and a CPU's BLAS may sum them in another order (a last-bit difference on some machines, none on others)
    np.testing.assert_allclose(transfer(grown, [clips[0].motion], "proud")[0], before, rtol=0, atol=1e-6)
    styled = transfer(grown, [clips[0].motion], "old")[0]
    assert np.isfinite(styled).all() and not np.array_equal(styled, before)
    np.testing.assert_array_equal(transfer(again, [clips[0].motion], "old")[0], styled)
    rebuilt = apply_branch(load_erd(folder), "old", {k: v.clone() for k, v in branch_tensors(grown).items()})
    np.testing.assert_array_equal(transfer(rebuilt, [clips[0].motion], "old")[0], styled)
    with pytest.raises(MotionDataError, match="missing weights"):
        apply_branch(load_erd(folder), "old", {"w_ih": branch_tensors(grown)["w_ih"]})
    with pytest.raises(ValueError, match="already"):
        net.with_style("proud")
