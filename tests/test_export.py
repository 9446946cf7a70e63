"""Export of a finished run: HumanML3D layout (standard loader conventions) and merged Parquet."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from motionaug.augment.corpus import HumanML3DReader, read_parquet_corpus
from motionaug.augment.outputs.export import export_run
from motionaug.augment.outputs.run_dir import RunDir
from motionaug.augment.outputs.shards import iter_shard_rows
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.run_config import RunConfig, load_run_config

N_CLIPS = 30
STYLES = [
    {
        "name": "proud",
        "words": {"adjective": "proud", "adverb": "proudly"},
        "examples": [{"source": "000004", "description": "a person walks proudly"}],
    },
    {
        "name": "old",
        "words": {"adjective": "old", "phrases": ["like an old person"]},
        "examples": [{"source": "000008", "description": "a person walks like an old person"}],
    },
]


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    import ray

    from motionaug.augment.synth import generate_corpus
    from motionaug.workflows.ray_executor import execute_run

    root = tmp_path_factory.mktemp("export")
    generate_corpus(root / "corpus", N_CLIPS, seed=1)
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        execute_run(_config(root / "corpus", root / "run"))
    finally:
        ray.shutdown()
    return root / "run"


def _config(corpus: Path, out: Path) -> RunConfig:
    data = {
        "corpus": {"path": str(corpus)},
        "styles": STYLES,
        "output": str(out),
        "compute": {"unit_size": 16, "batch_size": 8},
    }
    return load_run_config(None, data=data)


def _ids(folder: Path, split: str) -> list[str]:
    return (folder / f"{split}.txt").read_text().split()


def test_humanml3d_export_loads_and_keeps_stylized_clips_in_train(run_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "hml"
    summary = export_run(run_dir, out, "humanml3d")
    source = run_dir.parent / "corpus"
    train, val, test = (_ids(out, s) for s in ("train", "val", "test"))
    stylized = [i for i in _ids(out, "all") if "__" in i]
    assert summary.originals == N_CLIPS and summary.stylized == len(stylized) == 2 * len(_ids(source, "train"))
    assert set(stylized) <= set(train) and not {i for i in val + test if "__" in i}
    assert sorted(_ids(out, "added")) == sorted(stylized)  # what `added_share` pre-training reads
    assert val == _ids(source, "val") and test == _ids(source, "test")
    assert set(_ids(out, "train_val")) == set(train) | set(val)
    clips = {c.id: c for c in HumanML3DReader(out, split="all", on_error="raise")}
    assert len(clips) == N_CLIPS + len(stylized)
    some = stylized[0]
    assert clips[some].captions and any(w in clips[some].captions[0].text for w in ("proud", "old"))
    mean, std = HumanML3DReader(out).mean_std()
    assert mean.shape == std.shape == (263,) and (std > 0).all()
    assert not np.allclose(mean, HumanML3DReader(source).mean_std()[0])  # recomputed with the stylized clips


def test_export_is_idempotent_and_can_keep_mean_std(run_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "hml"
    export_run(run_dir, out, "humanml3d", keep_mean_std=True)
    first = {p.relative_to(out): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}
    export_run(run_dir, out, "humanml3d", keep_mean_std=True)
    second = {p.relative_to(out): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}
    assert first == second
    assert np.array_equal(np.load(out / "Mean.npy"), np.load(run_dir.parent / "corpus" / "Mean.npy"))
    assert not list(tmp_path.glob(".*.tmp"))


def test_parquet_export_is_one_readable_corpus(run_dir: Path, tmp_path: Path) -> None:
    import duckdb

    summary = export_run(run_dir, tmp_path / "pq", "parquet")
    clips = list(read_parquet_corpus(tmp_path / "pq"))
    assert len(clips) == summary.originals + summary.stylized
    styled = [c for c in clips if "__" in c.id]
    assert styled and all(c.meta["split"] == "train" and c.style in ("proud", "old") for c in styled)
    n = duckdb.sql(f"select count(*) from read_parquet('{tmp_path / 'pq'}/*.parquet')").fetchall()[0][0]
    assert n == len(clips)


def test_export_refuses_unfinished_runs_and_foreign_folders(run_dir: Path, tmp_path: Path) -> None:
    with pytest.raises(MotionDataError, match="not complete"):
        export_run(tmp_path, tmp_path / "out")
    (tmp_path / "busy").mkdir()
    (tmp_path / "busy" / "keep.txt").write_text("mine")
    with pytest.raises(MotionDataError, match="not empty"):
        export_run(run_dir, tmp_path / "busy")
    with pytest.raises(MotionDataError, match="score"):
        export_run(run_dir, tmp_path / "scored", min_content_score=0.5)


def _rows(run: Path) -> list[dict]:
    return sorted(iter_shard_rows(run), key=lambda row: row["output_id"])


def test_a_flipped_byte_in_a_shard_is_refused_by_every_reader_and_a_rerun_repairs_it(
    run_dir: Path, tmp_path: Path
) -> None:
    import ray
    from typer.testing import CliRunner

    from motionaug.augment.eval.evaluation import evaluate_run, preview_grid, preview_transfer
    from motionaug.workflows.cli import app
    from motionaug.workflows.ray_executor import execute_run

    run = tmp_path / "run"
    shutil.copytree(run_dir, run)
    shard = RunDir(run).shard_files()[0]
    data = bytearray(shard.read_bytes())
    data[len(data) // 2] ^= 0x01
    shard.write_bytes(bytes(data))
    source = _rows(run_dir)[0]
    readers = {
        "export": lambda: export_run(run, tmp_path / "out"),
        "evaluate": lambda: evaluate_run(run),
        "preview --grid": lambda: preview_grid(run, 2, tmp_path / "grid.png"),
        "preview --clip": lambda: preview_transfer(run, source["source_id"], str(source["style"]), tmp_path / "a.gif"),
    }
    for name, read in readers.items():
        with pytest.raises(MotionDataError, match="checksum mismatch; run `motionaug run` again") as err:
            read()
        assert err.value.source == str(shard), name
    result = CliRunner().invoke(app, ["export", str(run), "--out", str(tmp_path / "out")])
    lines = result.output.strip().splitlines()
    assert result.exit_code == 1 and len(lines) == 1 and str(shard.name) in lines[0] and "checksum" in lines[0]
    assert not (tmp_path / "out").exists()

    ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        summary = execute_run(_config(run_dir.parent / "corpus", run))
    finally:
        ray.shutdown()
    transfer = summary.manifest.stages["transfer"]
    assert transfer.tasks - transfer.skipped == 1  # only the damaged unit was redone
    assert _rows(run) == _rows(run_dir)
    assert export_run(run, tmp_path / "out").stylized == export_run(run_dir, tmp_path / "ref").stylized
