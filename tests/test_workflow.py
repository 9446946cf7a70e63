"""The distributed workflow end to end on a real local Ray cluster (num_cpus=2) and real Parquet files.

One cluster per module (started and shut down here only; never ``ray stop``). The corpus is ~40
synthetic clips, two styles with one example each, the cheap ``stats`` method.
"""

from __future__ import annotations

import copy
import json
from pathlib import Path

import duckdb
import numpy as np
import pyarrow.parquet as pq
import pytest
import yaml
from conftest import TWO_STYLES
from typer.testing import CliRunner

from motionaug.augment.corpus import read_rejects
from motionaug.augment.outputs.checksums import sha256_file
from motionaug.schemas.run_config import RunConfig, load_run_config
from motionaug.schemas.shards import Manifest
from motionaug.workflows.cli import app
from motionaug.workflows.dry_run import plan_run

N_CLIPS = 40
UNIT_SIZE = 4
STYLES = TWO_STYLES


def config_dict(corpus: Path, output: Path, **compute: object) -> dict:
    return {
        "corpus": {"path": str(corpus)},
        "styles": copy.deepcopy(STYLES),
        "method": {"name": "stats"},
        "compute": {"num_cpus": 2, "batch_size": 3, "unit_size": UNIT_SIZE, **compute},
        "output": str(output),
        "seed": 0,
    }


def write_config(path: Path, data: dict) -> Path:
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from motionaug.augment.synth import generate_corpus

    root = tmp_path_factory.mktemp("corpus") / "synth"
    generate_corpus(root, N_CLIPS, seed=0)
    return root


@pytest.fixture(scope="module")
def finished_run(ray_cluster: str, corpus: Path, tmp_path_factory: pytest.TempPathFactory):
    from motionaug.workflows.ray_executor import execute_run

    out = tmp_path_factory.mktemp("runs") / "full"
    config = load_run_config(None, data=config_dict(corpus, out))
    summary = execute_run(config)
    return config, summary


def shard_rows(run_dir: Path) -> list[tuple[str, bytes]]:
    """(output_id, motion bytes) of every row, sorted."""
    table = pq.read_table(sorted((run_dir / "shards").glob("style=*/*.parquet")), columns=["output_id", "motion"])
    pairs = zip(table["output_id"].to_pylist(), table["motion"].to_pylist())
    rows = [(oid, np.asarray(m, np.float32).tobytes()) for oid, m in pairs]
    return sorted(rows)


def test_end_to_end_shards_manifest_and_success(finished_run) -> None:
    config, summary = finished_run
    run = config.output
    assert (run / "_SUCCESS").is_file()
    assert summary.manifest.rows == N_CLIPS * len(STYLES)
    shards = f"read_parquet('{run}/shards/*/*.parquet', hive_partitioning=false)"
    assert duckdb.sql(f"select count(*) from {shards}").fetchall()[0][0] == N_CLIPS * len(STYLES)
    per_style = dict(duckdb.sql(f"select style, count(distinct source_id) from {shards} group by style").fetchall())
    assert per_style == {"proud": N_CLIPS, "old": N_CLIPS}
    import pandas as pd

    frame = pd.read_parquet(run / "shards", columns=["output_id", "style", "n_frames"])  # the style= folders merge
    assert len(frame) == N_CLIPS * len(STYLES) and frame["output_id"].is_unique
    assert pq.read_table(run / "shards").num_rows == len(frame)
    manifest = Manifest.model_validate_json((run / "manifest.json").read_text())
    assert manifest.run_id == config.run_id() and len(manifest.shards) == N_CLIPS // UNIT_SIZE * len(STYLES)
    for shard in manifest.shards:
        assert sha256_file(run / shard.path) == shard.sha256
        assert pq.read_metadata(run / shard.path).num_rows == shard.rows
    assert set(manifest.artifacts) == {"proud", "old"} and manifest.scores["foot_skating"] >= 0
    row = pq.read_table(run / manifest.shards[0].path).slice(0, 1).to_pylist()[0]
    assert row["output_id"] == f"{row['source_id']}__{row['style']}"
    assert len(row["motion"]) == row["n_frames"] * row["n_feats"] and row["n_feats"] == 263
    assert row["captions"] and all(t.count("/") == 1 for c in row["captions"] for t in c["tokens"])
    assert json.loads((run / "config.resolved.json").read_text())["run_id"] == config.run_id()
    # the sidestep example travels and the punch stays in place, so each style misses one kind of the clips
    assert [note.split(":")[0] for note in summary.notes] == ["style 'proud'", "style 'old'"]
    assert summary.notes == plan_run(config).notes


