"""The fault matrix: SIGKILLs, corrupted files, concurrent runs and a full disk against a real local Ray (2 CPUs).

Every case drives ``motionaug run`` as a subprocess (its own process group) against one local cluster started
here, lands its fault at a point found by watching the run folder or the cluster's processes (a Ray worker's
title is ``ray::<task name>`` while it runs that task), then reruns and compares the folder with an
uninterrupted run of the same config and seed: shard files byte-identical, manifest equal but for
``TIMING_FIELDS``, no row lost or duplicated. The stats method on 40 synthetic clips for most cases; the
on-the-fly method (its smoke params, tiny base models) where the fault is in training or fine-tuning.

    .venv/bin/python bench/bench_faults.py                 # the whole matrix: a table on stdout
    .venv/bin/python bench/bench_faults.py --cases kill-driver-stats-transfer-mid corrupt-shard

The full-disk cases mount a tmpfs (root only; skipped otherwise). tests/test_fault_matrix.py runs a subset of
``CASES`` with this code.
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
N_CLIPS = 40
STATS, ONTHEFLY = "stats", "onthefly"
# Two styles with one example each (ids of the synthetic corpus's first clips), as tests/conftest.py's TWO_STYLES.
STYLES = [
    {
        "name": "proud",
        "words": {"adjective": "proud", "adverb": "proudly", "phrases": ["in a proud way"]},
        "examples": [{"source": "000004", "description": "a person walks proudly"}],
    },
    {
        "name": "old",
        "words": {"adjective": "old", "phrases": ["like an old person"]},
        "examples": [{"source": "000008", "description": "a person walks like an old person"}],
    },
]
TIMING_FIELDS = (
    "stages.*.seconds",  # wall clock of this invocation
    "stages.*.skipped",  # what this invocation found already done (a resumed run skips more)
    "artifacts.*.seconds",
    "shards.*.seconds",
    "shards.*.load_seconds",
    "shards.*.peak_rss_mb",  # the worker's memory high-water mark, which depends on what it ran before
)
"""Manifest fields that describe how an invocation ran, not what the run holds: the only ones a resumed run may
change."""
RAY_LOG_LINE = re.compile(r"^\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d+\s+(INFO|WARNING)\s")
TASK_PREFIXES = ("ray::plan", "ray::train", "ray::prepare[", "ray::transfer[")


# ---- runs ---------------------------------------------------------------------------------------------


def config_dict(method: str, corpus: Path, out: Path) -> dict[str, Any]:
    """The run config of a case: stats on all clips, or on-the-fly (smoke params, tiny base models)."""
    data: dict[str, Any] = {
        "corpus": {"path": str(corpus)},
        "styles": copy.deepcopy(STYLES),
        "method": {"name": STATS},
        "compute": {"num_cpus": 2, "batch_size": 3, "unit_size": 4},
        "output": str(out),
        "seed": 0,
    }
    if method == ONTHEFLY:
        from motionaug.augment.methods.registry import method_class

        data["method"] = {"name": ONTHEFLY, "params": dict(method_class(ONTHEFLY).smoke_params)}
        data["base_models"] = {"size": "tiny"}
        data["corpus"]["filters"] = {"source_styles": ["neutral"], "min_frames": 40}
        data["compute"]["unit_size"] = 8
    return data


@dataclass
class Finished:
    returncode: int
    stdout: str
    stderr: str
    seconds: float

    def last_line(self) -> str:
        lines = user_lines(self.stderr) or self.stdout.strip().splitlines() or [""]
        return lines[-1][:200]


def user_lines(stderr: str) -> list[str]:
    """What a user reads on stderr: its non-blank lines without Ray's own timestamped log lines."""
    return [line for line in stderr.splitlines() if line.strip() and not RAY_LOG_LINE.match(line)]


def one_clean_line(result: Finished) -> str | None:
    """The one line a failure printed, or None when it printed a traceback or more or fewer lines."""
    lines = user_lines(result.stderr)
    if "Traceback" in result.stdout + result.stderr or len(lines) != 1:
        return None
    return lines[0]


