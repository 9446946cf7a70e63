"""Every user-facing error of docs/errors.md, fed through the real ``motionaug`` command (its own process, so exit
codes and tracebacks are what a user sees): one ``error:`` line naming the thing and the reason, no traceback, the
documented exit code, and nothing that existed before changed or lost.

Cases that fail before Ray starts run four at a time, each in a forked child of a process that imported the CLI
once (tests/cli_zygote.py: the console script's entry point, its exit code and its lines); two need a Ray run (a
corrupt-clip corpus whose bad clips become rejects while the run goes on, then reads of its damaged shard; a style
example that is not in the corpus, raised inside a task). Read-only and full disks are small tmpfs mounts (the
machines run as root).
"""

from __future__ import annotations

import hashlib
import http.server
import io
import json
import os
import re
import select
import signal
import subprocess
import sys
import tempfile
import threading
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
MOTIONAUG = Path(sys.executable).with_name("motionaug")
ERRORS_DOC = REPO / "docs" / "errors.md"
TEMPLATE = REPO / "tests" / "fixtures" / "bvh" / "dataset-2" / "data" / "dataset-2_raise-up-left-hand_active_003.bvh"
RAY_LOG = re.compile(r"^\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d+\s+(INFO|WARNING)\s")
N_CLIPS = 20


@dataclass(frozen=True)
class Case:
    """One bad input: the command (run in the scene folder), its exit code and what its one line must say."""

    id: str
    args: tuple[str, ...]
    code: int
    says: str