def test_rerun_skips_everything_and_keeps_rows(finished_run) -> None:
    from motionaug.workflows.ray_executor import execute_run

    config, _ = finished_run
    before = shard_rows(config.output)
    summary = execute_run(config)
    assert summary.skipped == {"prepare": 2, "transfer": N_CLIPS // UNIT_SIZE * 2}
    assert shard_rows(config.output) == before


def test_bad_clip_lands_in_rejects_and_the_rest_is_written(ray_cluster: str, corpus: Path, tmp_path: Path) -> None:
    import shutil

    from motionaug.workflows.ray_executor import execute_run

    bad = tmp_path / "corpus"
    shutil.copytree(corpus, bad)
    motion = np.load(bad / "new_joint_vecs" / "000010.npy")
    motion[5, 7] = np.nan
    np.save(bad / "new_joint_vecs" / "000010.npy", motion)
    config = load_run_config(None, data=config_dict(bad, tmp_path / "run", unit_size=16))
    summary = execute_run(config)
    rejects = read_rejects(tmp_path / "run" / "rejects" / "corpus.jsonl")
    assert [r.id for r in rejects] == ["000010"] and "NaN" in rejects[0].reason
    assert summary.manifest.rows == (N_CLIPS - 1) * len(STYLES) and summary.manifest.rejects == 1
    ids = {r[0] for r in shard_rows(tmp_path / "run")}
    assert "000010__proud" not in ids and "000011__proud" in ids


def test_fan_out_k_styles_per_clip(ray_cluster: str, corpus: Path, tmp_path: Path) -> None:
    from motionaug.workflows.ray_executor import execute_run

    data = {**config_dict(corpus, tmp_path / "run", unit_size=20), "fan_out": {"per_clip": 1, "seed": 3}}
    summary = execute_run(load_run_config(None, data=data))
    ids = [r[0] for r in shard_rows(tmp_path / "run")]
    assert summary.manifest.rows == N_CLIPS == len({i.split("__")[0] for i in ids})
    assert {i.split("__")[1] for i in ids} == {"proud", "old"}


def test_other_config_in_the_same_folder_is_refused(finished_run, corpus: Path, tmp_path: Path) -> None:
    config, _ = finished_run
    data = {**config_dict(corpus, config.output), "seed": 1}
    result = CliRunner().invoke(app, ["run", str(write_config(tmp_path / "c.yaml", data))])
    assert result.exit_code == 1
    assert "holds run" in result.output and "--force" in result.output


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        (
            lambda d: d["styles"][0]["examples"].__setitem__(0, {"source": "nope.npy", "description": "walks proudly"}),
            "nope.npy not found",
        ),
        (lambda d: d["corpus"].__setitem__("path", "/no/such/corpus"), "corpus.path"),
        (lambda d: d["compute"].__setitem__("batch_size", -4), "batch_size"),
        (lambda d: d["compute"].__setitem__("unit_size", 0), "unit_size"),
        (lambda d: d.__setitem__("method", {"name": "stats", "params": {"strength": 3}}), "method.params"),
        (lambda d: d.__setitem__("method", {"name": "nope"}), "unknown method"),
        (lambda d: d.__setitem__("colour", "red"), "colour"),
        (
            lambda d: d.update(method={"name": "onthefly", "params": {"train": {"prior_steps": -1}}}),
            "method.params.train.prior_steps",
        ),
        (
            lambda d: d.update(base_models={"pretrain": {"prior_steps": 100}}),
            "pretrain moved: the method's training settings are method.params.train now",
        ),
    ],
)
def test_config_errors_exit_2_with_one_line(change, expected: str, corpus: Path, tmp_path: Path) -> None:
    data = config_dict(corpus, tmp_path / "run")
    change(data)
    result = CliRunner().invoke(app, ["run", str(write_config(tmp_path / "c.yaml", data))])
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and expected in lines[0], result.output
    assert not (tmp_path / "run").exists()


def test_diffusion_k_greater_than_t_is_a_config_error(corpus: Path, tmp_path: Path) -> None:
    data = {
        **config_dict(corpus, tmp_path / "run"),
        "method": {"name": "onthefly", "params": {"transfer_noise_step": 5000}},
    }
    result = CliRunner().invoke(app, ["run", str(write_config(tmp_path / "c.yaml", data))])
    assert result.exit_code == 2 and "method.params" in result.output