@dataclass
class Harness:
    """One local Ray, a corpus, and the uninterrupted reference run of each method."""

    address: str
    root: Path
    corpus: Path
    refs: dict[str, Path] = field(default_factory=dict)

    def fresh(self, name: str) -> Path:
        out = self.root / "runs" / name
        shutil.rmtree(out, ignore_errors=True)
        return out

    def config(self, method: str, out: Path) -> Path:
        import yaml

        path = self.root / "configs" / f"{out.name}.yaml"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(yaml.safe_dump(config_dict(method, self.corpus, out)), encoding="utf-8")
        return path

    def command(self, method: str, out: Path, *extra: str) -> list[str]:
        cli = [sys.executable, "-m", "motionaug.workflows.cli", "run", str(self.config(method, out))]
        return [*cli, "--address", self.address, *extra]

    def start(self, method: str, out: Path, *extra: str) -> subprocess.Popen:
        """``motionaug run`` in its own process group (so a kill takes the whole driver)."""
        logs = self.root / "logs"
        logs.mkdir(exist_ok=True)
        stdout = open(logs / f"{out.name}.{time.monotonic_ns()}.log", "wb")  # noqa: SIM115 - the child owns it
        return subprocess.Popen(
            self.command(method, out, *extra),
            cwd=REPO,
            env=child_env(),
            stdout=stdout,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )

    def run(self, method: str, out: Path, *extra: str, timeout: float = 1800) -> Finished:
        start = time.perf_counter()
        done = subprocess.run(
            self.command(method, out, *extra), cwd=REPO, env=child_env(), capture_output=True, text=True,
            timeout=timeout,
        )  # fmt: skip
        return Finished(done.returncode, done.stdout, done.stderr, time.perf_counter() - start)

    def reference(self, method: str) -> Path:
        """The uninterrupted run every case of ``method`` is compared with (made once)."""
        if method not in self.refs:
            out = self.fresh(f"reference-{method}")
            result = self.run(method, out)
            if result.returncode != 0:
                raise RuntimeError(f"reference {method} run failed: {result.last_line()}")
            self.refs[method] = out
        return self.refs[method]


def child_env() -> dict[str, str]:
    return {**os.environ, "RAY_USAGE_STATS_ENABLED": "0", "PYTHONUNBUFFERED": "1"}


@contextmanager
def local_cluster() -> Iterator[str]:
    """A private local Ray with 2 CPUs; yields its address (every case's driver joins it)."""
    import ray

    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        yield ray.get_runtime_context().gcs_address
    finally:
        ray.shutdown()


# ---- processes ----------------------------------------------------------------------------------------


def _children_map() -> dict[int, list[int]]:
    children: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        children.setdefault(int(fields[1]), []).append(int(stat.parent.name))
    return children


def descendants(pid: int) -> list[int]:
    """Every process below ``pid`` (the cluster this process started is below it; other users' Rays are not)."""
    children, found, todo = _children_map(), [], [pid]
    while todo:
        kids = children.get(todo.pop(), [])
        found.extend(kids)
        todo.extend(kids)
    return found


