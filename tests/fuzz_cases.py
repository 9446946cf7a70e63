"""Generated bad inputs for every command, shared by ``test_fuzz_cli.py`` (500+ cases in ``make test``) and
``bench/bench_fuzz.py`` (a longer run with figures).

A case is a ``motionaug`` command line run in-process with typer's ``CliRunner`` in a scene folder (a small synthetic
corpus, a good config, a BVH take, a server that is not a Ray dashboard, a closed port). Each kind of case draws its
inputs with hypothesis: configs with a field set to a value of any type, ``--set`` values, raw config text, cluster
addresses, mangled BVH text and ``.npy`` bytes. ``problems`` lists what is wrong with an outcome: a traceback, an
"unexpected" line, an exit code other than 0, 1 or 2, a failure without exactly one ``error:`` line, or a wait over
``MAX_CASE_S``. Nothing a case writes lands in the scene (outputs go to a folder per case, removed after), so the
scene's checksums before and after say whether any input file changed.
"""

from __future__ import annotations

import hashlib
import http.server
import json
import shutil
import socket
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from hypothesis import strategies as st
from typer.testing import CliRunner

REPO = Path(__file__).resolve().parents[1]
TEMPLATE = REPO / "tests" / "fixtures" / "bvh" / "dataset-2" / "data" / "dataset-2_raise-up-left-hand_active_003.bvh"
MAX_CASE_S = 60.0
EXIT_CODES = {0, 1, 2}
KINDS = ("config-field", "override", "config-text", "address", "bvh", "npy")

GOOD = {
    "version": 1,
    "corpus": {"path": "@CORPUS@"},
    "styles": [
        {
            "name": "proud",
            "words": {"adjective": "proud", "adverb": "proudly", "phrases": ["in a proud way"]},
            "examples": [{"source": "000004", "description": "a person walks proudly"}],
        }
    ],
    "method": {"name": "stats", "params": {}},
    "compute": {"num_cpus": 1, "batch_size": 8, "unit_size": 8},
    "output": "run",
    "seed": 0,
}
FIELDS = [
    ("version",),
    ("corpus",),
    ("corpus", "path"),
    ("corpus", "format"),
    ("corpus", "split"),
    ("corpus", "pool_split"),
    ("corpus", "max_clip_frames"),
    ("corpus", "filters"),
    ("corpus", "filters", "contents"),
    ("corpus", "filters", "caption_regex"),
    ("corpus", "filters", "min_frames"),
    ("corpus", "filters", "max_frames"),
    ("styles",),
    ("styles", 0, "name"),
    ("styles", 0, "words"),
    ("styles", 0, "words", "adjective"),
    ("styles", 0, "words", "adverb"),
    ("styles", 0, "words", "phrases"),
    ("styles", 0, "examples"),
    ("styles", 0, "examples", 0, "source"),
    ("styles", 0, "examples", 0, "description"),
    ("method",),
    ("method", "name"),
    ("method", "params"),
    ("method", "params", "strength"),
    ("fan_out", "per_clip"),
    ("base_models", "path"),
    ("base_models", "size"),
    ("compute", "address"),
    ("compute", "num_cpus"),
    ("compute", "finetune_cpus"),
    ("compute", "transfer_cpus"),
    ("compute", "transfer_gpus"),
    ("compute", "finetune_gpus"),
    ("compute", "batch_size"),
    ("compute", "unit_size"),
    ("compute", "connect_timeout_s"),
    ("output",),
    ("seed",),
    ("colour",),
]
WORDS = ["", " ", "#", "a#b", "proud", "nope", "000004", "999999", "corpus", "run", "good.yaml", "mine", "x.npy",
         "../..", "/", "\n", "\x00", "é", "[", "{", ":", "- a", "null", "true", "1e400", "-1", "0", "NaN"]  # fmt: skip
