"""The official MDM prior as base models: checkpoint files in the official key layout (random weights, tiny widths),
a random-weight CLIP text tower in OpenAI's layout, `motionaug pretrain --from-mdm`, then pairs and transfer."""

from __future__ import annotations

import copy
import gzip
import shutil
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import torch
from conftest import FIXTURES, TWO_STYLES
from test_mdm import official_state_dict
from typer.testing import CliRunner

from motionaug.augment.corpus import Corpus
from motionaug.augment.methods.onthefly.method import OnTheFlyMethod
from motionaug.augment.outputs.run_dir import RunDir
from motionaug.augment.outputs.shards import TransferOutput
from motionaug.augment.synth import generate_corpus
from motionaug.augment.training.base_models import BaseModels
from motionaug.augment.training.from_mdm import MdmSource, infer_mdm_config, load_mdm_prior, pretrain_from_mdm
from motionaug.augment.training.pretrain import PretrainConfig
from motionaug.models.clip_text import VOCAB_FILE, ClipTextConfig, ClipTextTower, ClipTokenizer
from motionaug.models.text_encoder import ClipTextEncoder
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.run_config import load_run_config
from motionaug.schemas.styles import StyleExample, StyleSpec
from motionaug.workflows.cli import app

torch.set_num_threads(1)
D, FF, LAYERS, TEXT = 64, 128, 2, 48  # tiny MDM; CLIP text width 64 projected to 48
STEPS = {"encoder_steps": 4, "classifier_epochs": 1, "batch_size": 4, "max_frames": 64}
MERGES = ["w a", "l k</w>", "wa lk</w>", "p e", "r s", "o n</w>", "pe rs", "t h", "th e</w>"]


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("from_mdm") / "corpus"
    generate_corpus(root, 40, seed=0)
    return root


