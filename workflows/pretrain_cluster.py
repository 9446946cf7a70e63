"""Data-parallel pre-training on Ray Train: ``motionaug pretrain --workers N`` on a local Ray or a cluster.

Each worker runs the one-process ``pretrain`` on its own device, draws the same seeded global batch, trains on its
equal slice, and DDP averages the gradients: the worker count changes the speed, not the model (up to float reduction
order). Checkpoints stay the project's own (``OUT/checkpoints``, written by rank 0), because they resume bit for bit
whatever the worker count; that folder is also Ray Train's experiment folder, where each checkpoint is reported
without copying. A dead worker makes Ray Train restart the group, which resumes from the last checkpoint like a
re-run of the command; each launch starts a fresh Ray Train run state, since the project rotates step folders an old
state would still list. ``OUT`` must be on storage every node sees.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any

import ray
import ray.train
from ray.train import Checkpoint, CheckpointUploadMode, FailureConfig, RunConfig, ScalingConfig
from ray.train.torch import TorchConfig, TorchTrainer, get_device

from motionaug.augment.training.pretrain import CHECKPOINTS, Parallel, PretrainConfig, pretrain
from motionaug.schemas.errors import MotionDataError
from motionaug.workflows.progress_log import Heartbeat

LOG = logging.getLogger(__name__)

MAX_FAILURES = 2
RAY_TRAIN_SNAPSHOT = "checkpoint_manager_snapshot.json"  # Ray Train's run state in its experiment folder


def _report(metrics: dict[str, float], folder: Path | None) -> None:
    """Tell Ray Train about a checkpoint rank 0 just wrote (in place: it lies inside the experiment folder)."""
    checkpoint = Checkpoint(str(folder)) if folder is not None else None
    ray.train.report(metrics, checkpoint=checkpoint, checkpoint_upload_mode=CheckpointUploadMode.NO_UPLOAD)


def _worker(setup: dict[str, Any]) -> None:
    """One Ray Train worker: the whole pretraining with its rank, on its device (NCCL needs the GPU Ray Train
    gave this worker, gloo the CPU); rank 0 also trains the evaluators and saves."""
    context = ray.train.get_context()
    rank, world = context.get_world_rank(), context.get_world_size()
    config = PretrainConfig.model_validate(setup["config"]).model_copy(update={"threads": setup["threads"]})
    parallel = Parallel(rank, world, _report)
    evaluators = setup.get("evaluators", True)
    if rank != 0:
        pretrain(setup["corpus"], setup["out"], config, None, parallel=parallel, device=get_device())
        return
    # rank 0's progress as a line every log_every seconds (Ray sends worker output to the driver and the job log)
    with Heartbeat("pretrain (rank 0)", every=setup.get("log_every", 10.0), write=LOG.info) as beat:
        options = {"parallel": parallel, "device": get_device(), "evaluators": evaluators}
        pretrain(setup["corpus"], setup["out"], config, beat.update, **options)


def _cpus_per_worker(workers: int) -> int:
    """An equal share of the cluster's CPUs (at least one): each worker sets its torch threads to it."""
    total = int(ray.cluster_resources().get("CPU", 1))
    return max(1, total // workers)


def _check_gpus(gpus_per_worker: float, workers: int) -> None:
    have = ray.cluster_resources().get("GPU", 0.0)
    if gpus_per_worker > 0 and have < gpus_per_worker * workers:
        reason = (
            f"{workers} workers x {gpus_per_worker} GPUs need {gpus_per_worker * workers:g}, the cluster has {have:g}"
        )
        raise MotionDataError("pretrain --gpus-per-worker", reason)


def _first_cause(err: ray.train.TrainingFailedError) -> Exception:
    """The error a worker raised (a MotionDataError stays one line), or Ray Train's own."""
    failures = getattr(err, "worker_failures", None) or {}
    for failure in failures.values():
        cause = getattr(failure, "cause", failure)
        if isinstance(cause, MotionDataError):
            return cause
    return err


def train_on_ray(
    corpus_dir: str | Path,
    out_dir: str | Path,
    config: PretrainConfig,
    workers: int,
    gpus_per_worker: float = 0.0,
    log_every: float = 10.0,
    evaluators: bool = True,
) -> None:
    """Pretrain into ``out_dir`` on ``workers`` Ray Train workers of the Ray this process is connected to."""
    out = Path(out_dir).resolve()
    out.mkdir(parents=True, exist_ok=True)
    # each launch is a new Ray Train run: a previous launch's run state lists step folders the project has since
    # rotated away, which Ray Train refuses as a corrupted run; resuming reads the project's checkpoints instead
    (out / CHECKPOINTS / RAY_TRAIN_SNAPSHOT).unlink(missing_ok=True)
    _check_gpus(gpus_per_worker, workers)
    cpus = _cpus_per_worker(workers)
    resources: dict[str, float] = {"CPU": cpus, **({"GPU": gpus_per_worker} if gpus_per_worker > 0 else {})}
    trainer = TorchTrainer(
        _worker,
        train_loop_config={
            "corpus": str(Path(corpus_dir).resolve()),
            "out": str(out),
            "config": config.model_dump(),
            "threads": config.threads or cpus,
            "log_every": log_every,
            "evaluators": evaluators,
        },
        torch_config=TorchConfig(backend="nccl" if gpus_per_worker > 0 else "gloo"),
        scaling_config=ScalingConfig(num_workers=workers, use_gpu=gpus_per_worker > 0, resources_per_worker=resources),
        run_config=RunConfig(
            name=CHECKPOINTS, storage_path=str(out), failure_config=FailureConfig(max_failures=MAX_FAILURES)
        ),
    )
    try:
        trainer.fit()
    except ray.train.TrainingFailedError as err:
        raise _first_cause(err) from None


def pretrain_on_ray(
    corpus_dir: str | Path,
    out_dir: str | Path,
    config: PretrainConfig,
    workers: int,
    gpus_per_worker: float = 0.0,
    address: str | None = None,
    log_every: float = 10.0,
    evaluators: bool = True,
) -> Path:
    """``ensure_base_models`` with the training on Ray Train; joins ``address`` or starts an embedded Ray.

    An already initialised Ray (a test's, a job driver's) is used as it is.
    """
    from motionaug.augment.training.pretrain import ensure_base_models

    if workers < 1:
        raise MotionDataError("pretrain --workers", f"must be at least 1, got {workers}")
    Parallel(0, workers).part(config.batch_size)  # a batch that does not split is refused before Ray starts
    started = not ray.is_initialized()
    if started:
        os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
        ray.init(address=address, log_to_driver=True)
    try:
        return ensure_base_models(
            corpus_dir,
            out_dir,
            config=config,
            runner=lambda corpus, out, cfg: train_on_ray(
                corpus, out, cfg, workers, gpus_per_worker, log_every, evaluators
            ),
            evaluators=evaluators,
        )
    finally:
        if started:
            ray.shutdown()
