"""bench/RESULTS.md stays a short table of current figures whose commands name scripts that exist."""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "bench" / "RESULTS.md"
MAX_LINES = 400
MAX_CHARS = 160
SCRIPT = re.compile(r"(?<![\w/.-])((?:bench|lab)/[\w/.-]+\.py)\b")


def test_results_fits_its_limits() -> None:
    lines = RESULTS.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= MAX_LINES, f"bench/RESULTS.md: {len(lines)} lines (at most {MAX_LINES}); history goes to lab/"
    long = [f"line {n}: {len(line)} chars" for n, line in enumerate(lines, 1) if len(line) > MAX_CHARS]
    assert not long, f"bench/RESULTS.md lines over {MAX_CHARS} characters: {long}"


def test_results_names_only_scripts_that_exist() -> None:
    named = set(SCRIPT.findall(RESULTS.read_text(encoding="utf-8")))
    assert named, "bench/RESULTS.md names no bench/ or lab/ script"
    missing = sorted(path for path in named if not (REPO / path).is_file())
    assert not missing, f"bench/RESULTS.md names scripts that do not exist: {missing}"