@pytest.fixture(scope="module")
def unlabelled(corpus: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The corpus as HumanML3D is: captions, no content or style labels."""
    root = tmp_path_factory.mktemp("unlabelled") / "corpus"
    shutil.copytree(corpus, root, ignore=shutil.ignore_patterns("labels.jsonl"))
    return root


@pytest.fixture(scope="module")
def clip_files(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, torch.Tensor]]:
    """A BPE vocabulary in OpenAI's file format and a random CLIP text tower sized to it."""
    folder = tmp_path_factory.mktemp("clip")
    with gzip.open(folder / VOCAB_FILE, "wt", encoding="utf-8") as handle:
        handle.write("\n".join(["#version: 0.2", *MERGES]) + "\n")
    torch.manual_seed(7)
    vocab = ClipTokenizer(folder / VOCAB_FILE).vocab_size
    tower = ClipTextTower(ClipTextConfig(vocab_size=vocab, width=64, layers=2, heads=1, embed_dim=TEXT))
    return folder, {k: v.detach().clone() for k, v in tower.state_dict().items()}


def write_checkpoint(folder: Path, clip_state: dict[str, torch.Tensor] | None) -> Path:
    """``model000475000.pt`` as MDM saves it: a plain state dict, with or without the ``clip_model.*`` keys."""
    state = {k: v for k, v in official_state_dict(D, FF, LAYERS, text=TEXT).items() if not k.startswith("clip_")}
    if clip_state is not None:
        state |= {f"clip_model.{k}": v.half() for k, v in clip_state.items()}  # MDM keeps CLIP in fp16
    folder.mkdir(parents=True, exist_ok=True)
    torch.save(state, folder / "model000475000.pt")
    return folder / "model000475000.pt"


def test_tokenizer_reads_openai_vocabulary_format(clip_files: tuple[Path, dict]) -> None:
    tokenizer = ClipTokenizer(clip_files[0] / VOCAB_FILE)
    assert tokenizer.vocab_size == 512 + len(MERGES) + 2
    a_end = 256 + ord("a") - ord("!")  # "a</w>", 320 as in OpenAI's vocabulary
    assert tokenizer.ids("A   WALK") == tokenizer.ids("a walk") == [a_end, 512 + MERGES.index("wa lk</w>")]
    tokens, eot = tokenizer.encode(["walk", "the person walks on and on and on"], max_tokens=5)
    assert tokens.shape == (2, 7) and eot.tolist() == [2, 6]
    assert tokens[0, 0] == tokenizer.sot and tokens[0, 2] == tokenizer.eot and tokens[0, 3:].eq(0).all()


OPENAI_IDS = {  # open_clip 3.3.0's SimpleTokenizer on OpenAI's vocabulary (tests/fixtures/clip/SOURCE.md)
    "a person walks forward and then turns around.": [320, 2533, 8192, 2342, 537, 1594, 3185, 1630, 269],
    "A man  jumps UP high, twice!": [320, 786, 18911, 705, 1400, 267, 6970, 256],
    "someone's waving their left hand 3 times": [2100, 568, 26545, 911, 1823, 2463, 274, 1661],
    "the person does a cartwheel-like move; then sits down on the floor and rests with both arms crossed over the "
    "chest for a while": [518, 2533, 1897, 320, 27705, 6744, 268, 789, 2783, 282, 1594, 12726, 1136, 525, 518]
    + [4125, 537, 33775, 593, 2212, 5706, 11731, 962, 518, 10563, 556, 320, 1519],
}


def test_tokenizer_gives_openai_ids_with_openai_vocabulary() -> None:
    tokenizer = ClipTokenizer(FIXTURES / "clip" / VOCAB_FILE)
    assert (tokenizer.vocab_size, tokenizer.sot, tokenizer.eot) == (49408, 49406, 49407)
    for text, ids in OPENAI_IDS.items():
        assert tokenizer.ids(text) == ids, text
    long = next(t for t in OPENAI_IDS if t.startswith("the person does"))
    tokens, eot = tokenizer.encode([long], max_tokens=20)  # MDM's cut: clip.tokenize(context_length=22, truncate)
    assert tokens[0].tolist() == [49406, *OPENAI_IDS[long][:20], 49407] and eot.tolist() == [21]


@pytest.mark.filterwarnings("ignore::DeprecationWarning", "ignore::torch.jit.TracerWarning")
def test_clip_tower_reads_caption_until_eot_only(clip_files: tuple[Path, dict], tmp_path: Path) -> None:
    folder, state = clip_files
    torch.save(state, tmp_path / "ViT-B-32.pt")
    encoder = ClipTextEncoder(tmp_path / "ViT-B-32.pt", folder / VOCAB_FILE, normalize=False, max_tokens=20)
    both = encoder.encode(["a walk", "the person walks on and on"])
    assert both.shape == (2, TEXT) and encoder.dim == TEXT
    encoder.clear_cache()
    assert torch.allclose(encoder.encode(["a walk"])[0], both[0], atol=1e-5)  # padding never reaches the EOT
    tower = ClipTextTower.from_state_dict(state)  # OpenAI's ViT-B-32.pt is a TorchScript archive: read it too
    torch.jit.save(torch.jit.trace(tower, (torch.zeros(1, 3, dtype=torch.long), torch.tensor([2]))), tmp_path / "j.pt")
    scripted = ClipTextEncoder(tmp_path / "j.pt", folder / VOCAB_FILE, normalize=False, max_tokens=20)
    assert torch.allclose(scripted.encode(["a walk", "the person walks on and on"]), both, atol=1e-5)
    torch.save(state | {"ln_final.weight": torch.ones(3)}, tmp_path / "bad.pt")
    with pytest.raises(ValueError, match=r"ln_final.weight: shape \(3,\) != expected \(64,\)"):
        ClipTextEncoder(tmp_path / "bad.pt", folder / VOCAB_FILE)


def test_architecture_is_read_from_the_tensors() -> None:
    paper = infer_mdm_config(official_state_dict())
    shape = (paper.latent_dim, paper.ff_size, paper.num_layers, paper.text_dim, paper.n_feats)
    assert shape == (512, 1024, 8, 512, 263)  # the case: the text width is read, not the 384 preset
    tiny = official_state_dict(D, FF, LAYERS, text=TEXT)
    assert load_mdm_prior(tiny, 263).config.text_dim == TEXT
    bad = dict(tiny) | {"seqTransEncoder.layers.1.linear2.weight": torch.zeros(D, 99)}
    with pytest.raises(MotionDataError, match=r"layers.1.linear2.weight: shape \(64, 99\), expected \(64, 128\) for"):
        infer_mdm_config(bad)
    with pytest.raises(MotionDataError, match="poseEmbedding.weight: reads 263-wide features, corpus has 251"):
        infer_mdm_config(tiny, n_feats=251)
    with pytest.raises(MotionDataError, match="'trans_dec' checkpoint"):
        infer_mdm_config(dict(tiny) | {"seqTransDecoder.layers.0.linear1.weight": torch.zeros(1)})


def test_missing_clip_or_stats_is_one_line(
    corpus: Path, clip_files: tuple[Path, dict], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))  # no ~/.cache/clip/ViT-B-32.pt either
    checkpoint = write_checkpoint(tmp_path / "mdm", None)
    config = PretrainConfig.for_size("tiny", **STEPS)
    with pytest.raises(MotionDataError, match=r"CLIP ViT-B/32 text encoder: .* pass --clip-weights FILE"):
        pretrain_from_mdm(corpus, tmp_path / "out", MdmSource(checkpoint), config)
    with pytest.raises(MotionDataError, match=r"Mean.npy: missing; the official MDM prior needs HumanML3D's"):
        pretrain_from_mdm(corpus, tmp_path / "out", MdmSource(checkpoint, stats=tmp_path), config)