FAST = [
    # files and configs (exit 2: the config or an argument is wrong)
    Case("missing-config", ("run", "nope.yaml"), 2, "config file not found"),
    Case("yaml-syntax", ("run", "broken.yaml"), 2, "broken.yaml:3:7: not valid YAML"),
    Case("unknown-key", ("run", "colour.yaml"), 2, "colour: Extra inputs are not permitted"),
    Case("bad-value-type", ("run", "type.yaml"), 2, "compute.batch_size: Input should be a valid integer"),
    Case("bad-override", ("run", "good.yaml", "--set", "compute.unit_size"), 2, "is not key.sub=value"),
    Case("unknown-method", ("run", "method.yaml"), 2, "unknown method"),
    Case("bad-method-param", ("run", "param.yaml"), 2, "method.params.strength"),
    Case("missing-corpus", ("run", "nocorpus.yaml"), 2, "corpus.path"),
    Case("missing-example-file", ("run", "nofile.yaml"), 2, "nope.npy not found"),
    Case("example-not-in-corpus", ("run", "noexample.yaml", "--out", "run-b"), 2, "'999999' is not in the corpus"),
    Case("reference-not-in-corpus", ("run", "noref.yaml", "--out", "run-b"), 2, "reference: clip id '999999' is not"),
    Case("short-example", ("run", "short.yaml", "--out", "run-b"), 2, "too short: 5 frames < 20"),
    Case("caption-separator", ("run", "hash.yaml", "--out", "run-b"), 2, "holds '#'"),
    Case("missing-split-file", ("run", "good.yaml", "--set", "corpus.split=nope"), 2, "corpus.split: "),
    Case("config-is-a-folder", ("run", "corpus"), 2, "corpus: is a folder; give the run config file"),
    Case("bad-override-value", ("run", "good.yaml", "--set", "compute.num_cpus=["), 2, "is not valid YAML"),
    Case("cpus-over-machine", ("run", "good.yaml", "--set", "compute.num_cpus=4096"), 2, "4096 CPUs asked"),
    Case(
        "task-over-machine",
        ("run", "good.yaml", "--set", "compute.transfer_cpus=4"),
        2,
        "compute.transfer_cpus: transfer tasks ask for 4 CPUs each, but the embedded Ray on this machine has 2",
    ),
    Case("gpus-over-machine", ("run", "good.yaml", "--set", "compute.finetune_gpus=64"), 2, "ask for 64 GPUs each"),
    Case("out-is-a-file", ("run", "good.yaml", "--out", "good.yaml"), 2, "good.yaml is a file; a run needs a folder"),
    Case(
        "stream-input-format",
        ("stream", "--style", "old", "--model", "corpus", "--input", "good.yaml"),
        2,
        "--input: reads .bvh or .npy motion, not 'yaml'",
    ),
    Case("submit-client-address", ("submit", "good.yaml", "--address", "ray://127.0.0.1:1"), 2, "Ray Client address"),
    Case("preview-args", ("preview", "corpus", "--clip", "000001", "--style", "proud"), 2, "is a corpus, not a run"),
    Case("preview-html-worst-of-corpus", ("preview", "corpus", "--html", "--worst", "3"), 2, "has no content scores"),
    Case("view-not-a-run", ("view", "corpus"), 2, "not a run folder; for a corpus use"),
    Case("viewer-unknown-id", ("corpus", "view", "corpus", "--ids", "nope", "--out", "v"), 1, "no clip with id 'nope'"),
    Case(
        "labels-from-without-fields",
        ("corpus", "import-bvh", "takes", "--out", "n", "--labels-from", "plain.bvh"),
        2,
        "has no {field}",
    ),
    # data and outputs (exit 1)
    Case(
        "run-into-foreign-folder", ("run", "good.yaml", "--out", "mine"), 1, "is not empty and is not a motionaug run"
    ),
    Case("export-unfinished", ("export", "mine", "--out", "x"), 1, "run is not complete"),
    Case(
        "drop-styles-into-foreign-folder",
        ("corpus", "drop-styles", "corpus", "--style", "proud", "--out", "mine"),
        1,
        "folder is not empty; a filtered corpus is written into a new folder",
    ),
    Case("inspect-not-a-corpus", ("corpus", "inspect", "mine"), 1, "not a corpus"),
    Case(
        "oversized-npy-header",
        ("preview", "corpus", "--clip", "huge_header", "--out", "h.gif"),
        1,
        "header says 1000000000 frames but file has 192 bytes",
    ),
    # clusters
    Case(
        "unreachable-cluster",
        ("submit", "good.yaml", "--address", "http://127.0.0.1:1"),
        1,
        "cannot reach the Ray dashboard",
    ),
    Case("unreachable-status", ("status", "run-x", "--address", "http://127.0.0.1:1"), 1, "cannot reach"),
    Case("run-unreachable-cluster", ("run", "good.yaml", "--address", "127.0.0.1:1"), 1, "cannot reach the Ray"),
    Case("not-a-dashboard", ("logs", "x", "--address", "{not_ray}"), 1, "not a Ray dashboard"),
    # disks
    Case("read-only-output", ("corpus", "synth", "--out", "ro/c", "--clips", "40"), 1, "ro/c: read-only file system"),
    Case("full-disk", ("corpus", "synth", "--out", "full/c", "--clips", "40"), 1, "no space left on device"),
    # BVH import
    Case("import-into-corpus", ("corpus", "import-bvh", "takes", "--out", "corpus"), 1, "pass --append"),
    Case("import-into-file", ("corpus", "import-bvh", "takes", "--out", "good.yaml"), 1, "--out needs a folder"),
    Case("import-append-and-force", ("corpus", "import-bvh", "takes", "--out", "n", "--append", "--force"), 2, "one"),
    Case("import-unlabelled", ("corpus", "import-bvh", "unlabelled", "--out", "n"), 1, "pass --content"),
    Case(
        "import-bad-joint-map",
        ("corpus", "import-bvh", "takes", "--out", "n", "--joint-map", "map.json"),
        1,
        "bad joint map",
    ),
    Case("import-unmapped-rig", ("corpus", "import-bvh", "rig", "--out", "n"), 1, "pass --joint-map"),
]
EMPTY_SELECTION = Case(
    "empty-selection", ("run", "nothing.yaml", "--out", "run-b"), 1, "select 0 of the 20 readable clips"
)
FAST.append(EMPTY_SELECTION)
AFTER_RUN = [
    Case("export-damaged-shard", ("export", "run", "--out", "exported"), 1, "checksum mismatch; run `motionaug run`"),
    Case("evaluate-damaged-shard", ("evaluate", "run"), 1, "checksum mismatch; run `motionaug run`"),
    Case("export-over-foreign-folder", ("export", "run", "--out", "mine"), 1, "holds no earlier export"),
]
IN_TASK = Case("disk-full-in-task", ("run", "good.yaml", "--out", "small/run"), 1, "no space left on device")
BAD_CLIPS = {
    "huge_header": "header says 1000000000 frames but file has 192 bytes",
    "nan_clip": "NaN/Inf values from frame 3",
    "narrow": "feature width 100, expected 263",
    "no_caption": "caption file is missing",
    "garbage": "not a readable .npy file",
}


# ---- the scene: a corpus, configs, takes, tmpfs mounts -------------------------------------------------------------


def _config(corpus: Path, **changes: object) -> dict:
    data = {
        "version": 1,
        "corpus": {"path": str(corpus)},
        "styles": [
            {
                "name": "proud",
                "words": {"adjective": "proud", "adverb": "proudly"},
                "examples": [{"source": "000004", "description": "a person walks proudly"}],
            }
        ],
        "method": {"name": "stats"},
        "compute": {"num_cpus": 2, "batch_size": 8, "unit_size": 16},
        "output": "run",
        "seed": 0,
    }
    data.update(changes)
    return data