def title(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")[0].decode(errors="replace")
    except OSError:
        return ""


def task_pids(prefix: str) -> list[int]:
    """Workers of this process's cluster running a task whose title starts with ``prefix``."""
    return [pid for pid in descendants(os.getpid()) if title(pid).startswith(prefix)]


def wait_until_idle(timeout: float = 60) -> bool:
    """Wait until no worker of this cluster runs a pipeline task (a killed driver's tasks are being reaped)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if not any(task_pids(prefix) for prefix in TASK_PREFIXES):
            return True
        time.sleep(0.1)
    return False


Trigger = Callable[[Path, int], bool]
Case = Callable[..., "CaseResult"]


def count(pattern: str, n: int = 1) -> Trigger:
    """Fires once ``n`` paths of the run folder match ``pattern``."""
    return lambda out, pid: len(list(out.glob(pattern))) >= n


def task_running(prefix: str) -> Trigger:
    return lambda out, pid: bool(task_pids(prefix))


def manifest_building(out: Path, pid: int) -> bool:
    """The driver is in the manifest stage: its ``git describe`` child (the code version) runs, or it wrote."""
    return any(title(kid).endswith("git") for kid in descendants(pid)) or (out / "manifest.json").exists()


def kill_when(proc: subprocess.Popen, out: Path, trigger: Trigger, timeout: float = 1800) -> str:
    """SIGKILL the driver's process group the moment ``trigger`` fires; says "fired", "ended" or "timed out"."""
    deadline = time.monotonic() + timeout
    outcome = "timed out"
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            outcome = "ended"
            break
        if trigger(out, proc.pid):
            outcome = "fired"
            break
        time.sleep(0.003)
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    return outcome


def landing(out: Path) -> str:
    """Where a kill landed, from what the run folder holds."""
    facts = [
        f"plan {'yes' if (out / 'plan.json').exists() else 'no'}",
        f"base {'yes' if (out / 'base_models' / 'base.json').exists() else 'no'}",
        f"styles {len(list(out.glob('styles/*.done')))}",
        f"shards {len(list(out.glob('shards/style=*/_unit-*.done')))}",
        f"manifest {'yes' if (out / 'manifest.json').exists() else 'no'}",
    ]
    return ", ".join(facts)


# ---- comparison ------------------------------------------------------------------------------------------


@dataclass
class Comparison:
    lost: int
    duplicated: int
    problems: list[str]

    @property
    def ok(self) -> bool:
        return not self.problems


def output_ids(run: Path) -> Counter[str]:
    """Every row's output id, over every shard file a dataset reader would see."""
    import pyarrow.parquet as pq

    ids: Counter[str] = Counter()
    for path in sorted(run.glob("shards/style=*/unit-*.parquet")):
        try:
            ids.update(pq.read_table(path, columns=["output_id"])["output_id"].to_pylist())
        except Exception:  # noqa: BLE001 - an unreadable shard loses its rows; counted as lost
            continue
    return ids


def shard_digests(run: Path) -> dict[str, str]:
    from motionaug.augment.outputs.checksums import sha256_file

    return {p.relative_to(run).as_posix(): sha256_file(p) for p in sorted(run.glob("shards/style=*/unit-*.parquet"))}


def drop_field(data: Any, path: list[str]) -> None:
    """Remove the dotted ``path`` (``*``: every key or element) from nested dicts and lists."""
    head, rest = path[0], path[1:]
    if head == "*":
        items = data.values() if isinstance(data, dict) else data if isinstance(data, list) else []
        for item in items:
            if rest:
                drop_field(item, rest)
        return
    if isinstance(data, dict) and head in data:
        if rest:
            drop_field(data[head], rest)
        else:
            del data[head]


def comparable_manifest(run: Path) -> dict[str, Any]:
    """The manifest without ``TIMING_FIELDS``, the run folder's own path written as ``<run>``."""
    text = (run / "manifest.json").read_text(encoding="utf-8").replace(json.dumps(str(run))[1:-1], "<run>")
    data = json.loads(text)
    for dotted in TIMING_FIELDS:
        drop_field(data, dotted.split("."))
    return data


def _flat(data: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(data, dict):
        return {k: v for key, value in data.items() for k, v in _flat(value, f"{prefix}{key}.").items()}
    if isinstance(data, list):
        return {k: v for i, value in enumerate(data) for k, v in _flat(value, f"{prefix}{i}.").items()}
    return {prefix.rstrip("."): data}


def manifest_differences(run: Path, ref: Path) -> list[str]:
    try:
        a, b = _flat(comparable_manifest(run)), _flat(comparable_manifest(ref))
    except (OSError, ValueError) as err:
        return [f"manifest unreadable: {err}"]
    return sorted(k for k in a.keys() | b.keys() if a.get(k) != b.get(k))


def compare(run: Path, ref: Path) -> Comparison:
    """Rows lost and duplicated against the reference, and every way the run differs from it."""
    got, want = output_ids(run), output_ids(ref)
    lost = len(set(want) - set(got))
    duplicated = sum(n - 1 for n in got.values() if n > 1)
    problems = []
    if extra := set(got) - set(want):
        problems.append(f"{len(extra)} rows the reference does not have")
    if lost or duplicated:
        problems.append(f"{lost} rows lost, {duplicated} duplicated")
    mine, theirs = shard_digests(run), shard_digests(ref)
    if differing := sorted(k for k in mine.keys() | theirs.keys() if mine.get(k) != theirs.get(k)):
        problems.append(f"shards differ: {', '.join(differing[:3])}")
    if differing := manifest_differences(run, ref):
        problems.append(f"manifest differs at {', '.join(differing[:4])}")
    if not (run / "_SUCCESS").is_file():
        problems.append("no _SUCCESS")
    if leftovers := sorted(p.name for p in run.rglob("*.tmp")):
        problems.append(f"temporaries left: {', '.join(leftovers[:2])}")
    return Comparison(lost, duplicated, problems)


# ---- cases ------------------------------------------------------------------------------------------------


@dataclass
class CaseResult:
    case: str
    ok: bool
    lost: int | None
    duplicated: int | None
    seconds: float
    note: str

    @property
    def result(self) -> str:
        return "pass" if self.ok else "FAIL"


def _settle(h: Harness, case: str, method: str, out: Path, start: float, note: str) -> CaseResult:
    """Rerun to completion, compare with the reference, and say how it went."""
    rerun = h.run(method, out)
    cmp = compare(out, h.reference(method))
    if rerun.returncode != 0:
        cmp.problems.insert(0, f"rerun exit {rerun.returncode}: {rerun.last_line()}")
    text = "; ".join([note, *cmp.problems])
    return CaseResult(case, cmp.ok, cmp.lost, cmp.duplicated, time.perf_counter() - start, text)


def kill_driver(method: str, trigger: Trigger, where: str) -> Case:
    """SIGKILL the driver when ``trigger`` fires, rerun, compare."""

    def case(h: Harness, name: str) -> CaseResult:
        h.reference(method)
        start = time.perf_counter()
        out = h.fresh(name)
        outcome = kill_when(h.start(method, out), out, trigger)
        landed = landing(out)
        wait_until_idle()
        if outcome != "fired" or (out / "_SUCCESS").exists():
            note = f"missed {where}: the run {outcome} first ({landed})"
            return CaseResult(name, False, None, None, time.perf_counter() - start, note)
        return _settle(h, name, method, out, start, f"killed {where} ({landed})")

    return case


def kill_worker(method: str, prefix: str) -> Case:
    """SIGKILL the Ray worker running a ``prefix`` task; Ray retries it; the run and a rerun give the same rows."""

    def case(h: Harness, name: str) -> CaseResult:
        h.reference(method)
        start = time.perf_counter()
        out = h.fresh(name)
        proc = h.start(method, out)
        killed = ""
        deadline = time.monotonic() + 1800
        while proc.poll() is None and not killed and time.monotonic() < deadline:
            for pid in task_pids(prefix):
                killed = title(pid).removeprefix("ray::")
                os.kill(pid, signal.SIGKILL)
                break
            time.sleep(0.003)
        code = proc.wait(timeout=1800)
        if not killed:
            return CaseResult(name, False, None, None, time.perf_counter() - start, "no worker found to kill")
        note = f"killed the worker of {killed}; the run exited {code}"
        if code != 0:
            return _settle(h, name, method, out, start, note + " (not retried)")
        return _settle(h, name, method, out, start, note)

    return case


def flip_byte(path: Path) -> None:
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))


def truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def garble(path: Path) -> None:
    path.write_text('{"version": 1, "torn', encoding="utf-8")


def _redone(out: Path) -> dict[str, int]:
    """Per stage, the units the last invocation ran (tasks minus skipped, from the manifest)."""
    stages = json.loads((out / "manifest.json").read_text(encoding="utf-8"))["stages"]
    return {name: s["tasks"] - s.get("skipped", 0) for name, s in stages.items()}


def finished(h: Harness, name: str, shared: Path | None) -> Path | None:
    """A complete stats run folder: ``shared`` (made once, left repaired by each case) or a fresh one."""
    out = shared or h.fresh(name)
    if (out / "_SUCCESS").exists() or h.run(STATS, out).returncode == 0:
        return out
    return None


def corrupt(relative: str, damage: Callable[[Path], None], redo: dict[str, int]) -> Case:
    """Damage one file of a finished stats run; the rerun must redo exactly ``redo`` (it was detected) and end
    with the reference's rows."""

    def case(h: Harness, name: str, shared: Path | None = None) -> CaseResult:
        h.reference(STATS)
        start = time.perf_counter()
        out = finished(h, name, shared)
        if out is None:
            return CaseResult(name, False, None, None, time.perf_counter() - start, "could not make the run")
        damage(out / relative)
        result = _settle(h, name, STATS, out, start, f"{damage.__name__} {relative}")
        redone = _redone(out) if (out / "manifest.json").exists() else {}
        missed = {k: v for k, v in redo.items() if redone.get(k) != v}
        if missed:
            result.ok = False
            result.note += f"; not detected: redid {redone}, expected {redo}"
        elif result.ok:
            result.note += f"; redid {', '.join(f'{k} {v}' for k, v in redo.items())}"
        return result

    return case


