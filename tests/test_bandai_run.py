"""Real motion capture end to end: a few Bandai-2 takes imported, base models pre-trained on their train split,
held-out `normal` takes stylized by ``motionaug run`` on a real local Ray, the outputs scored by those evaluators.

Sizes are tiny (40 prior steps): this checks that the real-data path runs and keeps its held-out protocol, not the
quality, which lab/bandai2_quality.py measures.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from test_import_bvh import require_shared_data

from motionaug.augment.corpus import Corpus
from motionaug.augment.corpus.import_bvh import BANDAI2_CLIP_FRAMES, import_bvh
from motionaug.augment.methods.registry import method_class
from motionaug.augment.outputs.run_dir import RunDir
from motionaug.augment.outputs.shards import iter_shard_rows
from motionaug.schemas.run_config import load_run_config

TAKES = [
    f"dataset-2_{content}_{style}_{n:03d}"
    for content in ("walk", "run")
    for style in ("normal", "active")
    for n in range(1, 5)
]


@pytest.fixture(scope="module")
def bandai(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """16 takes (walk and run, normal and active, takes 001-004): per pair 001-002 train, 003 val, 004 test."""
    data = require_shared_data("bandai", "dataset-2")
    src = tmp_path_factory.mktemp("bandai") / "dataset-2"
    (src / "data").mkdir(parents=True)
    shutil.copytree(data / "cfg", src / "cfg")
    for take in TAKES:
        shutil.copyfile(data / "data" / f"{take}.bvh", src / "data" / f"{take}.bvh")
    out = src.parent / "corpus"
    import_bvh(src, out, max_frames=BANDAI2_CLIP_FRAMES, val_takes=1, test_takes=1, mean_std=True)
    return out


def test_real_takes_pretrain_and_stylize_held_out(ray_cluster: str, bandai: Path, tmp_path: Path) -> None:
    from motionaug.workflows.ray_executor import execute_run

    params = {**method_class("onthefly").smoke_params, "style_guidance": 1.25, "foot_lock": True}
    config = {
        "corpus": {
            "path": str(bandai),
            "split": "test",
            "pool_split": "train",
            "filters": {"source_styles": ["normal"]},
        },
        "styles": [
            {
                "name": "active",
                "words": {"adjective": "active", "adverb": "energetically", "phrases": ["in a lively manner"]},
                "examples": [{"source": "dataset-2_walk_active_001", "description": "a person walks energetically"}],
            }
        ],
        "method": {"name": "onthefly", "params": params},
        "base_models": {"size": "tiny"},
        "compute": {"num_cpus": 2, "batch_size": 4, "unit_size": 4},
        "output": str(tmp_path / "run"),
        "seed": 0,
    }
    execute_run(load_run_config(None, data=config))
    run = RunDir(tmp_path / "run")
    test_normal = {c.id for c in Corpus(bandai, split="test") if c.style == "normal"}
    train = {c.id for c in Corpus(bandai, split="train")}
    plan = run.read_plan()
    assert plan is not None and set(plan.pool) <= train and not set(plan.pool) & test_normal  # learns from train only
    rows = list(iter_shard_rows(run.root, columns=["source_id", "style", "motion", "captions"]))
    assert sorted(r["source_id"] for r in rows) == sorted(test_normal) and len(rows) == 2  # walk 004, run 004
    assert all(np.isfinite(np.asarray(r["motion"], dtype=np.float32)).all() for r in rows)
    base = run.trained_dir if (run.trained_dir / "base.json").is_file() else run.root / "base_models"
    assert (base / "evaluators" / "evaluators.json").is_file()  # the evaluators trained on the same train split
    report = run.manifest()
    assert report.stages["transfer"].seconds is not None