def _write_yaml(path: Path, data: dict) -> None:
    path.write_text(yaml.safe_dump(data), encoding="utf-8")


def _npy_header_only(shape: tuple[int, ...], size: int) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": "<f4", "fortran_order": False, "shape": shape})
    return buf.getvalue().ljust(size, b"\0")


def _add_bad_clips(corpus: Path) -> None:
    """Clips a run must turn into rejects (with these reasons) while it goes on with the rest."""
    good = np.load(corpus / "new_joint_vecs" / "000001.npy")
    (corpus / "new_joint_vecs" / "huge_header.npy").write_bytes(_npy_header_only((10**9, 263), 192))
    nan = good.copy()
    nan[3, 7] = np.nan
    np.save(corpus / "new_joint_vecs" / "nan_clip.npy", nan)
    np.save(corpus / "new_joint_vecs" / "narrow.npy", good[:, :100])
    np.save(corpus / "new_joint_vecs" / "no_caption.npy", good)
    (corpus / "new_joint_vecs" / "garbage.npy").write_bytes(b"this is not numpy at all")
    caption = (corpus / "texts" / "000001.txt").read_text(encoding="utf-8")
    for name in ("huge_header", "nan_clip", "narrow", "garbage"):
        (corpus / "texts" / f"{name}.txt").write_text(caption, encoding="utf-8")
    for split in ("all", "train"):
        with open(corpus / f"{split}.txt", "a", encoding="utf-8") as handle:
            handle.writelines(f"{name}\n" for name in BAD_CLIPS)


def _mount_tmpfs(path: Path, options: str) -> bool:
    path.mkdir(parents=True, exist_ok=True)
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(path)], capture_output=True)
    return done.returncode == 0


def _build_scene(root: Path) -> None:
    from motionaug.augment.synth import generate_corpus

    corpus = root / "corpus"
    generate_corpus(corpus, N_CLIPS, seed=1)
    _add_bad_clips(corpus)
    _write_yaml(root / "good.yaml", _config(corpus))
    (root / "broken.yaml").write_text("version: 1\ncorpus: {path: corpus\nstyles: [\n", encoding="utf-8")
    _write_yaml(root / "colour.yaml", _config(corpus, colour="red"))
    _write_yaml(root / "type.yaml", _config(corpus, compute={"batch_size": "many"}))
    _write_yaml(root / "method.yaml", _config(corpus, method={"name": "nope"}))
    _write_yaml(root / "param.yaml", _config(corpus, method={"name": "stats", "params": {"strength": 3}}))
    _write_yaml(root / "nocorpus.yaml", _config(root / "no-such-corpus"))
    for name, source in (("nofile", "nope.npy"), ("noexample", "999999"), ("short", "short.npy")):
        data = _config(corpus)
        data["styles"][0]["examples"][0]["source"] = source
        _write_yaml(root / f"{name}.yaml", data)
    noref = _config(corpus)
    noref["styles"][0]["examples"][0]["reference"] = "999999"
    _write_yaml(root / "noref.yaml", noref)
    np.save(root / "short.npy", np.zeros((5, 263), dtype=np.float32))
    hashed = _config(corpus)
    hashed["styles"][0]["words"]["phrases"] = ["in a #1 way"]
    _write_yaml(root / "hash.yaml", hashed)
    nothing = _config(corpus)
    nothing["corpus"]["filters"] = {"contents": ["fly"]}
    _write_yaml(root / "nothing.yaml", nothing)
    (root / "mine").mkdir()
    (root / "mine" / "notes.txt").write_text("not a run, not a corpus\n", encoding="utf-8")
    bvh = TEMPLATE.read_text(encoding="utf-8")
    for folder, name, text in (
        ("takes", "dataset-2_walk_proud_001", bvh),
        ("unlabelled", "my_take", bvh),
        ("rig", "dataset-2_walk_proud_002", bvh.replace("Hips", "Pelvis")),
    ):
        (root / folder).mkdir(exist_ok=True)
        (root / folder / f"{name}.bvh").write_text(text, encoding="utf-8")
    (root / "map.json").write_text(json.dumps({"version": 1, "name": "half", "scale": 0.01, "joints": {}}))


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    root = tmp_path_factory.mktemp("catalogue")
    _build_scene(root)
    mounts = ((root / "ro", "ro,size=64k"), (root / "full", "size=64k"), (root / "small", "size=128k"))
    mounted = [p for p, o in mounts if _mount_tmpfs(p, o)]
    if len(mounted) < len(mounts):
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail("cannot mount a tmpfs for the read-only and full-disk cases (run as root)")
        pytest.skip("cannot mount a tmpfs (not root?): the disk cases need one")
    try:
        with not_a_dashboard() as url:
            NOT_RAY[:] = [url]
            yield root
    finally:
        for path in mounted:
            subprocess.run(["umount", str(path)], capture_output=True)