SCALARS = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(10**20), max_value=10**20),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from(WORDS),
    st.text(max_size=12),
)
PLAUSIBLE = st.sampled_from(
    [1, 2, 3, 4, 8, 0, 0.5, 1.0, 64, "all", "train", "test", "neutral", "proud", "stats", True, None, [], {}, ["walk"]]
)
VALUES = PLAUSIBLE | st.recursive(
    SCALARS,
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=5), inner, max_size=3),
    max_leaves=6,
)


@dataclass
class Scene:
    root: Path
    not_ray: str  # an HTTP server that answers 404 to everything
    closed: str  # 127.0.0.1:<a port nothing listens on>


@dataclass
class Outcome:
    args: list[str]
    code: int
    output: str
    seconds: float


def build_scene(root: Path) -> None:
    """The corpus, configs, takes and a foreign folder every case reads; nothing a case writes goes here."""
    from motionaug.augment.synth import generate_corpus

    generate_corpus(root / "corpus", 16, seed=3)
    (root / "good.yaml").write_text(yaml.safe_dump(GOOD).replace("'@CORPUS@'", "corpus"), encoding="utf-8")
    (root / "takes").mkdir()
    shutil.copy(TEMPLATE, root / "takes" / "dataset-2_walk_proud_001.bvh")
    (root / "mine").mkdir()
    (root / "mine" / "notes.txt").write_text("not a run\n", encoding="utf-8")


@contextmanager
def serving(root: Path) -> Iterator[Scene]:
    """The scene with a 404-only HTTP server on 127.0.0.1 and a closed port, for the address cases."""
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _NotFound)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        closed = f"127.0.0.1:{sock.getsockname()[1]}"
    try:
        yield Scene(root, f"http://127.0.0.1:{server.server_address[1]}", closed)
    finally:
        server.shutdown()
        server.server_close()


class _NotFound(http.server.BaseHTTPRequestHandler):
    def do_GET(self) -> None:  # noqa: N802 - http.server's name
        self.send_error(404)

    def log_message(self, *args: object) -> None:
        pass


def snapshot(root: Path) -> dict[str, str]:
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


# ---- the kinds of case --------------------------------------------------------------------------------------------


def _set(data: dict, path: tuple, value: object) -> dict:
    node = data
    for part in path[:-1]:
        if isinstance(node, dict):
            node = node.setdefault(part, {})
        elif isinstance(node, list) and isinstance(part, int) and part < len(node):
            node = node[part]
        else:
            return data
    if isinstance(node, dict):
        node[path[-1]] = value
    elif isinstance(node, list) and isinstance(path[-1], int) and path[-1] < len(node):
        node[path[-1]] = value
    return data


@st.composite
def config_field(draw: st.DrawFn) -> tuple[str, bytes, list[str]]:
    """The good config with one to three fields set to anything (``run CONFIG --dry-run``)."""
    data = json.loads(json.dumps(GOOD))
    for _ in range(draw(st.integers(1, 3))):
        _set(data, draw(st.sampled_from(FIELDS)), draw(VALUES))
    text = yaml.safe_dump(data, allow_unicode=True)
    return "cfg.yaml", text.encode("utf-8", "surrogatepass"), ["run", "{file}", "--dry-run", "--out", "{out}/run"]


@st.composite
def override(draw: st.DrawFn) -> tuple[str, bytes, list[str]]:
    """``--set key=value`` with any key of the config (or none) and any text after the ``=``."""
    key = ".".join(str(p) for p in draw(st.sampled_from(FIELDS)))
    key = draw(st.sampled_from([key, key, "", ".", "compute..num_cpus", "styles.0"]))
    raw = draw(st.one_of(st.sampled_from(WORDS), st.text(max_size=10), VALUES.map(json.dumps)))
    item = draw(st.sampled_from([f"{key}={raw}", key, f"={raw}"]))
    return "", b"", ["run", "good.yaml", "--dry-run", "--out", "{out}/run", "--set", item]


