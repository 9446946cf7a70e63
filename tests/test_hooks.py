"""Hooks registered from outside the package reach the Ray workers that use them.

The output shaper below is defined in this test module; the run config names the module in ``hooks.modules``,
so every worker imports it before building the method. A worker that had not would fail the run with an unknown
shaper. Shapers are the run's (``method.shapers``), so any method takes them: here the stats baseline, after the
shipped ``moments`` (which needs the prepare stage's references). Imports only the package (the workers import this
module by name, without the tests' conftest).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.numpy import load_file

from motionaug.augment.corpus import Corpus
from motionaug.augment.methods.hooks import (
    LossBatch,
    LossTerm,
    OutputShaper,
    ShapeContext,
    import_hook_modules,
    loss_terms,
    output_shapers,
    split_spec,
)
from motionaug.augment.methods.shaping import SHAPING_FILE
from motionaug.augment.outputs.shards import iter_shard_rows, row_motion
from motionaug.augment.synth import generate_corpus
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.run_config import load_run_config


@output_shapers.register("test-content")
class ContentBack(OutputShaper):
    """Gives the content clip back: every output is its source."""

    def __call__(self, output: np.ndarray, context: ShapeContext) -> np.ndarray:
        return context.content.copy()


@loss_terms.register("test-hooks-joints")
class JointDistance(LossTerm):
    """Mean distance of the predicted joints from the target's, metres."""

    def __call__(self, batch: LossBatch) -> torch.Tensor:
        return (batch.predicted - batch.target).norm(dim=-1)[batch.mask].mean()


def run_config(corpus: Path, out: Path, modules: list[str], method: dict | None = None, reference: str | None = None):
    example = {"source": "000004", "description": "a person walks proudly"} | (
        {"reference": reference} if reference else {}
    )
    styles = [{"name": "proud", "words": {"adjective": "proud", "adverb": "proudly"}, "examples": [example]}]
    data = {
        "corpus": {"path": str(corpus), "filters": {"source_styles": ["neutral"], "min_frames": 40}},
        "styles": styles,
        "method": method or {"name": "stats", "params": {}, "shapers": ["moments", "test-content"]},
        "hooks": {"modules": modules},
        "base_models": {"size": "tiny"},
        "compute": {"num_cpus": 2, "batch_size": 4, "unit_size": 4},
        "output": str(out),
        "seed": 0,
    }
    return load_run_config(None, data=data)


def test_specs_and_unknown_modules_are_one_line() -> None:
    assert split_spec("moments") == ("moments", {})
    assert split_spec({"name": "moments", "floor": 0.5}) == ("moments", {"floor": 0.5})
    assert output_shapers.create({"name": "moments", "floor": 0.5}).floor == 0.5
    with pytest.raises(MotionDataError, match=r"output shaper 'moments': .*floor"):
        output_shapers.create({"name": "moments", "floor": 2.0})
    with pytest.raises(MotionDataError, match=r"config hooks\.modules: cannot import 'no_such_hooks'"):
        import_hook_modules(["no_such_hooks"])
    with pytest.raises(ValueError, match="registered already"):
        output_shapers.register("test-content")(type("Other", (OutputShaper,), {"__call__": lambda s, o, c: o}))


def test_a_shaper_defined_in_a_test_module_runs_in_the_ray_workers(tmp_path: Path, ray_cluster: str) -> None:
    from motionaug.workflows.pipeline import named_references
    from motionaug.workflows.ray_executor import execute_run

    corpus = tmp_path / "corpus"
    generate_corpus(corpus, 24, seed=0)
    plain = sorted(c.id for c in Corpus(corpus) if c.style == "neutral")[-1]
    config = run_config(corpus, tmp_path / "run", ["tests.test_hooks"], reference=plain)
    execute_run(config)  # on the module's local Ray (conftest's ``ray_cluster``), as on a cluster a user keeps
    sources = {c.id: c for c in Corpus(corpus)}
    rows = list(iter_shard_rows(tmp_path / "run"))
    assert rows
    for row in rows:  # the shapers ran, in order: every output is its source
        np.testing.assert_array_equal(row_motion(row), sources[row["source_id"]].motion)
    shaping = load_file(str(tmp_path / "run" / "styles" / "proud" / SHAPING_FILE))
    assert set(shaping) == {"example.0", "reference.0"}  # the moments shaper's reference, stored at prepare
    np.testing.assert_array_equal(shaping["reference.0"], sources[plain].motion)  # the one the example names
    unknown = run_config(corpus, tmp_path / "run2", [], reference="no_such_clip")
    with pytest.raises(MotionDataError, match="example '000004'.*reference 'no_such_clip' is not in the corpus"):
        named_references(unknown.styles[0], unknown)


def test_a_loss_term_defined_in_a_test_module_trains_in_the_ray_workers(tmp_path: Path, ray_cluster: str) -> None:
    """Style-ERD's training runs in a Ray task: the term named in ``train.loss_terms`` joins its loss there."""
    from motionaug.augment.methods.registry import method_class
    from motionaug.workflows.ray_executor import execute_run

    corpus = tmp_path / "corpus"
    generate_corpus(corpus, 24, seed=0)
    smoke = method_class("erd").smoke_params
    train = {**smoke["train"], "loss_terms": [{"name": "test-hooks-joints", "weight": 0.5}]}
    method = {"name": "erd", "params": {**smoke, "train": train}}
    config = run_config(corpus, tmp_path / "run", ["tests.test_hooks"], method)
    summary = execute_run(config)
    record = json.loads((Path(summary.manifest.base_models) / "erd.json").read_text(encoding="utf-8"))
    assert all(row["test-hooks-joints"] > 0 for row in record["history"])


def test_hooks_named_on_a_command_line_parse_to_config_specs() -> None:
    from motionaug.augment.methods.hooks import parse_hook_specs

    assert parse_hook_specs("") == []
    assert parse_hook_specs("coordination:shrink=0.0:floor=0.01,moments") == [
        {"name": "coordination", "shrink": 0.0, "floor": 0.01},
        "moments",
    ]