def test_pretrain_from_mdm_then_pairs_and_transfer(
    unlabelled: Path, clip_files: tuple[Path, dict], tmp_path: Path
) -> None:
    """Checkpoint with clip_model.* keys, the vocabulary beside it, prior statistics that differ from the corpus's,
    and a corpus without labels, as HumanML3D is."""
    folder, state = clip_files
    checkpoint = write_checkpoint(tmp_path / "mdm", state)
    (tmp_path / "mdm" / VOCAB_FILE).write_bytes((folder / VOCAB_FILE).read_bytes())
    stats = tmp_path / "humanml3d_stats"
    stats.mkdir()
    np.save(stats / "Mean.npy", np.load(unlabelled / "Mean.npy") + 0.01)
    np.save(stats / "Std.npy", np.load(unlabelled / "Std.npy"))
    sets = [f"{k}={v}" for k, v in STEPS.items()]
    args = ["pretrain", "--corpus", str(unlabelled), "--out", str(tmp_path / "base"), "--size", "tiny"]
    args += ["--from-mdm", str(checkpoint), "--mdm-stats", str(stats), *[a for s in sets for a in ("--set", s)]]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    assert "note: the corpus's own Mean/Std differ from the prior's" in result.output
    assert "note: style: no style labels (HumanML3D has none), so no style classifier" in result.output
    base = BaseModels.load(tmp_path / "base")
    assert base.info.text_encoder == "clip" and base.info.prior["text_dim"] == TEXT
    assert np.allclose(base.normalizer.mean, np.load(stats / "Mean.npy"))  # the prior's statistics, not the corpus's
    expected = official_state_dict(D, FF, LAYERS, text=TEXT)["seqTransEncoder.layers.1.linear1.weight"]
    assert torch.equal(base.prior.seqTransEncoder.layers[1].linear1.weight, expected)  # the prior is not retrained
    assert {"encoder_test_loss", "prior_test_mse"} <= set(base.info.metrics)
    assert not list((tmp_path / "base" / "evaluators").glob("*.safetensors"))  # nothing to classify with
    assert base.text_encoder.encode(["a walk"]).shape == (1, TEXT)

    clips = [c for c in Corpus(unlabelled) if c.n_frames >= 40]
    spec = StyleSpec(
        name="proud",
        words=TWO_STYLES[0]["words"],
        examples=[StyleExample(source=clips[0].id, description="a person walks proudly")],
    )
    method = OnTheFlyMethod({**OnTheFlyMethod.smoke_params, "pair_steps": 5, "bf16": False})
    model, fit, _, _ = method.fit(spec, clips[:1], base, corpus=clips[1:3])
    outputs = model.transfer(clips[1:3])
    assert all(isinstance(o, TransferOutput) and np.isfinite(o.motion).all() for o in outputs)
    assert all(np.isfinite(o.scores["content_score"]) for o in outputs)  # how content is judged without labels
    assert fit.curve and np.isfinite(fit.curve[-1]["l_rec"])


@pytest.mark.slow
def test_run_config_from_mdm_on_ray(corpus: Path, clip_files: tuple[Path, dict], tmp_path: Path) -> None:
    """MDM's own training loop drops clip_model.*: the CLIP file comes from method.params.train.clip_weights."""
    import ray

    from motionaug.workflows.pipeline import check_config
    from motionaug.workflows.ray_executor import execute_run

    folder, state = clip_files
    checkpoint = write_checkpoint(tmp_path / "mdm", None)
    torch.save(state, folder / "ViT-B-32.pt")
    data = {
        "corpus": {"path": str(corpus), "filters": {"source_styles": ["neutral"], "min_frames": 40}},
        "styles": copy.deepcopy(TWO_STYLES[:1]),
        "method": {
            "name": "onthefly",
            "params": OnTheFlyMethod.smoke_params
            | {"train": {"from_mdm": str(checkpoint), "clip_weights": str(folder / "ViT-B-32.pt"), **STEPS}},
        },
        "base_models": {"size": "tiny"},
        "compute": {"num_cpus": 2, "batch_size": 4, "unit_size": 8},
        "output": str(tmp_path / "run"),
    }
    config = load_run_config(None, data=data)
    check_config(config)
    try:
        summary = execute_run(config)
    finally:
        if ray.is_initialized():
            ray.shutdown()
    base = BaseModels.load(summary.manifest.base_models)
    assert base.info.source["from_mdm"] == str(checkpoint) and base.info.text_encoder == "clip"
    table = pq.read_table(RunDir(tmp_path / "run").shards_dir)
    assert set(table.column("style").to_pylist()) == {"proud"} and table.num_rows == summary.manifest.rows > 0
