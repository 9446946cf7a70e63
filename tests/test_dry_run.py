"""``motionaug run --dry-run``: the plan the run would make, its cost estimated, nothing run or written (no Ray)."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import yaml
from conftest import TWO_STYLES
from typer.testing import CliRunner

from motionaug.augment.outputs.run_dir import RunDir
from motionaug.schemas.run_config import load_run_config
from motionaug.workflows.cli import app
from motionaug.workflows.dry_run import dry_run_report, free_space, plan_run
from motionaug.workflows.executor import LocalBackend, run_pipeline

N_CLIPS = 40
UNIT_SIZE = 4


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from motionaug.augment.synth import generate_corpus

    root = tmp_path_factory.mktemp("corpus") / "synth"
    generate_corpus(root, N_CLIPS, seed=0)
    return root


def config_dict(corpus: Path, output: Path) -> dict:
    return {
        "corpus": {"path": str(corpus), "filters": {"min_frames": 40}},
        "styles": copy.deepcopy(TWO_STYLES),
        "method": {"name": "stats"},
        "compute": {"num_cpus": 2, "batch_size": 3, "unit_size": UNIT_SIZE},
        "output": str(output),
        "seed": 0,
    }


def test_dry_run_prints_the_plan_and_writes_nothing(corpus: Path, tmp_path: Path) -> None:
    import ray

    out = tmp_path / "never" / "run"
    config = tmp_path / "run.yaml"
    config.write_text(yaml.safe_dump(config_dict(corpus, tmp_path / "ignored")), encoding="utf-8")
    result = CliRunner().invoke(app, ["run", str(config), "--out", str(out), "--dry-run"])
    assert result.exit_code == 0, result.output
    dry = plan_run(load_run_config(config).model_copy(update={"output": out}))
    rows = {}
    for line in result.output.splitlines():
        cells = [c.strip() for c in line.split("│")[1:-1]]
        if len(cells) == 4 and cells[0]:
            rows[cells[0]] = cells
    assert rows["plan"][1] == "1" and rows["prepare"][1] == "2" and rows["transfer"][1] == f"{dry.shards:,}"
    assert dry.shards == dry.units * len(TWO_STYLES) and dry.units == -(-dry.clips // UNIT_SIZE)
    assert "disk: needs" in result.output and ": enough" in result.output
    assert not out.exists() and not out.parent.exists(), "a dry run wrote into --out"
    assert not ray.is_initialized()


def test_the_dry_run_plans_what_the_run_does_and_sizes_its_shards(corpus: Path, tmp_path: Path) -> None:
    config = load_run_config(None, data=config_dict(corpus, tmp_path / "run"))
    dry = plan_run(config)
    run_pipeline(config, LocalBackend())
    run = RunDir(config.output)
    plan = run.read_plan()
    assert plan is not None and dry.plan.model_dump() == plan.model_dump()
    markers = run.shard_markers()
    assert len(markers) == dry.shards
    written = sum((config.output / m.path).stat().st_size for m in markers)
    shard_bytes = dry.shards * dry.shard_bytes_mean
    assert 0.75 * written <= shard_bytes <= 1.25 * written, (shard_bytes, written)
    assert dry.disk_bytes >= shard_bytes and dry.seconds is not None and dry.seconds > 0


def test_a_method_without_a_benchmark_rate_says_not_measured(corpus: Path, tmp_path: Path) -> None:
    data = config_dict(corpus, tmp_path / "run")
    data["method"] = {"name": "erd"}
    data["base_models"] = {"path": str(tmp_path / "none"), "pretrain_if_missing": True}
    from motionaug.workflows.dry_run import dry_run_report

    dry = plan_run(load_run_config(None, data=data))
    prepare = next(s for s in dry.stages if s.name == "prepare")
    assert prepare.seconds is None and dry.seconds is None
    assert any("not measured" in str(part) for part in dry_run_report(dry))


def test_free_space_is_read_on_the_nearest_existing_folder(tmp_path: Path) -> None:
    where, free = free_space(tmp_path / "a" / "b" / "c")
    assert where == tmp_path.resolve() and free > 0


def test_a_style_whose_examples_all_move_one_way_is_named(corpus: Path, tmp_path: Path) -> None:
    """A style whose examples all travel (a run) while some clips stay in place gets one warning line, and one whose
    examples all stay in place (a wave) another; one example of each kind silences both."""
    data = config_dict(corpus, tmp_path / "run")
    data["styles"][0]["examples"] = [{"source": "000035", "description": "a person runs proudly"}]
    data["styles"][1]["examples"] = [{"source": "000009", "description": "a person waves like an old person"}]
    dry = plan_run(load_run_config(None, data=data))
    in_place = dry.plan.in_place
    assert in_place is not None and 0 < in_place < dry.clips
    assert dry.notes == [
        f"style 'proud': {in_place:,} of the run's {dry.clips:,} clips stay in place and none of its examples does;"
        " they take the change an example of another kind of motion shows, which carries the style far less: add an"
        " example that stays in place, with its reference (docs/methods.md)",
        f"style 'old': {dry.clips - in_place:,} of the run's {dry.clips:,} clips travel and none of its examples"
        " does; they take the change an example of another kind of motion shows, which carries the style far less:"
        " add an example that travels, with its reference (docs/methods.md)",
    ]
    printed = [line for line in dry_run_report(dry) if isinstance(line, str) and "warning" in line]
    assert len(printed) == 2 and "'proud'" in printed[0] and "'old'" in printed[1]
    for style, other in zip(data["styles"], ("000009", "000035")):
        style["examples"].append({"source": other, "description": style["examples"][0]["description"]})
    assert plan_run(load_run_config(None, data=data)).notes == []