def test_status_command(finished_run) -> None:
    config, _ = finished_run
    result = CliRunner().invoke(app, ["status", str(config.output)])
    assert result.exit_code == 0, result.output
    assert f"{N_CLIPS // UNIT_SIZE * 2}/{N_CLIPS // UNIT_SIZE * 2}" in result.output and "yes" in result.output


def test_run_id_ignores_where_but_not_what(corpus: Path, tmp_path: Path) -> None:
    a = RunConfig.model_validate(config_dict(corpus, tmp_path / "a"))
    b = RunConfig.model_validate(config_dict(corpus, tmp_path / "b", num_cpus=1, address="10.0.0.1:6379"))
    c = RunConfig.model_validate({**config_dict(corpus, tmp_path / "a"), "seed": 5})
    d = RunConfig.model_validate(config_dict(corpus, tmp_path / "a", unit_size=9))
    assert a.run_id() == b.run_id()
    assert len({a.run_id(), c.run_id(), d.run_id()}) == 3


def test_force_starts_over_and_foreign_folders_are_left_alone(corpus: Path, tmp_path: Path) -> None:
    from motionaug.augment.outputs.run_lock import RunLock
    from motionaug.schemas.errors import MotionDataError
    from motionaug.workflows.pipeline import write_resolved_config
    from motionaug.workflows.ray_executor import prepare_run_dir

    old = load_run_config(None, data={**config_dict(corpus, tmp_path / "run"), "seed": 9})
    write_resolved_config(old)
    (tmp_path / "run" / "styles").mkdir()  # the old run made something (a run that made nothing is taken over)
    (tmp_path / "run" / ".unit-00001.parquet.1.abc.tmp").write_text("half")
    new = load_run_config(None, data=config_dict(corpus, tmp_path / "run"))
    with RunLock(tmp_path / "run"):
        with pytest.raises(MotionDataError, match="holds run"):
            prepare_run_dir(new, force=False)
        prepare_run_dir(new, force=True)
    assert not any((tmp_path / "run").iterdir())
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "thesis.tex").write_text("keep")
    with pytest.raises(MotionDataError, match="not a motionaug run"), RunLock(tmp_path / "mine"):
        prepare_run_dir(load_run_config(None, data=config_dict(corpus, tmp_path / "mine")), force=True)
    assert [p.name for p in (tmp_path / "mine").iterdir()] == ["thesis.tex"]


def test_the_learning_pool_does_not_depend_on_the_unit_size(corpus: Path, tmp_path: Path) -> None:
    """compute.unit_size says how work is cut, not what a method learns from."""
    from motionaug.augment.methods.registry import create_method
    from motionaug.workflows.pipeline import PlanStage

    method = create_method("onthefly", {})
    plans = []
    for size in (4, 16):
        data = {**config_dict(corpus, tmp_path / f"u{size}", unit_size=size), "method": {"name": "onthefly"}}
        plans.append(PlanStage(load_run_config(None, data=data), method).run("plan"))
    assert [len(u.ids) for u in plans[0].units] != [len(u.ids) for u in plans[1].units]
    assert plans[0].pool == plans[1].pool and len(plans[0].pool) == min(method.content_clips(), plans[0].n_clips)
    assert set(plans[0].pool) <= {i for u in plans[0].units for i in u.ids}


def test_a_pool_split_keeps_the_methods_learning_clips_out_of_the_scored_ones(corpus: Path, tmp_path: Path) -> None:
    """``corpus.pool_split``: the pool comes from that split (through the same filters), never from the run's."""
    from motionaug.augment.corpus import Corpus
    from motionaug.augment.methods.registry import create_method
    from motionaug.workflows.pipeline import PlanStage

    method = create_method("onthefly", {})
    data = {**config_dict(corpus, tmp_path / "run"), "method": {"name": "onthefly"}}
    data["corpus"] = {
        "path": str(corpus),
        "split": "test",
        "pool_split": "train",
        "filters": {"source_styles": ["neutral"]},
    }
    plan = PlanStage(load_run_config(None, data=data), method).run("plan")
    train = {c.id: c for c in Corpus(corpus, split="train")}
    scored = {i for u in plan.units for i in u.ids}
    assert plan.pool and not set(plan.pool) & scored
    assert all(i in train and train[i].style == "neutral" for i in plan.pool)
    assert len(plan.pool) == min(method.content_clips(), sum(c.style == "neutral" for c in train.values()))
    again = PlanStage(load_run_config(None, data=data), method).run("plan")
    assert again.pool == plan.pool  # seeded