def corrupt_manifest(h: Harness, name: str, shared: Path | None = None) -> CaseResult:
    """A torn manifest: reading the run (export) says so in one line; the rerun writes it again."""
    h.reference(STATS)
    start = time.perf_counter()
    out = finished(h, name, shared)
    if out is None:
        return CaseResult(name, False, None, None, time.perf_counter() - start, "could not make the run")
    garble(out / "manifest.json")
    line = one_clean_line(cli("export", str(out), "--out", str(h.root / "exports" / name), "--format", "parquet"))
    result = _settle(h, name, STATS, out, start, f"export said: {line}")
    result.ok = result.ok and line is not None and "manifest" in line
    return result


def verified_read(h: Harness, name: str, shared: Path | None = None) -> CaseResult:
    """A flipped bit in a shard: export refuses in one line naming it and ``motionaug run``; a rerun repairs it."""
    h.reference(STATS)
    start = time.perf_counter()
    out = finished(h, name, shared)
    if out is None:
        return CaseResult(name, False, None, None, time.perf_counter() - start, "could not make the run")
    shard = "shards/style=old/unit-00002.parquet"
    flip_byte(out / shard)
    target = h.root / "exports" / name
    refused = cli("export", str(out), "--out", str(target), "--format", "parquet")
    line = one_clean_line(refused)
    named = line is not None and "unit-00002" in line and "motionaug run" in line
    result = _settle(h, name, STATS, out, start, f"export exit {refused.returncode}: {line or refused.last_line()}")
    shutil.rmtree(target, ignore_errors=True)
    again = cli("export", str(out), "--out", str(target), "--format", "parquet")
    result.ok = result.ok and refused.returncode != 0 and named and again.returncode == 0
    if again.returncode != 0:
        result.note += f"; export after the rerun: {again.last_line()}"
    return result


def cli(*args: str, timeout: float = 1800) -> Finished:
    start = time.perf_counter()
    cmd = [sys.executable, "-m", "motionaug.workflows.cli", *args]
    done = subprocess.run(cmd, cwd=REPO, env=child_env(), capture_output=True, text=True, timeout=timeout)
    return Finished(done.returncode, done.stdout, done.stderr, time.perf_counter() - start)


def concurrent_runs(h: Harness, name: str) -> CaseResult:
    """A second ``motionaug run`` (and a ``--force``) on a folder a live run writes: both refused in one line.

    The first driver is paused (SIGSTOP) while the others start, so it is alive however slow they are to start.
    """
    h.reference(STATS)
    start = time.perf_counter()
    out = h.fresh(name)
    first = h.start(STATS, out)
    if not kill_when_paused(first, out, count("plan.json")):
        return CaseResult(name, False, None, None, time.perf_counter() - start, "first run ended before the check")
    try:
        second = h.run(STATS, out)
        forced = h.run(STATS, out, "--force")
    finally:
        os.killpg(first.pid, signal.SIGCONT)
    code = first.wait(timeout=1800)
    lines = [one_clean_line(second), one_clean_line(forced)]
    refused = second.returncode != 0 and forced.returncode != 0 and all(lines)
    note = f"second exit {second.returncode}: {lines[0] or second.last_line()}; --force exit {forced.returncode}"
    if code != 0:
        note += f"; the first run exited {code}"
    result = _settle(h, name, STATS, out, start, note)
    result.ok = result.ok and refused and code == 0
    return result


