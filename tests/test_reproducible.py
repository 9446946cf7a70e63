"""Same command, seed and thread count on the same machine -> bit-identical base models, artefacts and shards.

One on-the-fly run (tiny base models trained in the run, the method's smoke params) made twice into two
folders on a real local Ray (num_cpus=2); every file that is part of what the run made is compared by sha256.
Left out are the files that record wall-clock facts about how it was made: ``timings.json`` of an artefact
(``checksums.TIMINGS_FILE``, outside its checksum), the training loss log and the training checkpoints (resume
state with elapsed seconds), the ``.done`` markers (they record each task's seconds; the checksums in them are
compared instead) and the run-level records (config, manifest), which name the run folder.
See docs/reproducibility.md.
"""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
from conftest import TWO_STYLES

from motionaug.augment.methods.registry import method_class
from motionaug.augment.outputs.checksums import TIMINGS_FILE, sha256_file
from motionaug.augment.synth import generate_corpus
from motionaug.schemas.run_config import load_run_config

N_CLIPS = 40
WALL_CLOCK_FILES = {TIMINGS_FILE, "loss_log.jsonl"}
RUN_RECORDS = {"config.resolved.json", "manifest.json"}


def onthefly_config(corpus: Path, out: Path) -> dict:
    return {
        "corpus": {"path": str(corpus), "filters": {"source_styles": ["neutral"], "min_frames": 40}},
        "styles": copy.deepcopy(TWO_STYLES),
        "method": {"name": "onthefly", "params": dict(method_class("onthefly").smoke_params)},
        "base_models": {"size": "tiny"},
        "compute": {"num_cpus": 2, "batch_size": 4, "unit_size": 8},
        "output": str(out),
        "seed": 0,
    }


def made_files(run: Path) -> dict[str, str]:
    """sha256 of every file the run made, by path in the run folder (wall-clock records and checkpoints left out)."""
    digests = {}
    for path in sorted(p for p in run.rglob("*") if p.is_file()):
        relative = path.relative_to(run)
        marker = path.suffix == ".done"
        if marker or path.name in WALL_CLOCK_FILES | RUN_RECORDS or "checkpoints" in relative.parts:
            continue
        digests[relative.as_posix()] = sha256_file(path)
    return digests


@pytest.fixture(scope="module")
def two_runs(ray_cluster: str, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    from motionaug.workflows.ray_executor import execute_run

    root = tmp_path_factory.mktemp("reproducible")
    generate_corpus(root / "corpus", N_CLIPS, seed=0)
    runs = (root / "first", root / "second")
    for out in runs:
        execute_run(load_run_config(None, data=onthefly_config(root / "corpus", out)))
    return runs


def test_the_same_run_twice_makes_bit_identical_files(two_runs: tuple[Path, Path]) -> None:
    first, second = (made_files(run) for run in two_runs)
    assert first.keys() == second.keys()
    differing = sorted(name for name in first if first[name] != second[name])
    assert not differing, f"not bit-identical: {differing}"


def test_the_comparison_covers_base_models_artefacts_and_shards(two_runs: tuple[Path, Path]) -> None:
    names = made_files(two_runs[0])
    for needed in ("base_models/prior.safetensors", "base_models/motion_encoder.safetensors", "base_models/Mean.npy"):
        assert needed in names
    assert {"styles/proud/weights.safetensors", "styles/old/weights.safetensors"} <= names.keys()
    assert sum(name.endswith(".parquet") for name in names) == 4  # 2 styles x 2 units of 8 clips


def test_markers_record_the_same_checksums(two_runs: tuple[Path, Path]) -> None:
    """Markers differ in their seconds, not in what they certify: the artefact, shard and base-model checksums
    (``timings.json``, the loss log and the checkpoints record wall clock and stay outside them)."""
    from motionaug.augment.outputs.run_dir import RunDir

    first, second = (RunDir(run) for run in two_runs)
    assert (first.artifact_dir("proud") / TIMINGS_FILE).is_file()
    for style in ("proud", "old"):
        a, b = first.artifact(style), second.artifact(style)
        assert a is not None and b is not None
        assert (a.sha256, a.files, a.trained_sha256) == (b.sha256, b.files, b.trained_sha256), style

    def certified(markers: list) -> list[tuple]:
        return [(m.path, m.rows, m.sha256, m.artifact_sha256, m.trained_sha256) for m in markers]

    assert len(first.shard_markers()) == 4
    assert certified(first.shard_markers()) == certified(second.shard_markers())
