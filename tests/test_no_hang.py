"""No hang, no surprise: what a run finds out before it starts, what it refuses to wait for, and empty results.

Real parts throughout: a synthetic corpus on disk, the real run stages on the local backend, and a real local Ray
(2 CPUs) for the stage whose tasks ask for more than any node has. The one-line errors of the CLI for the same
inputs are in ``test_error_catalogue.py``; generated bad inputs in ``test_fuzz_cli.py``.
"""

from __future__ import annotations

import copy
import io
import json
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import TWO_STYLES
from typer.testing import CliRunner

from motionaug.augment.corpus import Corpus
from motionaug.augment.corpus.humanml3d import MAX_CLIP_FRAMES, load_npy
from motionaug.augment.outputs.export import export_run
from motionaug.augment.outputs.run_lock import RunLock
from motionaug.schemas.errors import MotionConfigError, MotionDataError
from motionaug.schemas.run_config import RunConfig, load_run_config
from motionaug.workflows.cli import app
from motionaug.workflows.cli_app import MAX_LINE, error_line
from motionaug.workflows.executor import LocalBackend, run_pipeline
from motionaug.workflows.preflight import check_local_resources, probe_address
from motionaug.workflows.ray_executor import RayBackend, prepare_run_dir

REPO = Path(__file__).resolve().parents[1]
TEMPLATE = REPO / "tests" / "fixtures" / "bvh" / "dataset-2" / "data" / "dataset-2_raise-up-left-hand_active_003.bvh"
N_CLIPS = 24
ROOT_CHANNELS = "Xposition Yposition Zposition Zrotation Xrotation Yrotation"


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from motionaug.augment.synth import generate_corpus

    root = tmp_path_factory.mktemp("corpus") / "synth"
    generate_corpus(root, N_CLIPS, seed=0)
    return root


def config(corpus_path: Path, out: Path, **changes: object) -> RunConfig:
    data = {
        "corpus": {"path": str(corpus_path)},
        "styles": copy.deepcopy(TWO_STYLES),
        "method": {"name": "stats"},
        "compute": {"num_cpus": 2, "batch_size": 8, "unit_size": 8},
        "output": str(out),
    }
    for key, value in changes.items():
        section, _, field = key.partition("__")
        if field:
            data.setdefault(section, {})[field] = value
        else:
            data[key] = value
    return load_run_config(None, data=data)


# ---- bounded input ---------------------------------------------------------------------------------------------


def _sparse_npy(path: Path, frames: int) -> None:
    """A real .npy of ``frames`` zero frames that takes no disk (a sparse file): only its header is ever read."""
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": "<f4", "fortran_order": False, "shape": (frames, 263)})
    with open(path, "wb") as handle:
        handle.write(buf.getvalue())
        handle.truncate(len(buf.getvalue()) + frames * 263 * 4)


def test_a_clip_over_the_ceiling_is_refused_from_its_header(tmp_path: Path) -> None:
    _sparse_npy(tmp_path / "huge.npy", 2_000_000)
    with pytest.raises(MotionDataError, match=f"2000000 frames, over the ceiling of {MAX_CLIP_FRAMES}"):
        load_npy(tmp_path / "huge.npy", 2, 263)