@st.composite
def config_text(draw: st.DrawFn) -> tuple[str, bytes, list[str]]:
    """Raw config bytes: YAML or JSON cut short, junk, binary, a wrong top level (``.yaml``, ``.json``, others)."""
    good = yaml.safe_dump(GOOD).encode()
    content = draw(
        st.one_of(
            st.binary(max_size=64),
            st.text(max_size=64).map(lambda t: t.encode("utf-8", "surrogatepass")),
            st.integers(0, len(good)).map(lambda n: good[:n]),
            st.sampled_from([b"[]", b"- a\n", b"null", b"{", b"\xff\xfe", json.dumps(GOOD).encode()[:-3]]),
        )
    )
    name = draw(st.sampled_from(["c.yaml", "c.json", "c.yml", "c.txt", "c"]))
    return name, content, ["run", "{file}", "--dry-run", "--out", "{out}/run"]


@st.composite
def address(draw: st.DrawFn) -> tuple[str, bytes, list[str]]:
    """Cluster addresses for ``run``, ``submit``, ``status``, ``logs`` and ``cancel``: closed ports, a server that is
    not Ray's, other schemes, malformed ones (never ``auto``: that would join whatever cluster runs here)."""
    given = draw(
        st.sampled_from(
            [
                "{closed}",
                "http://{closed}",
                "https://{closed}",
                "ray://{closed}",
                "{not_ray}",
                "{not_ray}/api",
                "",
                " ",
                "http://",
                "http://127.0.0.1:99999",
                "127.0.0.1:",
                ":6379",
                "127.0.0.1:abc",
                "grpc://127.0.0.1:1",
                "http://[::1",
                "nowhere",
            ]
        )
    )
    command = draw(st.sampled_from(["run", "submit", "status", "logs", "cancel"]))
    if command == "run":
        return "", b"", ["run", "good.yaml", "--out", "{out}/run", "--address", given]
    if command == "submit":
        return "", b"", ["submit", "good.yaml", "--address", given]
    return "", b"", [command, draw(st.sampled_from(["run-x", "motionaug-run-x", ""])), "--address", given]


@st.composite
def bvh(draw: st.DrawFn) -> tuple[str, bytes, list[str]]:
    """The template take mangled: cut short, lines dropped or repeated, tokens replaced (``corpus import-bvh``)."""
    lines = TEMPLATE.read_text(encoding="utf-8").splitlines()
    for _ in range(draw(st.integers(1, 4))):
        at = draw(st.integers(0, len(lines) - 1))
        how = draw(st.sampled_from(["cut", "drop", "repeat", "token"]))
        if how == "cut":
            lines = lines[:at]
        elif how == "drop":
            del lines[at]
        elif how == "repeat":
            lines[at:at] = [lines[at]] * draw(st.integers(1, 300))
        else:
            words = lines[at].split() or [""]
            words[draw(st.integers(0, len(words) - 1))] = draw(st.sampled_from(WORDS[:20] + ["JOINT", "}", "{"]))
            lines[at] = " ".join(words)
        if not lines:
            break
    text = "\n".join(lines) + "\n"
    source = draw(st.sampled_from(["{file}", "{takes}"]))  # the take alone, or its folder beside a good take
    return "dataset-2_walk_proud_002.bvh", text.encode(), ["corpus", "import-bvh", source, "--out", "{out}/c"]