def kill_when_paused(proc: subprocess.Popen, out: Path, trigger: Trigger, timeout: float = 1800) -> bool:
    """SIGSTOP the driver's group when ``trigger`` fires; False when the run ended first."""
    deadline = time.monotonic() + timeout
    while proc.poll() is None and time.monotonic() < deadline:
        if trigger(out, proc.pid):
            os.killpg(proc.pid, signal.SIGSTOP)
            return True
        time.sleep(0.003)
    return False


@contextmanager
def small_disk(where: Path, mebibytes: int) -> Iterator[Path]:
    """A tmpfs of ``mebibytes`` at ``where`` (root only), unmounted after."""
    where.mkdir(parents=True, exist_ok=True)
    subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={mebibytes}m", "tmpfs", str(where)], check=True)
    try:
        yield where
    finally:
        subprocess.run(["umount", "-l", str(where)], check=False)


def fill(disk: Path, leave_kib: int) -> Path:
    """A filler file leaving about ``leave_kib`` KiB free on ``disk``."""
    stat = os.statvfs(disk)
    size = max(0, stat.f_bavail * stat.f_frsize - leave_kib * 1024)
    filler = disk / "filler.bin"
    with open(filler, "wb") as handle:
        handle.write(b"\0" * size)
    return filler


def full_disk(leave_kib: int) -> Case:
    """The run folder on a disk that fills up: one clean line, exit non-zero; freed, the rerun completes."""

    def case(h: Harness, name: str) -> CaseResult:
        h.reference(STATS)
        start = time.perf_counter()
        with small_disk(h.root / "disks" / name, 32) as disk:
            out = disk / "run"
            filler = fill(disk, leave_kib)
            failed = h.run(STATS, out)
            line = one_clean_line(failed)
            filler.unlink()
            shown = " | ".join(user_lines(failed.stderr)[-4:])
            note = f"exit {failed.returncode}: {line or 'NOT ONE LINE: ' + shown}"
            result = _settle(h, name, STATS, out, start, note)
        result.ok = result.ok and failed.returncode != 0 and line is not None and "space" in line.lower()
        return result

    return case


def is_root() -> bool:
    return os.geteuid() == 0


