"""Every command driven with generated bad inputs (``fuzz_cases``): no traceback, no "unexpected" line, only the
documented exit codes with one ``error:`` line, no wait over a minute, and no file of the scene changed.

In-process through typer's CliRunner so that 500+ cases fit in well under a minute. ``bench/bench_fuzz.py`` runs this
module with more cases (``MOTIONAUG_FUZZ_PER_KIND``) and a report file (``MOTIONAUG_FUZZ_REPORT``, one JSON line per
case and one for the scene) from which it prints the figures.
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Iterator
from pathlib import Path

import pytest
from fuzz_cases import KINDS, STRATEGIES, Scene, build_scene, problems, run_case, serving, snapshot
from hypothesis import HealthCheck, given, settings

CASES_PER_KIND = int(os.environ.get("MOTIONAUG_FUZZ_PER_KIND", "90"))  # x 6 kinds = 540 cases in make test
REPORT = os.environ.get("MOTIONAUG_FUZZ_REPORT")


def report(record: dict) -> None:
    """One JSON line for the bench's figures (only when ``MOTIONAUG_FUZZ_REPORT`` names a file)."""
    if REPORT:
        with open(REPORT, "a", encoding="utf-8") as out:
            out.write(json.dumps(record) + "\n")


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Scene]:
    root = tmp_path_factory.mktemp("fuzz-scene")
    build_scene(root)
    before = snapshot(root)
    with serving(root) as served:
        yield served
    changed = sorted(k for k, v in snapshot(root).items() if before.get(k) != v)
    report({"scene_files_changed": changed})
    assert not changed, f"a fuzz case changed a file of the scene: {changed}"


@pytest.mark.parametrize("kind", KINDS)
def test_generated_bad_inputs_get_a_documented_answer(kind: str, scene: Scene, tmp_path: Path) -> None:
    seen: list[int] = []

    @settings(
        max_examples=CASES_PER_KIND,
        deadline=None,
        derandomize=True,
        database=None,
        suppress_health_check=list(HealthCheck),
    )
    @given(case=STRATEGIES[kind])
    def check(case: tuple[str, bytes, list[str]]) -> None:
        work = tmp_path / f"case-{len(seen)}"
        seen.append(1)
        try:
            outcome = run_case(scene, work, case)
        finally:
            shutil.rmtree(work, ignore_errors=True)
        wrong = problems(outcome)
        report(
            {"kind": kind, "code": outcome.code, "seconds": outcome.seconds, "args": outcome.args, "problems": wrong}
        )
        assert not wrong, (wrong, outcome.args, outcome.output[-2000:])

    check()
    assert len(seen) >= min(CASES_PER_KIND, 90)  # a kind may have fewer distinct cases than asked (addresses)