@st.composite
def npy(draw: st.DrawFn) -> tuple[str, bytes, list[str]]:
    """A clip file of the wrong shape, dtype, length or bytes, read through ``corpus inspect`` and ``preview``."""
    shape = draw(st.sampled_from([(0, 263), (5, 263), (30, 263), (30, 100), (263,), (2, 3, 4), (3_000_000, 263)]))
    dtype = draw(st.sampled_from(["<f4", "<f8", "<i4", "|u1", "<c8"]))
    header = _npy_header(shape, dtype)
    body = draw(st.sampled_from(["full", "short", "none", "garbage"]))
    size = int(np.prod(shape)) * np.dtype(dtype).itemsize if body == "full" and np.prod(shape) < 10**6 else 37
    content = header + (bytes(size) if body != "none" else b"")
    if body == "garbage":
        content = draw(st.binary(min_size=1, max_size=200))
    command = draw(st.sampled_from(["inspect", "preview"]))
    args = ["corpus", "inspect", "{out}/corpus"]
    if command == "preview":
        args = ["preview", "{out}/corpus", "--clip", "fuzzed", "--out", "{out}/p.gif", "--max-frames", "5"]
    return "fuzzed.npy", content, args


def _npy_header(shape: tuple[int, ...], dtype: str) -> bytes:
    import io

    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": dtype, "fortran_order": False, "shape": shape})
    return buf.getvalue()


STRATEGIES = {
    "config-field": config_field(),
    "override": override(),
    "config-text": config_text(),
    "address": address(),
    "bvh": bvh(),
    "npy": npy(),
}


# ---- running a case ---------------------------------------------------------------------------------------------


def run_case(scene: Scene, work: Path, case: tuple[str, bytes, list[str]]) -> Outcome:
    """Write the case's file into ``work`` (an npy case into a copy of the corpus), run the command in the scene."""
    import os

    from motionaug.workflows.cli import app

    name, content, args = case
    work.mkdir(parents=True, exist_ok=True)
    file = work / name if name else None
    if name.endswith(".npy"):
        shutil.copytree(scene.root / "corpus", work / "corpus")
        file = work / "corpus" / "new_joint_vecs" / name
        (work / "corpus" / "texts" / "fuzzed.txt").write_text("a person walks#a/DET#0.0#0.0\n", encoding="utf-8")
        with open(work / "corpus" / "all.txt", "a", encoding="utf-8") as handle:
            handle.write("fuzzed\n")
    elif name.endswith(".bvh"):
        file = work / "takes" / name
        file.parent.mkdir()
        shutil.copy(TEMPLATE, work / "takes" / "dataset-2_walk_proud_001.bvh")
    if file is not None:
        file.write_bytes(content.replace(b"@CORPUS@", str(scene.root / "corpus").encode()))
    where = {"{file}": str(file), "{takes}": str(work / "takes"), "{closed}": scene.closed, "{not_ray}": scene.not_ray}
    filled = []
    for arg in args:
        for key, value in where.items():
            arg = arg.replace(key, value)
        filled.append(arg.replace("{out}", str(work)))
    before = os.getcwd()
    os.chdir(scene.root)
    started = time.monotonic()
    try:
        result = CliRunner().invoke(app, filled, env={"COLUMNS": "200", "NO_COLOR": "1"})
    finally:
        os.chdir(before)
    seconds = time.monotonic() - started
    code = result.exit_code if result.exception is None or isinstance(result.exception, SystemExit) else -1
    output = result.output
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        output += f"\nTraceback (escaped the CLI): {type(result.exception).__name__}: {result.exception}"
    return Outcome(filled, code, output, seconds)


def problems(outcome: Outcome) -> list[str]:
    """What is wrong with an outcome (empty: a documented result)."""
    found = []
    lines = outcome.output.splitlines()
    if "Traceback" in outcome.output:
        found.append("traceback")
    if any(line.startswith("error: unexpected ") for line in lines):  # the line of a bug (docs/errors.md)
        found.append("unexpected")
    if outcome.code not in EXIT_CODES:
        found.append(f"exit code {outcome.code}")
    errors = [line for line in lines if line.startswith("error:")]
    usage = any(line.startswith(("Usage:", "Try ", "│", "╭")) for line in lines)  # click's own usage errors
    if outcome.code in (1, 2) and len(errors) != 1 and not usage:
        found.append(f"{len(errors)} error lines")
    if outcome.seconds > MAX_CASE_S:
        found.append(f"waited {outcome.seconds:.0f} s")
    return found
