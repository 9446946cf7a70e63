"""Generated bad inputs for every command, more of them than ``make test`` runs, with the figures for RESULTS.md.

    .venv/bin/python bench/bench_fuzz.py --per-kind 500

Draws ``--per-kind`` cases of each kind of ``tests/fuzz_cases.py`` (configs with any field set to anything,
``--set`` values, raw config text, cluster addresses, mangled BVH, bad ``.npy`` clips), runs each ``motionaug``
command in-process and prints: cases, exit codes, tracebacks, "unexpected" lines, other problems, files of the
scene changed, and the longest wait. Exits 1 when any case has a problem.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")

from fuzz_cases import (  # noqa: E402
    KINDS,
    STRATEGIES,
    Outcome,
    Scene,
    build_scene,
    problems,
    run_case,
    serving,
    snapshot,
)
from hypothesis import HealthCheck, given, seed, settings  # noqa: E402


def fuzz_kind(scene: Scene, work: Path, kind: str, n: int, seed_value: int) -> list[Outcome]:
    """``n`` drawn cases of one kind, each run in a fresh folder under ``work`` (removed after)."""
    outcomes: list[Outcome] = []

    @seed(seed_value)
    @settings(max_examples=n, deadline=None, database=None, suppress_health_check=list(HealthCheck))
    @given(case=STRATEGIES[kind])
    def one(case: tuple[str, bytes, list[str]]) -> None:
        folder = work / f"{kind}-{len(outcomes)}"
        try:
            outcomes.append(run_case(scene, folder, case))
        finally:
            shutil.rmtree(folder, ignore_errors=True)

    one()
    return outcomes


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--per-kind", type=int, default=500)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    root = Path(tempfile.mkdtemp(prefix="motionaug-fuzz-"))
    codes: Counter[tuple[str, int]] = Counter()
    found: list[tuple[str, list[str], list[str]]] = []
    longest = (0.0, [""])
    started = time.monotonic()
    try:
        build_scene(root / "scene")
        before = snapshot(root / "scene")
        with serving(root / "scene") as scene:
            for kind in KINDS:
                for outcome in fuzz_kind(scene, root / "work", kind, args.per_kind, args.seed):
                    codes[(kind, outcome.code)] += 1
                    longest = max(longest, (outcome.seconds, outcome.args))
                    wrong = problems(outcome)
                    if wrong:
                        found.append((kind, outcome.args, wrong))
        changed = sorted(k for k, v in snapshot(root / "scene").items() if before.get(k) != v)
    finally:
        shutil.rmtree(root, ignore_errors=True)
    total = sum(codes.values())
    print(f"cases {total} in {time.monotonic() - started:.0f} s; kinds {len(KINDS)}")
    for kind in KINDS:
        row = {code: n for (k, code), n in sorted(codes.items()) if k == kind}
        print(f"  {kind:13s} " + ", ".join(f"exit {code}: {n}" for code, n in row.items()))
    kinds_of = Counter(p.split()[0] for _, _, wrong in found for p in wrong)
    print(f"tracebacks {kinds_of['traceback']}, unexpected {kinds_of['unexpected']}, other problems "
          f"{len(found) - kinds_of['traceback'] - kinds_of['unexpected']}, files changed {len(changed)}")  # fmt: skip
    print(f"longest wait {longest[0]:.2f} s: motionaug {' '.join(longest[1])[:160]}")
    for kind, argv, wrong in found[:20]:
        print(f"  PROBLEM {kind}: {wrong}: {' '.join(argv)[:200]}")
    return 1 if found or changed else 0


if __name__ == "__main__":
    sys.exit(main())
