"""Pretraining: geometric losses, training batches, the three stages, resume, base-models round trip, reuse."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from pydantic import ValidationError
from safetensors.torch import load_file

from motionaug.augment.corpus.fingerprint import corpus_fingerprint
from motionaug.augment.device import DEVICE_ENV
from motionaug.augment.diffusion import NoiseSchedule
from motionaug.augment.diffusion.gaussian import sample_timesteps
from motionaug.augment.eval.evaluation import load_classifiers
from motionaug.augment.motion.features import Normalizer, feature_slices
from motionaug.augment.synth import generate_corpus
from motionaug.augment.training.base_models import BaseModels, BaseModelsInfo
from motionaug.augment.training.data import (
    build_motion_set,
    iter_batches,
    read_clips,
    sample_batch,
    share_weights,
    split_ids,
)
from motionaug.augment.training.geometric_losses import (
    foot_contact_loss,
    geometric_losses,
    joint_position_loss,
    joint_velocity_loss,
)
from motionaug.augment.training.pretrain import (
    PretrainConfig,
    Run,
    _load_data,
    build_prior,
    ensure_base_models,
    pretrain,
    prior_loss,
    skeleton_for,
)
from motionaug.models.mdm import MDM, MDMConfig
from motionaug.models.motion_encoder import MotionEncoder, MotionEncoderConfig
from motionaug.models.text_encoder import make_text_encoder
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.skeleton import T2M

MODULES = ("prior", "motion_encoder", "evaluators/content_classifier", "evaluators/style_classifier")


class Interrupt(Exception):
    """Raised from the progress callback to stop a run mid-stage, as a killed process would."""


def tiny_config(**overrides: object) -> PretrainConfig:
    defaults = {
        "prior_steps": 24,
        "encoder_steps": 16,
        "classifier_epochs": 3,
        "checkpoint_every": 10,
        "threads": 1,
        "log_every": 1,
        "bf16": False,
        "max_frames": 60,
    }
    return PretrainConfig.for_size("tiny", **{**defaults, **overrides})


@pytest.fixture(scope="module", autouse=True)
def on_cpu():
    """These tests compare weights bit for bit, which CUDA kernels do not promise: CPU even where a GPU is
    (tests/test_pretrain_device.py covers CUDA)."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv(DEVICE_ENV, "cpu")
        yield


@pytest.fixture(scope="module")
def text_encoder():
    return make_text_encoder("minilm")


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("pretrain") / "corpus"
    generate_corpus(root, 24, seed=0)
    return root


@pytest.fixture(scope="module")
def baseline(corpus: Path, text_encoder, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, BaseModelsInfo]:
    out = tmp_path_factory.mktemp("pretrain") / "base"
    return out, pretrain(corpus, out, tiny_config(), text_encoder=text_encoder)


def real_features(corpus: Path, n: int = 2) -> list[np.ndarray]:
    return [np.load(p) for p in sorted((corpus / "new_joint_vecs").glob("*.npy"))[:n]]


def padded(features: list[np.ndarray], frames: int) -> tuple[torch.Tensor, torch.Tensor]:
    x = torch.zeros(len(features), frames, features[0].shape[1])
    mask = torch.zeros(len(features), frames, dtype=torch.bool)
    for i, f in enumerate(features):
        n = min(len(f), frames)
        x[i, :n] = torch.from_numpy(f[:n])
        mask[i, :n] = True
    return x, mask


# ---- geometric losses ---------------------------------------------------------------------------


def test_geometric_losses_are_zero_for_identical_motions_and_positive_otherwise(corpus: Path) -> None:
    x, mask = padded(real_features(corpus), 50)
    same = geometric_losses(x, x.clone(), mask)
    assert all(torch.equal(v, torch.zeros(2)) for v in same.values())
    moved = x.clone()
    moved[..., feature_slices(T2M)["ric"]] += 0.05 * torch.randn_like(moved[..., feature_slices(T2M)["ric"]])
    diff = geometric_losses(moved, x, mask)
    assert all((v > 0).all() for v in diff.values())


def test_foot_contact_loss_counts_only_planted_frames() -> None:
    target = torch.zeros(1, 4, 22, 3)
    pred = target.clone()
    pred[0, :, 7, 0] = torch.tensor([0.0, 0.1, 0.2, 0.3])  # predicted left ankle slides 10 cm per frame
    planted = torch.zeros(1, 4, 4)
    assert float(foot_contact_loss(pred, target, planted)) == 0.0
    planted[0, :, 0] = 1.0  # the target says the left ankle is planted
    assert float(foot_contact_loss(pred, target, planted)) == pytest.approx(0.01 / 4)  # one of four feet channels
    assert float(foot_contact_loss(target, target, planted)) == 0.0


