"""Every command driven with generated bad inputs (``fuzz_cases``): no traceback, no "unexpected" line, only the
documented exit codes with one ``error:`` line, no wait over a minute, and no file of the scene changed.

In-process through typer's CliRunner so that 500+ cases fit in well under a minute; ``bench/bench_fuzz.py`` runs
more of them and reports the figures.
"""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from pathlib import Path

import pytest
from fuzz_cases import KINDS, STRATEGIES, Scene, build_scene, problems, run_case, serving, snapshot
from hypothesis import HealthCheck, given, settings

CASES_PER_KIND = 90  # x 6 kinds = 540 cases


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Scene]:
    root = tmp_path_factory.mktemp("fuzz-scene")
    build_scene(root)
    before = snapshot(root)
    with serving(root) as served:
        yield served
    assert snapshot(root) == before, "a fuzz case changed a file of the scene"


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
        assert not problems(outcome), (problems(outcome), outcome.args, outcome.output[-2000:])

    check()
    assert len(seen) >= CASES_PER_KIND
