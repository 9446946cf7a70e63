"""The fault matrix's cases that fit the suite: real Ray (2 CPUs), real SIGKILLs, damaged files, a full disk.

The cases are bench/bench_faults.py's (the whole matrix runs there): each lands a fault in a ``motionaug run``
subprocess, reruns, and compares with an uninterrupted run of the same config and seed (shards byte-identical,
manifest equal but for ``TIMING_FIELDS``, no row lost or duplicated). The damaged-file cases share one finished
folder, which each leaves repaired.
"""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import load_bench

from motionaug.augment.synth import generate_corpus

faults = load_bench("bench_faults")

# The cases no other suite test covers: a driver killed mid-stage (the resume logic is the executor's, the same for
# every stage and method), a damaged artefact, a verified read and two writers. A worker killed mid-task runs in
# tests/test_cluster.py and a flipped shard byte in tests/test_export.py; the rest of the matrix (other stages,
# on-the-fly's training and fine-tunes, other damage, a full disk) runs in bench/bench_faults.py.
SUITE = [
    "kill-driver-stats-transfer-mid",
    "corrupt-artefact",
    "verified-read",
    "concurrent-runs",
]


@pytest.fixture(scope="module")
def harness(tmp_path_factory: pytest.TempPathFactory) -> Iterator:
    ray = pytest.importorskip("ray")
    assert not ray.is_initialized()
    root = tmp_path_factory.mktemp("faults")
    generate_corpus(root / "corpus", faults.N_CLIPS, seed=0)
    with faults.local_cluster() as address:
        yield faults.Harness(address, root, root / "corpus")


@pytest.mark.slow
@pytest.mark.parametrize("name", SUITE)
def test_fault_case_loses_and_duplicates_nothing(harness, name: str) -> None:
    if name in faults.ROOT_ONLY and not faults.is_root():
        pytest.skip("mounting a tmpfs needs root")
    case = faults.CASES[name]
    if name in faults.SHARED_FOLDER:
        result = case(harness, name, shared=harness.root / "runs" / "damaged")
    else:
        result = case(harness, name)
    assert result.lost == 0 and result.duplicated == 0, result.note
    assert result.ok, result.note


@pytest.mark.slow
def test_the_comparison_sees_a_changed_or_missing_shard(harness, tmp_path: Path) -> None:
    """The harness can fail: a copy of the reference with one shard changed and one gone is not equal to it."""
    ref = harness.reference(faults.STATS)
    copy = tmp_path / "copy"
    shutil.copytree(ref, copy)
    assert faults.compare(copy, copy).ok
    faults.flip_byte(copy / "shards/style=proud/unit-00001.parquet")
    (copy / "shards/style=old/unit-00002.parquet").unlink()
    result = faults.compare(copy, ref)
    assert not result.ok and result.lost == 4 and result.duplicated == 0
    assert any("shards differ" in problem for problem in result.problems)


def test_timing_fields_are_dropped_and_nothing_else() -> None:
    manifest = {
        "rows": 3,
        "stages": {"plan": {"seconds": 1.5, "tasks": 1, "skipped": 0}},
        "shards": [{"path": "a", "seconds": 2.0, "load_seconds": 0.1, "peak_rss_mb": 90.0, "rows": 3}],
        "artifacts": {"proud": {"seconds": 4.0, "sha256": "x"}},
    }
    for dotted in faults.TIMING_FIELDS:
        faults.drop_field(manifest, dotted.split("."))
    assert manifest == {
        "rows": 3,
        "stages": {"plan": {"tasks": 1}},
        "shards": [{"path": "a", "rows": 3}],
        "artifacts": {"proud": {"sha256": "x"}},
    }