def test_padding_never_reaches_the_geometric_losses_or_their_gradient(corpus: Path) -> None:
    x, mask = padded(real_features(corpus), 80)
    mask[0, 30:] = False
    pred = (x + 0.01 * torch.randn_like(x)).requires_grad_(True)
    losses = geometric_losses(pred, x, mask)
    junk = pred.detach().clone()
    junk[0, 30:] = torch.randn_like(junk[0, 30:]) * 1e3
    junk_target = x.clone()
    junk_target[0, 30:] = float("nan")
    again = geometric_losses(junk, junk_target, mask)
    for name in losses:
        torch.testing.assert_close(again[name], losses[name].detach())
    sum(v.sum() for v in losses.values()).backward()
    assert pred.grad is not None and torch.all(pred.grad[0, 30:] == 0) and pred.grad[0, :30].abs().sum() > 0


def test_input_perturbation_adds_exactly_its_extra_noise_to_the_prior_input(
    corpus: Path, text_encoder, tmp_path: Path
) -> None:
    """DDPM-IP: same batch, timesteps and first noise; the input differs by sqrt(1 - ab_t) * gamma * N(0, I)."""
    normalizer, train, test = _load_data(corpus, text_encoder)
    schedule, gamma = NoiseSchedule.cosine(), 0.5
    batch = sample_batch(train, 64, 60, torch.Generator().manual_seed(0))
    inputs = []
    for g in (0.0, gamma):
        cfg = tiny_config(input_perturbation=g)
        run = Run(cfg, tmp_path, normalizer, skeleton_for(normalizer.dim), train, test, "test", None)
        prior = build_prior(cfg, normalizer.dim, train.text_embed.shape[1])
        hook = prior.register_forward_pre_hook(lambda _m, args: inputs.append(args[0].detach().clone()))
        loss, _ = prior_loss(prior, schedule, batch, run, torch.Generator().manual_seed(1))
        hook.remove()
        assert torch.isfinite(loss)
    t = sample_timesteps(64, schedule, torch.Generator().manual_seed(1))  # the draw prior_loss makes first
    scale = (1 - schedule.alphas_cumprod[t]).sqrt()[:, None, None] * gamma
    extra = (inputs[1] - inputs[0]) / scale
    assert abs(float(extra.std()) - 1.0) < 0.05 and abs(float(extra.mean())) < 0.05


def test_geometric_losses_reject_mismatched_shapes() -> None:
    with pytest.raises(MotionDataError, match="prediction"):
        joint_position_loss(torch.zeros(1, 3, 22, 3), torch.zeros(1, 4, 22, 3))
    with pytest.raises(MotionDataError, match="mask"):
        joint_velocity_loss(torch.zeros(1, 3, 22, 3), torch.zeros(1, 3, 22, 3), torch.ones(1, 4, dtype=torch.bool))


# ---- training data ------------------------------------------------------------------------------


def test_training_batches_crop_pad_mask_and_caption(corpus: Path, text_encoder) -> None:
    normalizer = Normalizer.load(corpus)
    clips = read_clips(corpus, split_ids(corpus, "train"))
    data = build_motion_set(clips, normalizer, text_encoder)
    assert (
        len(data.texts) == len({c.text for clip in clips for c in clip.captions}) <= sum(len(c.captions) for c in clips)
    )
    assert data.text_embed.shape == (len(data.texts), 384)
    assert set(data.content.tolist()) <= set(range(len(data.content_labels))) and data.style.min() >= 0
    batch = sample_batch(data, 6, 40, torch.Generator().manual_seed(0), bucket=8)
    assert batch.motion.shape[1] <= 40 and batch.motion.dtype == torch.float32
    for row, i in enumerate(batch.index.tolist()):
        n = int(batch.mask[row].sum())
        assert n == min(40, data.motions[i].shape[0]) and torch.all(batch.motion[row, n:] == 0)
        assert bool(batch.mask[row, :n].all())
        options = data.text_embed[data.captions[i]]
        assert any(torch.equal(batch.text_embed[row], o) for o in options)
    first = next(iter_batches(data, 4, 1000))
    torch.testing.assert_close(first.motion[0, : data.motions[0].shape[0]], data.motions[0])
    again = sample_batch(data, 6, 40, torch.Generator().manual_seed(0), bucket=8)
    assert torch.equal(again.motion, batch.motion) and torch.equal(again.index, batch.index)