CASES: dict[str, Case] = {
    # the driver killed (stats: plan, prepare, transfer, manifest; on-the-fly: training and fine-tuning)
    "kill-driver-stats-plan-mid": kill_driver(STATS, task_running("ray::plan"), "in the plan task"),
    "kill-driver-stats-plan-done": kill_driver(STATS, count("plan.json"), "once plan.json was written"),
    "kill-driver-stats-prepare-mid": kill_driver(STATS, count("styles/*.done"), "after the first of 2 styles"),
    "kill-driver-stats-prepare-done": kill_driver(STATS, count("styles/*.done", 2), "once both styles were ready"),
    "kill-driver-stats-transfer-mid": kill_driver(
        STATS, count("shards/style=*/_unit-*.done", 10), "after 10 of 20 shards"
    ),
    "kill-driver-stats-transfer-done": kill_driver(
        STATS, count("shards/style=*/_unit-*.done", 20), "once all 20 shards were written"
    ),
    "kill-driver-stats-manifest-mid": kill_driver(STATS, manifest_building, "while the manifest was built"),
    "kill-driver-onthefly-train-mid": kill_driver(
        ONTHEFLY, count("base_models/checkpoints/prior/*"), "at the prior's first checkpoint"
    ),
    "kill-driver-onthefly-train-done": kill_driver(
        ONTHEFLY, count("base_models/base.json"), "once the base models were written"
    ),
    "kill-driver-onthefly-prepare-mid": kill_driver(ONTHEFLY, task_running("ray::prepare["), "in a fine-tune task"),
    "kill-driver-onthefly-prepare-done": kill_driver(
        ONTHEFLY, count("styles/*.done"), "after the first of 2 fine-tunes"
    ),
    "kill-driver-onthefly-transfer-mid": kill_driver(
        ONTHEFLY, count("shards/style=*/_unit-*.done"), "after the first of 4 shards"
    ),
    # a Ray worker killed mid-task (Ray retries the task)
    "kill-worker-stats-transfer": kill_worker(STATS, "ray::transfer["),
    "kill-worker-onthefly-train": kill_worker(ONTHEFLY, "ray::train"),
    "kill-worker-onthefly-prepare": kill_worker(ONTHEFLY, "ray::prepare["),
    # damaged files
    "corrupt-shard": corrupt("shards/style=proud/unit-00003.parquet", flip_byte, {"transfer": 1}),
    "truncate-shard": corrupt("shards/style=old/unit-00005.parquet", truncate, {"transfer": 1}),
    "corrupt-shard-marker": corrupt("shards/style=proud/_unit-00004.done", garble, {"transfer": 1}),
    "corrupt-artefact": corrupt("styles/old/weights.safetensors", flip_byte, {"prepare": 1}),
    "corrupt-artefact-marker": corrupt("styles/proud.done", garble, {"prepare": 1}),
    "corrupt-plan": corrupt("plan.json", garble, {"plan": 1}),
    "corrupt-manifest": corrupt_manifest,
    "verified-read": verified_read,
    # two writers; a full disk
    "concurrent-runs": concurrent_runs,
    "full-disk-in-a-task": full_disk(leave_kib=3 * 1024),
    "full-disk-at-start": full_disk(leave_kib=0),
}
ROOT_ONLY = {"full-disk-in-a-task", "full-disk-at-start"}
SHARED_FOLDER = {
    "corrupt-shard",
    "truncate-shard",
    "corrupt-shard-marker",
    "corrupt-artefact",
    "corrupt-artefact-marker",
    "corrupt-plan",
    "corrupt-manifest",
    "verified-read",
}
"""Cases that may share one finished run folder (``shared=``): each leaves it repaired."""


def run_cases(names: list[str], h: Harness) -> list[CaseResult]:
    results = []
    for name in names:
        if name in ROOT_ONLY and not is_root():
            print(f"{name}: skipped (mounting a tmpfs needs root)", flush=True)
            continue
        try:
            result = CASES[name](h, name)
        except Exception as err:  # noqa: BLE001 - one broken case must not hide the rest of the table
            result = CaseResult(name, False, None, None, 0.0, f"harness error: {type(err).__name__}: {err}")
        print(f"{result.result:4} {name}: {result.note} ({result.seconds:.1f} s)", flush=True)
        results.append(result)
    return results


def table(results: list[CaseResult]) -> str:
    lines = ["| case | result | rows lost | rows duplicated | seconds |", "|---|---|---:|---:|---:|"]
    for r in results:
        lost = "-" if r.lost is None else str(r.lost)
        dup = "-" if r.duplicated is None else str(r.duplicated)
        lines.append(f"| {r.case} | {r.result} | {lost} | {dup} | {r.seconds:.1f} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="*", default=list(CASES), choices=list(CASES))
    parser.add_argument("--json", type=Path, help="Also write the results here.")
    args = parser.parse_args()
    from motionaug.augment.synth import generate_corpus

    with tempfile.TemporaryDirectory(prefix="faults-") as scratch, local_cluster() as address:
        root = Path(scratch)
        generate_corpus(root / "corpus", N_CLIPS, seed=0)
        started = time.perf_counter()
        results = run_cases(args.cases, Harness(address, root, root / "corpus"))
        print(table(results))
        passed = sum(r.ok for r in results)
        print(f"{passed}/{len(results)} cases pass in {time.perf_counter() - started:.0f} s")
        if args.json:
            args.json.write_text(json.dumps([r.__dict__ for r in results], indent=1) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
