"""Generated bad inputs for every command, more of them than ``make test`` runs, with the figures for RESULTS.md.

    .venv/bin/python bench/bench_fuzz.py --per-kind 500

Runs ``tests/test_fuzz_cli.py`` (the kinds of ``tests/fuzz_cases.py``: configs with any field set to anything,
``--set`` values, raw config text, cluster addresses, mangled BVH, bad ``.npy`` clips) with ``--per-kind`` cases of
each kind and prints from its report: cases, exit codes, tracebacks, "unexpected" lines, other problems, files of
the scene changed, and the longest wait. Exits 1 when any case has a problem.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--per-kind", type=int, default=500)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="motionaug-fuzz-") as tmp:
        report = Path(tmp) / "report.jsonl"
        env = {**os.environ, "MOTIONAUG_FUZZ_PER_KIND": str(args.per_kind), "MOTIONAUG_FUZZ_REPORT": str(report)}
        env.setdefault("RAY_USAGE_STATS_ENABLED", "0")
        started = time.monotonic()
        command = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "tests/test_fuzz_cli.py"]
        result = subprocess.run(command, cwd=REPO, env=env, capture_output=True, text=True)
        records = (
            [json.loads(line) for line in report.read_text(encoding="utf-8").splitlines()] if report.exists() else []
        )
    cases = [r for r in records if "kind" in r]
    changed = [f for r in records for f in r.get("scene_files_changed", [])]
    codes = Counter((r["kind"], r["code"]) for r in cases)
    print(f"cases {len(cases)} in {time.monotonic() - started:.0f} s; kinds {len({r['kind'] for r in cases})}")
    for kind in sorted({r["kind"] for r in cases}):
        row = {code: n for (k, code), n in sorted(codes.items()) if k == kind}
        print(f"  {kind:13s} " + ", ".join(f"exit {code}: {n}" for code, n in row.items()))
    found = [r for r in cases if r["problems"]]
    kinds_of = Counter(p.split()[0] for r in found for p in r["problems"])
    print(f"tracebacks {kinds_of['traceback']}, unexpected {kinds_of['unexpected']}, other problems "
          f"{len(found) - kinds_of['traceback'] - kinds_of['unexpected']}, files changed {len(changed)}")  # fmt: skip
    if cases:
        longest = max(cases, key=lambda r: r["seconds"])
        print(f"longest wait {longest['seconds']:.2f} s: motionaug {' '.join(longest['args'])[:160]}")
    for r in found[:20]:
        print(f"  PROBLEM {r['kind']}: {r['problems']}: {' '.join(r['args'])[:200]}")
    if result.returncode != 0:
        print(result.stdout[-3000:])
    return 1 if found or changed or result.returncode != 0 else 0


if __name__ == "__main__":
    sys.exit(main())