def test_weighted_draws_give_the_added_clips_their_share(corpus: Path, text_encoder) -> None:
    data = build_motion_set(read_clips(corpus, split_ids(corpus, "train")), Normalizer.load(corpus), text_encoder)
    rows_added = list(range(0, len(data), 3))  # spread over every length, as an expansion's clips are
    weights = share_weights(data.ids, [data.ids[i] for i in rows_added], 0.8)  # uniform would give them ~1/3
    assert torch.isclose(weights.sum(), torch.tensor(1.0, dtype=weights.dtype))
    generator = torch.Generator().manual_seed(0)
    for bucket in (None, 8):
        rows = torch.cat([sample_batch(data, 50, 40, generator, bucket, weights).index for _ in range(100)])
        share = float(np.isin(rows.numpy(), rows_added).mean())
        assert abs(share - 0.8) < 0.05, (bucket, share)
    for wrong in ([], data.ids):
        with pytest.raises(MotionDataError, match="added_share"):
            share_weights(data.ids, wrong, 0.5)


def test_split_without_files_is_a_stable_hash_split(corpus: Path, tmp_path: Path) -> None:
    copy = tmp_path / "c"
    shutil.copytree(corpus, copy)
    for name in ("train.txt", "test.txt", "val.txt"):
        (copy / name).unlink()
    train, test = split_ids(copy, "train"), split_ids(copy, "test")
    assert sorted(train + test) == sorted(split_ids(corpus, "all")) and not set(train) & set(test)
    assert split_ids(copy, "test") == test


# ---- pretraining --------------------------------------------------------------------------------


def losses_of(out: Path, stage: str) -> list[float]:
    lines = [json.loads(x) for x in (out / "loss_log.jsonl").read_text().splitlines()]
    return [x["loss"] for x in lines if x["stage"] == stage and "loss" in x]


