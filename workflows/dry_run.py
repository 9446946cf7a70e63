"""``motionaug run --dry-run``: the run's plan and what it will cost, before Ray starts or anything is written.

The corpus is read exactly as the plan stage reads it (same filters, same seeded units), so the task counts are
the run's own; seconds and bytes are estimates from the method's measured ``cost_rates``. Nothing is written into
the run folder: a dry run is safe beside a running or finished run.
"""

from __future__ import annotations

import math
import os
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

from rich.table import Table

from motionaug.schemas.run_config import RunConfig
from motionaug.schemas.shards import Plan
from motionaug.workflows.pipeline import PlanStage, check_config, example_coverage, select_clips, trained_dir
from motionaug.workflows.progress_log import format_seconds

# Shard bytes per output frame (Parquet + zstd, 263-dim float32 rows with captions and scores): zstd does better the
# more rows a shard holds, so the size is a log-linear fit to stats shards of a few sizes.
SHARD_BYTES_PER_FRAME = (1240.0, -220.0)  # a + b * log10(rows), kept within [700, 1100]
# Ray's cost per task beyond its own work (scheduling, arguments, marker), from the same scale runs.
TASK_OVERHEAD_S = 0.05


@dataclass
class StageEstimate:
    name: str
    tasks: int
    seconds: float | None  # None: no benchmark rate for this method
    note: str = ""


@dataclass
class DryRun:
    """What ``motionaug run`` would do: tasks per stage, their estimated time, the shards and the disk they need."""

    run_id: str
    output: Path
    clips: int
    rejects: int
    units: int
    slots: int
    plan: Plan
    stages: list[StageEstimate] = field(default_factory=list)
    shards: int = 0
    shard_bytes_mean: float = 0.0
    shard_bytes_max: float = 0.0
    disk_bytes: float = 0.0
    free_bytes: int = 0
    disk_at: Path = Path(".")
    artefacts_measured: bool = True
    notes: list[str] = field(default_factory=list)

    @property
    def seconds(self) -> float | None:
        known = [s.seconds for s in self.stages if s.seconds is not None]
        return sum(known) if known and len(known) == len(self.stages) else None

    @property
    def disk_ok(self) -> bool:
        return self.disk_bytes <= self.free_bytes


def task_slots(config: RunConfig, cpus_per_task: float) -> int:
    """How many tasks run at once: the embedded cluster's CPUs (or this machine's) over a task's CPUs."""
    cpus = config.compute.num_cpus or os.cpu_count() or 1
    return max(1, int(cpus // cpus_per_task))


def shard_bytes_per_frame(rows: int) -> float:
    """Estimated Parquet bytes per motion frame in a shard of ``rows`` clips (``SHARD_BYTES_PER_FRAME``)."""
    a, b = SHARD_BYTES_PER_FRAME
    return min(1100.0, max(700.0, a + b * math.log10(max(rows, 1))))


def free_space(path: Path) -> tuple[Path, int]:
    """Free bytes on the filesystem that will hold ``path`` (its nearest existing ancestor)."""
    probe = path.resolve()
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    return probe, shutil.disk_usage(probe).free


def plan_run(config: RunConfig) -> DryRun:
    """Plan the run as the plan stage would, and estimate each stage from the method's rates; writes nothing."""
    method = check_config(config)
    rate = method.cost_rates
    started = time.perf_counter()
    selection = select_clips(config)  # as PlanStage.run reads it
    stage = PlanStage(config, method)
    stage._check_example_ids(selection.all_ids)
    plan = stage._units(selection, len(selection.unreadable))
    frames = selection.frames
    plan_seconds = time.perf_counter() - started

    slots = task_slots(config, config.compute.transfer_cpus)
    prepare_slots = task_slots(config, config.compute.finetune_cpus)
    shard_bytes = [
        shard_bytes_per_frame(len(ids)) * sum(frames[i] for i in ids)
        for unit in plan.units
        for ids in unit.styles.values()
        if ids
    ]
    pairs = sum(len(ids) for unit in plan.units for ids in unit.styles.values())
    styles = len(config.styles)
    stages = [StageEstimate("plan", 1, plan_seconds, "measured: this dry run read the corpus")]
    if method.trains:
        if method.is_trained(trained_dir(config)):
            stages.append(StageEstimate("train", 0, 0.0, f"reuses {trained_dir(config)}"))
        else:
            stages.append(StageEstimate("train", 1, rate.train_s, "pre-trains the base models"))
    prepare_s = None if rate.prepare_s is None else _waves(styles, prepare_slots) * (rate.prepare_s + TASK_OVERHEAD_S)
    stages.append(StageEstimate("prepare", styles, prepare_s, f"{prepare_slots} at a time"))
    transfer_s = None
    if rate.transfer_clips_per_s:
        transfer_s = (pairs / rate.transfer_clips_per_s + len(shard_bytes) * TASK_OVERHEAD_S) / slots
    stages.append(
        StageEstimate("transfer", len(shard_bytes), transfer_s, f"{pairs:,} clips x styles, {slots} at a time")
    )
    disk_at, free = free_space(config.output)
    return DryRun(
        run_id=config.run_id(),
        output=config.output,
        clips=plan.n_clips,
        rejects=plan.rejects,
        units=len(plan.units),
        slots=slots,
        plan=plan,
        stages=stages,
        shards=len(shard_bytes),
        shard_bytes_mean=sum(shard_bytes) / len(shard_bytes) if shard_bytes else 0.0,
        shard_bytes_max=max(shard_bytes, default=0.0),
        disk_bytes=sum(shard_bytes) + styles * (rate.artefact_bytes or 0) + len(plan.model_dump_json()),
        free_bytes=free,
        disk_at=disk_at,
        artefacts_measured=rate.artefact_bytes is not None,
        notes=example_coverage(config, plan),
    )


def _waves(tasks: int, slots: int) -> int:
    return -(-tasks // slots)


def _size(n: float) -> str:
    for unit in ("B", "KB", "MB", "GB"):
        if n < 1000:
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return f"{n:.1f} TB"


def _time(seconds: float | None) -> str:
    return "not measured" if seconds is None else format_seconds(seconds)


def dry_run_report(d: DryRun) -> list[Table | str]:
    """The dry run as the CLI prints it: a table of stages, then the shards, the disk and the time."""
    table = Table(title=f"dry run of {d.run_id} (nothing run, nothing written)")
    for column in ("stage", "tasks", "estimated", "note"):
        table.add_column(column, justify="left" if column in ("stage", "note") else "right")
    for stage in d.stages:
        table.add_row(stage.name, f"{stage.tasks:,}", _time(stage.seconds), stage.note)
    lines: list[Table | str] = [table]
    lines.append(f"clips {d.clips:,} in {d.units:,} units ({d.rejects} unreadable); {d.slots} tasks at a time")
    lines.append(
        f"shards {d.shards:,}: {_size(d.shard_bytes_mean)} each on average, {_size(d.shard_bytes_max)} at most"
    )
    verdict = "enough" if d.disk_ok else "[red]NOT enough[/red]"
    what = "shards, plan" if d.artefacts_measured else "shards, plan; style artefacts not measured for this method"
    lines.append(f"disk: needs {_size(d.disk_bytes)} ({what}); {_size(d.free_bytes)} free at {d.disk_at}: {verdict}")
    lines.append(f"estimated time {_time(d.seconds)} (the method's measured rates, 2 cores), output {d.output}")
    lines.extend(f"[yellow]warning[/yellow] {note}" for note in d.notes)
    return lines