# ---- running the command ---------------------------------------------------------------------------------------------


def _motionaug(root: Path, *args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0", "COLUMNS": "200", "NO_COLOR": "1"}
    args = tuple(arg.format(not_ray=NOT_RAY[0]) if arg == "{not_ray}" else arg for arg in args)
    return subprocess.run(
        [str(MOTIONAUG), *args], cwd=root, env=env, capture_output=True, text=True, timeout=timeout, check=False
    )


NOT_RAY: list[str] = []  # the URL of an HTTP server that is not a Ray dashboard (every path: 404), set by ``scene``


@contextmanager
def not_a_dashboard() -> Iterator[str]:
    """A plain HTTP server on 127.0.0.1 answering 404 to everything, as a web server that is not Ray's would."""
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), http.server.SimpleHTTPRequestHandler)
    server.RequestHandlerClass = type("NotFound", (http.server.BaseHTTPRequestHandler,), {"do_GET": _not_found})
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()


def _not_found(handler: http.server.BaseHTTPRequestHandler) -> None:
    handler.send_error(404)


def _snapshot(root: Path) -> dict[str, str]:
    """sha256 of every file under ``root`` (what a failing command must leave as it was)."""
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


class Zygote:
    """tests/cli_zygote.py: runs command lines in forked children of one process that imported the CLI once."""

    def __init__(self, scratch: Path) -> None:
        env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0", "COLUMNS": "200", "NO_COLOR": "1"}
        self.scratch = scratch
        self.process = subprocess.Popen(
            [sys.executable, str(REPO / "tests" / "cli_zygote.py")],
            env=env,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            start_new_session=True,
        )

    def run(self, root: Path, case: Case, timeout: float = 300) -> subprocess.CompletedProcess:
        args = [arg.format(not_ray=NOT_RAY[0]) if arg == "{not_ray}" else arg for arg in case.args]
        out, err = self.scratch / f"{case.id}.out", self.scratch / f"{case.id}.err"
        assert self.process.stdin is not None and self.process.stdout is not None
        request = {"args": args, "cwd": str(root), "stdout": str(out), "stderr": str(err)}
        self.process.stdin.write(json.dumps(request) + "\n")
        self.process.stdin.flush()
        ready, _, _ = select.select([self.process.stdout], [], [], timeout)
        if not ready:
            self.close()
            raise TimeoutError(f"{case.id}: no answer in {timeout:.0f} s")
        code = int(self.process.stdout.readline())
        return subprocess.CompletedProcess(args, code, out.read_text(), err.read_text())

    def close(self) -> None:
        if self.process.poll() is None:
            os.killpg(self.process.pid, signal.SIGKILL)
        self.process.wait()


def _run_all(root: Path, cases: list[Case], workers: int = 4) -> dict[str, subprocess.CompletedProcess]:
    """Every case's command through ``workers`` zygotes (their answers outside ``root``, whose files are checked)."""
    with tempfile.TemporaryDirectory(prefix="catalogue-") as scratch:
        zygotes = [Zygote(Path(scratch)) for _ in range(workers)]
        try:
            with ThreadPoolExecutor(max_workers=workers) as pool:
                chunks = pool.map(
                    lambda i: [(c.id, zygotes[i].run(root, c)) for c in cases[i::workers]], range(workers)
                )
                return dict(pair for chunk in chunks for pair in chunk)
        finally:
            for zygote in zygotes:
                zygote.close()