def test_each_stage_lowers_its_loss(baseline: tuple[Path, BaseModelsInfo]) -> None:
    out, info = baseline
    for stage in ("prior", "motion_encoder", "evaluators_content_classifier", "evaluators_style_classifier"):
        losses = losses_of(out, stage)
        k = max(1, len(losses) // 4)
        assert np.mean(losses[-k:]) < np.mean(losses[:k]), (stage, losses)
    assert {"prior_test_mse", "encoder_test_loss", "content_classifier_accuracy", "style_classifier_accuracy"} <= set(
        info.metrics
    )
    assert info.corpus_fingerprint and info.config_hash == tiny_config().config_hash()


def test_interrupted_runs_resume_to_identical_weights(
    corpus: Path, baseline: tuple[Path, BaseModelsInfo], text_encoder, tmp_path: Path
) -> None:
    out = tmp_path / "resumed"
    for stop_stage, stop_step in (("prior", 17), ("motion_encoder", 13)):

        def stop(stage: str, step: int, total: int, metrics: dict[str, float], at=(stop_stage, stop_step)) -> None:
            if (stage, step) == at:
                raise Interrupt(f"{stage} {step}")

        with pytest.raises(Interrupt):
            pretrain(corpus, out, tiny_config(), progress=stop, text_encoder=text_encoder)
        assert not (out / "base.json").exists()
    pretrain(corpus, out, tiny_config(), text_encoder=text_encoder)
    for name in MODULES:
        a, b = load_file(str(baseline[0] / f"{name}.safetensors")), load_file(str(out / f"{name}.safetensors"))
        assert a.keys() == b.keys()
        assert all(torch.equal(a[k], b[k]) for k in a), name


def test_checkpoint_of_another_config_is_refused(corpus: Path, text_encoder, tmp_path: Path) -> None:
    def stop(stage: str, step: int, total: int, metrics: dict[str, float]) -> None:
        if step == 11:
            raise Interrupt

    with pytest.raises(Interrupt):
        pretrain(corpus, tmp_path / "o", tiny_config(), progress=stop, text_encoder=text_encoder)
    with pytest.raises(MotionDataError, match="checkpoint was made with config"):
        pretrain(corpus, tmp_path / "o", tiny_config(lr=2e-3), text_encoder=text_encoder)


def test_base_models_round_trip_gives_identical_outputs(baseline: tuple[Path, BaseModelsInfo], text_encoder) -> None:
    out, _ = baseline
    loaded = BaseModels.load(out, text_encoder=text_encoder)
    again = BaseModels.load(out, text_encoder=text_encoder)
    x = torch.randn(2, 30, 263)
    mask = torch.ones(2, 30, dtype=torch.bool)
    text = torch.randn(2, 384)
    t = torch.tensor([10, 500])
    torch.testing.assert_close(loaded.prior(x, t, text, mask), again.prior(x, t, text, mask), rtol=0, atol=0)
    torch.testing.assert_close(loaded.motion_encoder(x, mask), again.motion_encoder(x, mask), rtol=0, atol=0)
    assert torch.equal(
        loaded.motion_encoder.embed.poseEmbedding.weight, loaded.prior.input_process.poseEmbedding.weight
    )
    joints = torch.randn(2, 30, 22, 3)
    judges, judges_again = load_classifiers(out), load_classifiers(out)  # the evaluators: an artefact of their own
    assert judges.source == str(out / "evaluators") and judges.content is not None and judges.style is not None
    assert torch.equal(judges.content(joints, mask), judges_again.content(joints, mask))
    assert len(judges.content_labels) == judges.content.config.n_classes
    assert loaded.content_classifier is None  # the bundle a method loads carries no evaluator


def test_motion_encoder_state_dict_keys_match_standalone_and_shared() -> None:
    mdm = MDM(MDMConfig.named("tiny", text_dim=384))
    config = MotionEncoderConfig.named("tiny", d_model=64)
    assert MotionEncoder(config, mdm.input_process).state_dict().keys() == MotionEncoder(config).state_dict().keys()


def test_ensure_base_models_reuses_a_match_and_retrains_on_corpus_change(
    corpus: Path, baseline: tuple[Path, BaseModelsInfo], text_encoder, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    out = tmp_path / "base"
    shutil.copytree(baseline[0], out)
    before = (out / "prior.safetensors").stat().st_mtime_ns
    calls: list[str] = []
    assert ensure_base_models(corpus, out, "tiny", config=tiny_config(), progress=lambda *a: calls.append(a[0])) == out
    assert not calls and (out / "prior.safetensors").stat().st_mtime_ns == before
    changed = tmp_path / "corpus"
    shutil.copytree(corpus, changed)
    assert corpus_fingerprint(changed) == corpus_fingerprint(corpus)
    caption = next((changed / "texts").glob("*.txt"))
    caption.write_text("a person hops on one leg.#a/DET person/NOUN hop/VERB#0.0#0.0\n")
    assert corpus_fingerprint(changed) != corpus_fingerprint(corpus)
    ensure_base_models(
        changed, out, "tiny", config=tiny_config(), progress=lambda *a: calls.append(a[0]), text_encoder=text_encoder
    )
    assert "prior" in calls
    assert "made from another corpus or pre-training config; pre-training again" in caplog.text
    assert BaseModelsInfo.model_validate_json((out / "base.json").read_text()).corpus_fingerprint == corpus_fingerprint(
        changed
    )


def test_a_prior_without_evaluators_is_complete_only_for_a_caller_that_wants_none(
    corpus: Path, baseline: tuple[Path, BaseModelsInfo], text_encoder, tmp_path: Path
) -> None:
    """``pretrain --no-evaluators``: the same prior and encoder, no evaluators folder; one that wants them retrains."""
    from motionaug.augment.training.evaluators import evaluators_folder

    out = tmp_path / "base"
    ensure_base_models(corpus, out, "tiny", config=tiny_config(), text_encoder=text_encoder, evaluators=False)
    assert evaluators_folder(out) is None and evaluators_folder(baseline[0]) is not None
    for name in ("prior", "motion_encoder"):
        assert (out / f"{name}.safetensors").read_bytes() == (baseline[0] / f"{name}.safetensors").read_bytes()
    calls: list[str] = []
    ensure_base_models(
        corpus, out, "tiny", config=tiny_config(), progress=lambda *a: calls.append(a[0]), evaluators=False
    )
    assert not calls  # complete for a caller that wants no evaluators
    ensure_base_models(
        corpus, out, "tiny", config=tiny_config(), progress=lambda *a: calls.append(a[0]), text_encoder=text_encoder
    )
    assert calls and evaluators_folder(out) is not None


def test_bad_inputs_are_one_line_errors(tmp_path: Path) -> None:
    with pytest.raises(ValidationError):
        PretrainConfig(prior_stpes=3)  # type: ignore[call-arg]
    with pytest.raises(MotionDataError, match="does not exist"):
        corpus_fingerprint(tmp_path / "nowhere")
    with pytest.raises(MotionDataError, match="not a HumanML3D folder"):
        corpus_fingerprint(tmp_path)
