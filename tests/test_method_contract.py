"""Every registered method through the same motions: train -> prepare -> transfer, on a real local Ray.

A method is tested the day it is registered: the test is parametrised over the registry, and each method
declares its own seconds-long ``smoke_params``.
"""

from __future__ import annotations

import copy
import inspect
import json
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from conftest import TWO_STYLES

from motionaug.augment.corpus import Corpus
from motionaug.augment.methods.base import ARTIFACT_JSON, StyleTransferMethod, write_timings
from motionaug.augment.methods.registry import known_methods, method_class
from motionaug.augment.outputs.checksums import TIMINGS_FILE, sha256_tree
from motionaug.augment.outputs.run_dir import RunDir
from motionaug.augment.synth import generate_corpus
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.run_config import load_run_config
from motionaug.workflows.pipeline import check_config

N_CLIPS = 40


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("contract") / "corpus"
    generate_corpus(root, N_CLIPS, seed=0)
    return root


def config_for(name: str, corpus: Path, out: Path, **method: object):
    data = {
        "corpus": {"path": str(corpus), "filters": {"source_styles": ["neutral"], "min_frames": 40}},
        "styles": copy.deepcopy(TWO_STYLES),
        "method": {"name": name, "params": {**method_class(name).smoke_params, **method}},
        "base_models": {"size": "tiny"},
        "compute": {"num_cpus": 2, "batch_size": 4, "unit_size": 4},
        "output": str(out),
        "seed": 0,
    }
    return load_run_config(None, data=data)


def run_on_ray(config):
    """``motionaug run``'s executor on the Ray this process is connected to: the module's local Ray (its tests ask
    for conftest's ``ray_cluster``), used as it is, as a cluster a user keeps; one cluster start for every run."""
    from motionaug.workflows.ray_executor import execute_run

    return execute_run(config)


def test_every_method_declares_the_contract() -> None:
    for name in known_methods():
        cls = method_class(name)
        assert issubclass(cls, StyleTransferMethod) and cls.name == name
        assert cls.Params.model_config.get("extra") == "forbid", f"{name}: a typo in a config must be an error"
        cls.parse_params(cls.smoke_params)  # the smoke params are valid params
        assert list(inspect.signature(cls.load).parameters) == ["self", "artifact", "trained"], name
        with pytest.raises(MotionDataError, match=r"config method\.params"):
            cls.parse_params({"no_such_parameter": 1})


@pytest.mark.parametrize("name", known_methods())
def test_method_runs_train_prepare_transfer_on_ray(name: str, corpus: Path, tmp_path: Path, ray_cluster: str) -> None:

    config = config_for(name, corpus, tmp_path / "run")
    method = check_config(config)
    summary = run_on_ray(config)
    run = RunDir(tmp_path / "run")
    plan = run.read_plan()
    assert plan is not None and plan.n_clips > 0
    trained = Path(summary.manifest.base_models) if method.trains else None
    assert (trained is not None and method.is_trained(trained)) == method.trains
    for style in ("proud", "old"):
        marker = run.artifact(style)
        assert marker is not None and (run.root / marker.path / marker.entry / ARTIFACT_JSON).is_file()
    table = pq.read_table(run.shards_dir)
    planned = {(s, i) for u in plan.units for s, ids in u.styles.items() for i in ids}
    written = set(zip(table.column("style").to_pylist(), table.column("source_id").to_pylist()))
    assert written == planned and summary.manifest.rows == len(planned)  # every clip in every style, once
    neutral = {c.id for c in Corpus(corpus) if c.style == "neutral" and c.n_frames >= 40}
    assert {i for _, i in written} == neutral
    assert all(captions for captions in table.column("captions").to_pylist())
    assert set(table.column("method").to_pylist()) == {name}


@pytest.mark.parametrize("name", known_methods())
def test_an_unknown_parameter_is_one_config_line(name: str, corpus: Path, tmp_path: Path) -> None:
    with pytest.raises(MotionDataError, match=rf"config method\.params\.colour: {name}"):
        check_config(config_for(name, corpus, tmp_path / "run", colour=1))


@pytest.mark.parametrize("name", known_methods())
def test_prepare_checks_its_arguments_once_for_every_method(name: str, corpus: Path, tmp_path: Path) -> None:
    from motionaug.schemas.styles import StyleSpec

    method = method_class(name)(method_class(name).smoke_params)
    style = StyleSpec.model_validate(TWO_STYLES[0])
    example = next(c for c in Corpus(corpus) if c.style == "proud")
    with pytest.raises(MotionDataError, match="style 'proud': no example clips"):
        method.prepare(style, [], tmp_path, [], tmp_path / "none")
    if method.trains:
        with pytest.raises(MotionDataError, match=rf"{name} prepare: needs the trained models"):
            method.prepare(style, [example], None, [], tmp_path / "untrained")
    else:  # whoever runs the step records its seconds beside the artefact, outside its checksum
        prepared = method.prepare(style, [example], None, [], tmp_path / "style")
        assert not (prepared.folder / TIMINGS_FILE).exists()
        write_timings(prepared, 1.5)
        assert json.loads((prepared.folder / TIMINGS_FILE).read_text())["prepare_s"] == 1.5
        assert sha256_tree(prepared.folder)[1] == len([p for p in prepared.folder.rglob("*") if p.is_file()]) - 1


def test_style_erd_learns_a_style_its_network_never_saw_from_the_example_on_ray(
    corpus: Path, tmp_path: Path, ray_cluster: str
) -> None:
    """The network trains on the corpus without ``old``; ``old`` gets a branch fitted from its example in the
    prepare task, ``proud`` keeps its trained one, and every clip comes back in both."""

    from motionaug.augment.corpus.style_sets import write_without_styles
    from motionaug.augment.methods.erd.branch import BRANCH_FILE
    from motionaug.augment.methods.erd.training import read_artifact

    without_old = write_without_styles(corpus, tmp_path / "without-old", ["old"])
    config = config_for("erd", corpus, tmp_path / "run")
    config = config.model_copy(update={"base_models": config.base_models.model_copy(update={"corpus": without_old})})
    check_config(config)
    summary = run_on_ray(config)
    assert "old" not in read_artifact(summary.manifest.base_models).styles
    run = RunDir(tmp_path / "run")
    folders = {s: run.root / run.artifact(s).path / run.artifact(s).entry for s in ("proud", "old")}
    assert (folders["old"] / BRANCH_FILE).is_file() and not (folders["proud"] / BRANCH_FILE).exists()
    record = json.loads((folders["old"] / ARTIFACT_JSON).read_text())
    assert len(record["examples"]) == 1 and len(record["branch"]["history"]) >= 1
    table = pq.read_table(run.shards_dir)
    styles = table.column("style").to_pylist()
    assert styles.count("old") == styles.count("proud") == summary.manifest.rows // 2 > 0
