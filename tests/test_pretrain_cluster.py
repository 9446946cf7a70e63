"""Data-parallel pre-training on Ray Train: 2 workers on a real local Ray (num_cpus=2) against one process.

Tolerance: the 2-worker run computes each loss on half the batch and averages the gradients with an all-reduce,
so its float sums run in another order than one process's; those last-bit differences pass through AdamW and
grow a little each step. Per-step losses must agree to 1e-4 relative over the 24 + 16 steps here (seen: ~1e-6).
Anything that drew other examples, other noise or another condition-dropout mask per step would differ by
10-100% at once.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

from motionaug.augment.synth import generate_corpus
from motionaug.augment.training.base_models import BASE_JSON
from motionaug.augment.training.pretrain import CHECKPOINTS, LOSS_LOG, Parallel, PretrainConfig, pretrain
from motionaug.models.text_encoder import make_text_encoder
from motionaug.schemas.errors import MotionDataError

RTOL = 1e-4
STOP_AT = 15  # the one-process run is stopped here; its last checkpoint is at step 10


class Interrupt(Exception):
    """Raised from the progress callback to stop a run mid-stage, as a killed process would."""


def config(**overrides: object) -> PretrainConfig:
    defaults = {
        "prior_steps": 24,
        "encoder_steps": 16,
        "classifier_epochs": 2,
        "checkpoint_every": 10,
        "threads": 1,
        "log_every": 1,
        "bf16": False,
        "max_frames": 60,
        "batch_size": 8,
    }
    return PretrainConfig.for_size("tiny", **{**defaults, **overrides})


def losses(out: Path, stage: str) -> dict[int, float]:
    """Per-step training loss; a step logged twice (before a stop and again after resuming) keeps the last."""
    rows = [json.loads(line) for line in (out / LOSS_LOG).read_text(encoding="utf-8").splitlines()]
    return {r["step"]: r["loss"] for r in rows if r["stage"] == stage and "loss" in r}


def logged_steps(out: Path, stage: str) -> list[int]:
    rows = [json.loads(line) for line in (out / LOSS_LOG).read_text(encoding="utf-8").splitlines()]
    return [r["step"] for r in rows if r["stage"] == stage and "loss" in r]


def leave_an_earlier_launchs_ray_train_state(experiment: Path) -> None:
    """Ray Train's run state as a stopped launch leaves it, naming a step folder since rotated away: Ray Train
    refuses to start on it as a corrupted run unless the next launch starts a fresh run state."""
    result = {"version": 0, "checkpoint_dir_name": "prior/step_0000005", "metrics": {"step": 5.0}}
    state = {
        "ray_version": "2.60.0",
        "checkpoint_results": [result],
        "checkpoint_report_indices": [0],
        "latest_checkpoint_result": result,
        "pending_training_results": [],
        "pending_validation_specs": [],
        "current_report_index": 1,
        "validated_checkpoint_dir_names": [],
        "timed_out_validation_checkpoint_dir_names": [],
        "failed_validation_checkpoint_dir_names": [],
    }
    (experiment / "checkpoint_manager_snapshot.json").write_text(json.dumps(state), encoding="utf-8")


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("cluster") / "corpus"
    generate_corpus(root, 24, seed=0)
    return root


def test_batches_that_do_not_split_and_zero_workers_are_refused_before_ray_starts(corpus: Path, tmp_path: Path) -> None:
    from motionaug.workflows.pretrain_cluster import pretrain_on_ray

    with pytest.raises(MotionDataError, match="batch_size 8 does not split evenly over 3 workers"):
        pretrain_on_ray(corpus, tmp_path / "o", config(), workers=3)
    with pytest.raises(MotionDataError, match="at least 1"):
        pretrain_on_ray(corpus, tmp_path / "o", config(), workers=0)
    assert Parallel(1, 4).part(8) == slice(2, 4)


@pytest.mark.slow
def test_two_workers_resume_a_stopped_run_and_follow_the_one_process_loss_curve(
    corpus: Path, ray_cluster, tmp_path: Path
) -> None:
    """One process stopped at prior step 15, resumed on 2 Ray Train workers from its step-10 checkpoint: the
    2 workers then train prior steps 11-24 and the whole motion encoder; every step's loss is the one of an
    uninterrupted one-process run with the same global batch."""
    from motionaug.workflows.pretrain_cluster import pretrain_on_ray

    text_encoder = make_text_encoder("minilm")
    reference, parallel = tmp_path / "one", tmp_path / "two"
    cpu = torch.device("cpu")  # the workers ask for no GPU, so the references train on CPU too
    pretrain(corpus, reference, config(), text_encoder=text_encoder, device=cpu)

    def stop(stage: str, step: int, total: int, metrics: dict[str, float]) -> None:
        if stage == "prior" and step == STOP_AT:
            raise Interrupt

    with pytest.raises(Interrupt):
        pretrain(corpus, parallel, config(), progress=stop, text_encoder=text_encoder, device=cpu)
    leave_an_earlier_launchs_ray_train_state(parallel / CHECKPOINTS)
    pretrain_on_ray(corpus, parallel, config(), workers=2)

    # resumed from the last checkpoint (step 10): steps 11-15 were logged twice, 1-10 once
    assert logged_steps(parallel, "prior") == [*range(1, STOP_AT + 1), *range(11, 25)]
    for stage, steps in (("prior", range(11, 25)), ("motion_encoder", range(1, 17))):
        want, got = losses(reference, stage), losses(parallel, stage)
        assert set(steps) <= set(got)
        for step in steps:
            assert got[step] == pytest.approx(want[step], rel=RTOL), (stage, step)
    for name in ("prior", "motion_encoder"):
        one, two = load_file(reference / f"{name}.safetensors"), load_file(parallel / f"{name}.safetensors")
        assert max(float((one[k] - two[k]).abs().max()) for k in one) < 1e-3, name
    assert (parallel / BASE_JSON).is_file() and (parallel / "evaluators").is_dir()
    # Ray Train tracked the project's checkpoints in place: its latest is the encoder's final step folder
    snapshot = json.loads((parallel / CHECKPOINTS / "checkpoint_manager_snapshot.json").read_text(encoding="utf-8"))
    latest = snapshot["latest_checkpoint_result"]["checkpoint_dir_name"]
    assert latest == "motion_encoder/step_0000016" and (parallel / CHECKPOINTS / latest).is_dir()