def test_clips_over_the_runs_limit_are_rejects_with_their_length(corpus: Path, tmp_path: Path) -> None:
    lengths = {clip.id: clip.n_frames for clip in Corpus(corpus)}
    limit = sorted(lengths.values())[len(lengths) // 2]
    cfg = config(corpus, tmp_path / "run", corpus__max_clip_frames=limit)
    result = run_pipeline(cfg, LocalBackend())
    longer = {clip_id for clip_id, n in lengths.items() if n > limit}
    assert longer and result.manifest.rows == (len(lengths) - len(longer)) * len(TWO_STYLES)
    rejects = [json.loads(line) for line in (tmp_path / "run" / "rejects" / "corpus.jsonl").read_text().splitlines()]
    assert {r["id"] for r in rejects} == longer
    assert all(f"more than corpus.max_clip_frames={limit}" in r["reason"] for r in rejects)


def test_run_ids_of_configs_without_a_clip_limit_are_unchanged(corpus: Path, tmp_path: Path) -> None:
    """The run id as it was computed before ``corpus.max_clip_frames`` and ``method.shapers`` existed: earlier runs
    still resume."""
    import hashlib

    plain = config(corpus, tmp_path / "a")
    keep = plain.model_dump(mode="json", include={"version", "corpus", "styles", "method", "fan_out", "seed"})
    del keep["corpus"]["max_clip_frames"]
    del keep["method"]["shapers"]  # added later too, left out at its default in the same way
    keep["batching"] = [plain.compute.unit_size, plain.compute.batch_size]
    keep["corpus"]["path"] = str(Path(keep["corpus"]["path"]).resolve())
    keep["corpus"]["content"] = plain.corpus_fingerprint()
    before = "run-" + hashlib.sha256(json.dumps(keep, sort_keys=True).encode()).hexdigest()[:12]
    assert plain.run_id() == before
    assert config(corpus, tmp_path / "a", corpus__max_clip_frames=100).run_id() != before


def _deep_bvh(depth: int) -> str:
    head = ["HIERARCHY", "ROOT Hips", "{", "OFFSET 0 0 0", f"CHANNELS 6 {ROOT_CHANNELS}"]
    for i in range(depth):
        head += [f"JOINT j{i}", "{", "OFFSET 0 1 0", "CHANNELS 3 Zrotation Xrotation Yrotation"]
    head += ["End Site", "{", "OFFSET 0 1 0", "}"] + ["}"] * (depth + 1)
    frame = " ".join(["0"] * (6 + 3 * depth))
    return "\n".join([*head, "MOTION", "Frames: 2", "Frame Time: 0.05", frame, frame]) + "\n"


def _wide_bvh(joints: int) -> str:
    head = ["HIERARCHY", "ROOT Hips", "{", "OFFSET 0 0 0", f"CHANNELS 6 {ROOT_CHANNELS}"]
    for i in range(joints):
        head += [f"JOINT joint_with_a_long_name_{i}", "{", "OFFSET 0 1 0", "CHANNELS 3 Zrotation Xrotation Yrotation"]
        head += ["End Site", "{", "OFFSET 0 1 0", "}", "}"]
    frame = " ".join(["0"] * (6 + 3 * joints))
    return "\n".join([*head, "}", "MOTION", "Frames: 2", "Frame Time: 0.05", frame, frame]) + "\n"


def test_a_deep_or_huge_bvh_is_a_rejected_file_and_the_good_ones_import(tmp_path: Path) -> None:
    src = tmp_path / "takes"
    src.mkdir()
    (src / "dataset-2_walk_proud_001.bvh").write_text(_deep_bvh(10_000), encoding="utf-8")
    (src / "dataset-2_walk_proud_002.bvh").write_text(_wide_bvh(10_001), encoding="utf-8")
    (src / "dataset-2_walk_proud_003.bvh").write_text(TEMPLATE.read_text(encoding="utf-8"), encoding="utf-8")
    result = CliRunner().invoke(app, ["corpus", "import-bvh", str(src), "--out", str(tmp_path / "c")])
    assert result.exit_code == 0, result.output
    assert "unexpected" not in result.output and "Traceback" not in result.output
    assert "joints nested more than 128 deep" in result.output and "more than 1024 joints" in result.output
    assert max(len(line) for line in result.output.splitlines()) < 1000
    assert len(list((tmp_path / "c" / "new_joint_vecs").glob("*.npy"))) >= 1


def test_a_bad_bvh_on_stdin_is_named_stdin_not_a_temporary_file() -> None:
    from motionaug.augment.methods.erd.stream_files import read_frames

    with pytest.raises(MotionDataError) as caught:
        read_frames(io.BytesIO(b"HIERARCHY\nROOT Hips\n{\nOFFSET 0 0\n"), "bvh")
    assert str(caught.value).startswith("stdin: ") and ".bvh" not in str(caught.value), caught.value


def test_an_error_line_is_bounded() -> None:
    line = error_line(MotionDataError("x.bvh", "joints " + "j, " * 30_000))
    assert line is not None and len(line) <= MAX_LINE


# ---- empty is an error ---------------------------------------------------------------------------------------


def test_a_run_of_only_rejects_fails_with_the_commonest_reason(corpus: Path, tmp_path: Path) -> None:
    """A style phrase a caption cannot hold (the CLI refuses it first: this is the run's own last line of defence)."""
    styles = copy.deepcopy(TWO_STYLES)
    styles[0]["words"]["phrases"] = ["in a #1 way"]
    cfg = config(corpus, tmp_path / "run", styles=styles[:1])
    with pytest.raises(MotionDataError, match=rf"run wrote 0 rows from {N_CLIPS} clips; most often: .* \({N_CLIPS} of"):
        run_pipeline(cfg, LocalBackend())
    assert not (tmp_path / "run" / "_SUCCESS").exists()
    allowed = cfg.model_copy(update={"allow_empty": True})
    assert run_pipeline(allowed, LocalBackend()).manifest.rows == 0 and (tmp_path / "run" / "_SUCCESS").is_file()


def test_filters_that_select_nothing_fail_unless_allowed(corpus: Path, tmp_path: Path) -> None:
    cfg = config(corpus, tmp_path / "run", corpus={"path": str(corpus), "filters": {"contents": ["fly"]}})
    with pytest.raises(MotionDataError, match=f"select 0 of the {N_CLIPS} readable clips"):
        run_pipeline(cfg, LocalBackend())
    done = run_pipeline(cfg.model_copy(update={"allow_empty": True}), LocalBackend())
    assert done.manifest.rows == 0


def test_an_export_that_adds_no_stylized_clip_fails_and_writes_nothing(corpus: Path, tmp_path: Path) -> None:
    cfg = config(corpus, tmp_path / "run", corpus={"path": str(corpus), "split": "test"})
    assert run_pipeline(cfg, LocalBackend()).manifest.rows > 0  # every row a test clip: exports leave them out
    with pytest.raises(MotionDataError, match="export would add 0 stylized clips: of the run's"):
        export_run(tmp_path / "run", tmp_path / "out")
    assert not (tmp_path / "out").exists() and not list(tmp_path.glob(".out.*"))
    assert export_run(tmp_path / "run", tmp_path / "out", allow_empty=True).stylized == 0


# ---- a failed config does not claim its folder -----------------------------------------------------------------


def test_a_folder_whose_run_made_nothing_is_taken_over(corpus: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    failed = config(corpus, out, corpus={"path": str(corpus), "filters": {"contents": ["fly"]}})
    with RunLock(out):
        prepare_run_dir(failed, force=False)
        out.joinpath("config.resolved.json").write_text(json.dumps({"run_id": failed.run_id(), "config": {}}))
    with pytest.raises(MotionDataError):
        run_pipeline(failed, LocalBackend())  # the plan task finds the mistake: config and rejects are there
    fixed = config(corpus, out)
    with RunLock(out):
        prepare_run_dir(fixed, force=False)  # taken over: the failed run made nothing
    assert not (out / "config.resolved.json").exists()
    (out / "styles").mkdir()
    out.joinpath("config.resolved.json").write_text(json.dumps({"run_id": failed.run_id(), "config": {}}))
    with RunLock(out), pytest.raises(MotionDataError, match="the config or the corpus changed"):
        prepare_run_dir(fixed, force=False)  # a run that made something is never taken over silently


# ---- resources and clusters ------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("changes", "says"),
    [
        ({"num_cpus": 64}, "config compute.num_cpus: 64 CPUs asked, but this machine has 2"),
        ({"transfer_cpus": 4}, "transfer tasks ask for 4 CPUs each, but the embedded Ray on this machine has 2"),
        ({"finetune_gpus": 1}, "prepare tasks ask for 1 GPU each, but the embedded Ray on this machine has none"),
        ({"num_cpus": None, "transfer_cpus": 3}, "transfer tasks ask for 3 CPUs each, but the embedded Ray"),
    ],
)
def test_requests_over_the_machine_are_refused(corpus: Path, tmp_path: Path, changes: dict, says: str) -> None:
    compute = {"num_cpus": 2, **changes}
    cfg = config(corpus, tmp_path / "run", compute=compute)
    with pytest.raises(MotionConfigError) as caught:
        check_local_resources(cfg, trains=False, machine={"CPU": 2.0, "GPU": 0.0})
    assert says in str(caught.value)


def test_a_closed_port_fails_at_once_naming_the_address() -> None:
    started = time.monotonic()
    with pytest.raises(MotionDataError, match=r"--address 127.0.0.1:1: cannot reach the Ray cluster"):
        probe_address("127.0.0.1:1", timeout_s=5)
    assert time.monotonic() - started < 5
    with pytest.raises(MotionConfigError, match="not HOST:PORT"):
        probe_address("nowhere", timeout_s=1)


def test_tasks_no_node_can_hold_stop_the_run_naming_the_setting(ray_cluster, corpus: Path, tmp_path: Path) -> None:
    """A real 2-CPU Ray: transfers asking 4 CPUs (and a GPU the cluster lacks) are stopped, not waited on."""
    for compute, setting, waits in (
        ({"transfer_cpus": 4}, "compute.transfer_cpus", 2.0),
        ({"transfer_gpus": 1}, "compute.transfer_gpus", 0.0),
    ):
        cfg = config(corpus, tmp_path / setting, compute={"num_cpus": 2, "batch_size": 8, "unit_size": 8, **compute})
        started = time.monotonic()
        with pytest.raises(MotionConfigError) as caught:
            run_pipeline(cfg, RayBackend(0, unschedulable_s=waits, poll_s=0.5))
        assert str(caught.value).startswith(f"config {setting}: transfer tasks ask for "), caught.value
        assert time.monotonic() - started < 60
        assert not list((tmp_path / setting).rglob("*.parquet"))


@pytest.mark.parametrize("item", ["prior_steps=[", "prior_steps", "=3"])
def test_a_bad_pretrain_override_is_one_usage_line(item: str, tmp_path: Path) -> None:
    args = ["pretrain", "--corpus", str(tmp_path), "--out", str(tmp_path / "pt"), "--set", item]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2 and result.output.startswith("error: --set: override "), result.output
    assert "unexpected" not in result.output and not (tmp_path / "pt").exists()