def _check(case: Case, result: subprocess.CompletedProcess) -> None:
    output = result.stdout + result.stderr
    assert "Traceback" not in output, output
    errors = [line for line in output.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and case.says in errors[0], output
    assert result.returncode == case.code, output


def _one_line_only(result: subprocess.CompletedProcess) -> list[str]:
    lines = (result.stdout + result.stderr).splitlines()
    return [line for line in lines if line.strip() and not RAY_LOG.match(line)]


@pytest.fixture(scope="module")
def fast_results(scene: Path) -> tuple[dict[str, subprocess.CompletedProcess], dict[str, str], dict[str, str]]:
    before = _snapshot(scene)
    results = _run_all(scene, FAST)
    return results, before, _snapshot(scene)


@pytest.mark.parametrize("case", FAST, ids=[case.id for case in FAST])
def test_bad_input_is_one_line_with_its_exit_code(case: Case, fast_results, scene: Path) -> None:
    results, _, _ = fast_results
    _check(case, results[case.id])
    assert len(_one_line_only(results[case.id])) == 1, results[case.id].stdout + results[case.id].stderr


def test_nothing_already_written_was_lost_or_changed(fast_results) -> None:
    _, before, after = fast_results
    assert {k: v for k, v in after.items() if k in before} == before


def test_every_case_is_documented() -> None:
    doc = ERRORS_DOC.read_text(encoding="utf-8")
    cases = [*FAST, *AFTER_RUN, IN_TASK]
    missing = [case.id for case in cases if f"`{case.id}`" not in doc]
    assert not missing, f"docs/errors.md lacks {missing}"
    assert len(cases) + len(BAD_CLIPS) >= 15


def test_debug_prints_the_traceback_as_well(scene: Path) -> None:
    result = _motionaug(scene, "--debug", "run", "nope.yaml")
    assert result.returncode == 2 and "Traceback" in result.stderr
    assert result.stderr.strip().splitlines()[-1] == "error: nope.yaml: config file not found"


# ---- the two cases that need Ray ----------------------------------------------------------------------------------


def test_bad_clips_become_rejects_and_a_damaged_shard_is_refused(scene: Path, fast_results) -> None:
    result = _motionaug(scene, "run", "good.yaml", "--out", "run")
    assert result.returncode == 0 and "Traceback" not in result.stdout + result.stderr, result.stderr
    rejects = {
        r["id"]: r["reason"]
        for path in (scene / "run" / "rejects").rglob("*.jsonl")
        for r in map(json.loads, path.read_text(encoding="utf-8").splitlines())
    }
    for clip, reason in BAD_CLIPS.items():
        assert reason in rejects.get(clip, ""), (clip, rejects)
    manifest = json.loads((scene / "run" / "manifest.json").read_text(encoding="utf-8"))
    assert manifest["rows"] > 0 and manifest["rejects"] >= len(BAD_CLIPS)

    shard = sorted((scene / "run" / "shards").rglob("unit-*.parquet"))[0]
    data = bytearray(shard.read_bytes())
    data[len(data) // 2] ^= 0x01
    shard.write_bytes(bytes(data))
    before = _snapshot(scene / "run")
    results = _run_all(scene, AFTER_RUN)
    for case in AFTER_RUN:
        _check(case, results[case.id])
        assert len(_one_line_only(results[case.id])) == 1
    assert _snapshot(scene / "run") == before and not (scene / "exported").exists()


def test_an_error_raised_inside_a_ray_task_is_one_line(scene: Path) -> None:
    result = _motionaug(scene, *IN_TASK.args)
    _check(IN_TASK, result)
    assert (scene / "small" / "run" / "plan.json").is_file(), "the run got as far as its tasks"
    assert not list((scene / "small").rglob("*.parquet"))


def test_filters_that_select_nothing_claim_no_folder(scene: Path, fast_results) -> None:
    """Found by reading the corpus before the run starts: no run folder, no Ray."""
    _check(EMPTY_SELECTION, fast_results[0][EMPTY_SELECTION.id])
    assert not (scene / "run-b").exists()


@pytest.mark.parametrize(
    ("error", "line"),
    [
        (OSError(28, "No space left on device", "/o/run/x.tmp"), "/o/run/x.tmp: no space left on device"),
        (OSError(30, "Read-only file system", "/o/run"), "/o/run: read-only file system"),
        (PermissionError(13, "Permission denied", "/o/run"), "/o/run: permission denied"),
        (OSError("25774 requested and 16352 written"), "no space left on device"),
        (MemoryError(), "out of memory; use smaller units or batches (compute.unit_size, compute.batch_size)"),
    ],
)
def test_os_errors_from_a_ray_task_name_the_path(
    error: BaseException, line: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A task's error comes back wrapped (RayTaskError, as an instance of its cause): the line is the cause's."""
    from ray.exceptions import RayTaskError

    from motionaug.workflows import cli_app
    from motionaug.workflows.cli_app import error_line

    monkeypatch.setattr(cli_app, "_outputs", [])  # no command has said where it writes

    wrapped = RayTaskError("transfer[style=proud,unit=0000]", "Traceback (most recent call last): ...", error)
    assert error_line(error) == line
    assert error_line(wrapped) == line and error_line(wrapped.as_instanceof_cause()) == line
    try:
        raise RuntimeError("while publishing") from error
    except RuntimeError as chained:
        assert error_line(chained) == line
