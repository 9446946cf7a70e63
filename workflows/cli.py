"""The ``motionaug`` command line: thin commands that parse, call one library function, render its result.

Errors a user can fix print one line (the thing and the reason): exit 2 for usage, 1 for failure.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Literal

import typer
from pydantic import ValidationError
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TaskID,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)
from rich.table import Table

from motionaug.schemas.errors import MotionConfigError, MotionDataError
from motionaug.workflows import cli_inspect, cli_stream, cli_view  # noqa: F401  (register their commands on the app)
from motionaug.workflows.cli_app import (
    app,
    console,
    corpus_app,
    err_console,
    log_interval,
    note_output,
    off_terminal,
    run_safely,
    usage_errors,
)
from motionaug.workflows.cli_expansion import expansion_app

app.add_typer(expansion_app, name="expansion")

if TYPE_CHECKING:
    from motionaug.schemas.run_config import RunConfig
    from motionaug.workflows.ray_executor import RunSummary


def _facts(title: str, rows: list[tuple[str, object]]) -> Table:
    """A two-column key/value table."""
    table = Table(title=title, show_header=False)
    for key, value in rows:
        table.add_row(key, str(value))
    return table


def _counts(counts: dict[str, int]) -> str:
    return ", ".join(f"{k} {v}" for k, v in counts.items()) or "-"


@corpus_app.command("synth")
def corpus_synth(
    out: Annotated[Path, typer.Option(help="Output folder (HumanML3D layout).")],
    clips: Annotated[int, typer.Option(min=1, help="Number of clips.")] = 1000,
    seed: Annotated[int, typer.Option(help="Seed; the same seed gives byte-identical output.")] = 0,
) -> None:
    """Render the procedural style corpus (the embedded default) in the HumanML3D layout."""
    from motionaug.augment.synth import generate_corpus

    note_output(out)
    with console.status(f"rendering {clips} synthetic clips"):
        summary = run_safely(lambda: generate_corpus(out, clips, seed=seed))
    console.print(
        f"wrote {summary.n_clips} clips ({summary.frames} frames) to {summary.out_dir} in {summary.seconds:.1f} s"
    )


@corpus_app.command("drop-styles")
def corpus_drop_styles(
    corpus: Annotated[Path, typer.Argument(help="A HumanML3D folder with style labels.")],
    styles: Annotated[
        list[str], typer.Option("--style", help="A style to remove, with its counterparts (repeatable).")
    ],
    out: Annotated[Path, typer.Option(help="Output folder (new or empty).")],
) -> None:
    """Copy a corpus without some styles and their counterparts in other corpora, for training a model that has
    never seen them (splits kept, Mean/Std of the remaining train split)."""
    from motionaug.augment.corpus.style_sets import with_counterparts, write_without_styles

    note_output(out)
    with console.status(f"writing {corpus} without {', '.join(styles)}"):
        folder = run_safely(lambda: write_without_styles(corpus, out, styles))
    console.print(f"wrote {folder} without the styles {', '.join(sorted(with_counterparts(styles)))}")


@corpus_app.command("inspect")
def corpus_inspect(path: Annotated[Path, typer.Argument(help="A HumanML3D folder or a Parquet corpus.")]) -> None:
    """Count clips, frames, hours, captions, labels and rejects of a corpus."""
    from motionaug.augment.corpus import inspect_corpus

    info = run_safely(lambda: inspect_corpus(path))
    console.print(
        _facts(
            f"{info.path} ({info.format})",
            [
                ("clips", info.clips),
                ("frames", info.frames),
                ("hours", f"{info.hours:.2f}"),
                ("captions", info.captions),
                ("splits", _counts(info.splits)),
                ("contents", _counts(info.contents)),
                ("styles", _counts(info.styles)),
                ("rejects", info.rejects),
            ],
        )
    )


@corpus_app.command("import-bvh")
def corpus_import_bvh(
    src: Annotated[Path, typer.Argument(help="A .bvh file or a folder searched recursively.")],
    out: Annotated[Path, typer.Option(help="Output corpus folder (new or empty; else --append or --force).")],
    fmt: Annotated[Literal["humanml3d", "parquet"], typer.Option("--format", help="Output layout.")] = "humanml3d",
    content: Annotated[
        str | None, typer.Option(help="Content label for every file (else from Bandai names/JSON; others need it).")
    ] = None,
    style: Annotated[str | None, typer.Option(help="Style label for every file (else from names/JSON).")] = None,
    joint_map: Annotated[
        Path | None, typer.Option(help="Joint map JSON/YAML for a rig other than Bandai's (docs/joint-map.md).")
    ] = None,
    max_frames: Annotated[
        int, typer.Option(min=0, help="Cut longer takes into equal pieces of at most this many frames (0: no cut).")
    ] = 196,
    val_takes: Annotated[
        int | None,
        typer.Option(min=0, help="Takes per (content, style) pair for val.txt (default: 15% of its takes, 0: none)."),
    ] = None,
    test_takes: Annotated[
        int | None,
        typer.Option(min=0, help="Takes per (content, style) pair for test.txt (default: 15% of its takes, 0: none)."),
    ] = None,
    mean_std: Annotated[
        bool | None,
        typer.Option(help="Mean.npy/Std.npy from the train split (default: when the clips allow; else a warning)."),
    ] = None,
    labels_from: Annotated[
        str | None,
        typer.Option(help="Labels from file names, e.g. '{style}_{take}_{part}.bvh' (fields style, content, take)."),
    ] = None,
    licence: Annotated[str | None, typer.Option(help="The data's licence (Bandai file names imply theirs).")] = None,
    captions: Annotated[int, typer.Option(min=1, help="Captions per clip.")] = 3,
    append: Annotated[
        bool, typer.Option("--append", help="Add to the corpus in --out; clips it already holds are skipped.")
    ] = False,
    force: Annotated[bool, typer.Option("--force", help="Replace the corpus in --out.")] = False,
    log_every: Annotated[
        float | None,
        typer.Option(min=0.01, help="Off a terminal (a job's log): seconds between progress lines (default 10)."),
    ] = None,
) -> None:
    """Retarget BVH files to the t2m skeleton at 20 fps, caption them from their labels and write a training-ready
    corpus: takes cut at 196 frames, take-level train/val/test splits when the files carry take ids, Mean/Std of the
    train split (docs/bandai.md)."""
    from motionaug.augment.corpus.import_bvh import LabelPattern, import_bvh

    with usage_errors():
        if append and force:
            raise MotionDataError("--append/--force", "give one: --append adds to the corpus, --force replaces it")
        if labels_from:
            LabelPattern(labels_from)  # a pattern with no field is a usage error, before anything is read
    note_output(out)
    with console.status(f"importing BVH from {src}"), off_terminal("import-bvh", log_every, "files") as beat:
        summary = run_safely(
            lambda: import_bvh(
                src,
                out,
                fmt,
                content,
                style,
                joint_map,
                max_frames=max_frames or None,
                val_takes=val_takes,
                test_takes=test_takes,
                mean_std=mean_std,
                licence=licence,
                captions=captions,
                mode="append" if append else "force" if force else "new",
                progress=beat.update if beat else None,
                labels_from=labels_from,
            )
        )
    for reject in summary.rejects:
        err_console.print(f"[yellow]skipped[/yellow] {reject}", highlight=False)
    for note in summary.notes:
        err_console.print(f"[yellow]warning[/yellow] {note}", highlight=False)
    for split, pairs in summary.missing_pairs.items():
        err_console.print(f"[yellow]warning[/yellow] {split} has no clip of {', '.join(pairs)}", highlight=False)
    console.print(
        _facts(
            f"{summary.out} ({fmt})",
            [
                ("takes", summary.takes),
                ("clips", summary.clips),
                ("frames", summary.frames),
                ("cut takes", f"{summary.cut_takes} -> {summary.pieces} clips"),
                ("too short for MDM", len(summary.too_short)),
                ("already in the corpus", len(summary.skipped)),
                ("splits", _counts(summary.splits)),
                ("licence", summary.licence or "-"),
                ("seconds", f"{summary.seconds:.1f}"),
            ],
        )
    )
    console.print(
        f"wrote {summary.clips} clips ({summary.frames} frames) to {summary.out}; {len(summary.rejects)} rejected"
    )


@app.command()
def demo(
    out: Annotated[Path, typer.Option(help="Where the demo writes everything; run again to resume.")] = Path(
        "demo-out"
    ),
    clips: Annotated[int, typer.Option(min=40, help="Synthetic clips to render.")] = 1000,
    base_models: Annotated[
        Path | None,
        typer.Option(help="Base-models folder to reuse or train into (default OUT/base_models[-METHOD])."),
    ] = None,
    method: Annotated[
        str,
        typer.Option(help="erd (Style-ERD + output shapers, the default), onthefly (diffusion) or stats (a baseline)."),
    ] = "erd",
    size: Annotated[
        str, typer.Option(help="Base-model size: small, or tiny for a smoke run in about a minute.")
    ] = "small",
) -> None:
    """The embedded default end to end: synthetic corpus, the method's `small` base models (trained once on the
    corpus without the demo styles, then reused), three styles learnt from one example each, every neutral clip
    stylized into Parquet shards, and the expanded corpus exported in the HumanML3D layout."""
    from motionaug.workflows.demo import run_demo

    note_output(out)
    with Progress(*RUN_COLUMNS, console=console) as bars:
        result = run_safely(lambda: run_demo(out, clips, _Bars(bars), base_models, method, size))
    _print_run_summary(result.run)
    e = result.export
    console.print(
        f"corpus {result.corpus}; expanded corpus {e.out}: {e.originals} original + {e.stylized} stylized clips"
    )
    console.print(f"3D viewer: open file://{result.viewer.page.resolve()}", highlight=False, soft_wrap=True)
    console.print(
        f"next: motionaug preview {result.run.run_dir} --grid 6   |   motionaug evaluate {result.run.run_dir}"
    )


@app.command()
def pretrain(
    corpus: Annotated[Path, typer.Option(help="Training corpus (HumanML3D folder with Mean/Std).")],
    out: Annotated[Path, typer.Option(help="Base-models folder to write (resumes from its checkpoints).")],
    size: Annotated[str, typer.Option(help="Model size: tiny, small or paper.")] = "small",
    seed: Annotated[int, typer.Option(help="Training seed.")] = 0,
    overrides: Annotated[
        list[str] | None, typer.Option("--set", help="Preset override key=value, e.g. prior_steps=2000 (repeatable).")
    ] = None,
    evaluators_only: Annotated[
        bool,
        typer.Option(help="Only the evaluators (content/style classifiers), into OUT: for methods without a prior."),
    ] = False,
    evaluators: Annotated[
        bool,
        typer.Option(
            "--evaluators/--no-evaluators",
            help="Train the evaluators too (OUT/evaluators); --no-evaluators: the prior and motion encoder only, for "
            "runs scored by judges of their own (the run config's evaluators).",
        ),
    ] = True,
    from_mdm: Annotated[
        Path | None,
        typer.Option(help="Official MDM humanml trans_enc checkpoint as the prior: trains only encoder + evaluators."),
    ] = None,
    clip_weights: Annotated[
        Path | None,
        typer.Option(help="CLIP ViT-B/32 weights for --from-mdm (default: the checkpoint's, ~/.cache/clip)."),
    ] = None,
    mdm_stats: Annotated[
        Path | None, typer.Option(help="Folder with the prior's HumanML3D Mean/Std.npy (default: beside it, corpus).")
    ] = None,
    workers: Annotated[
        int, typer.Option(min=1, help="Data-parallel Ray Train workers (1: one process, no Ray); batch splits evenly.")
    ] = 1,
    gpus_per_worker: Annotated[
        float, typer.Option(min=0, help="GPUs per Ray Train worker (NCCL); 0 = CPU workers (gloo).")
    ] = 0.0,
    address: Annotated[
        str | None, typer.Option(help="Ray cluster address for --workers (default: RAY_ADDRESS or an embedded Ray).")
    ] = None,
    log_every: Annotated[
        float | None,
        typer.Option(min=0.01, help="Off a terminal (a job's log): seconds between progress lines (default 10)."),
    ] = None,
) -> None:
    """Train the base models: the T2M diffusion prior and the motion encoder, and the evaluators (OUT/evaluators)
    unless --no-evaluators."""
    from motionaug.augment.training.pretrain import PretrainConfig, ensure_base_models, fit_evaluators
    from motionaug.schemas.run_config import apply_overrides

    with usage_errors():
        try:
            options = apply_overrides({}, overrides or [])
        except ValueError as err:
            raise MotionDataError("--set", str(err)) from None
    mdm = {"from_mdm": from_mdm, "clip_weights": clip_weights, "mdm_stats": mdm_stats}
    options |= {name: str(path.resolve()) for name, path in mdm.items() if path is not None}
    config = run_safely(lambda: PretrainConfig.for_size(size, seed=seed, **options))
    if evaluators_only and not evaluators:
        with usage_errors():
            raise MotionConfigError("--evaluators-only", "asks for the evaluators alone; drop --no-evaluators")
    if evaluators_only:
        with off_terminal("pretrain evaluators", log_every):
            metrics = run_safely(lambda: fit_evaluators(corpus, out, config))
        console.print(_facts(f"evaluators in {out}", [(k, f"{v:.4f}") for k, v in sorted(metrics.items())]))
        return
    if workers > 1 or gpus_per_worker > 0:
        from motionaug.workflows.pretrain_cluster import pretrain_on_ray

        with off_terminal("pretrain (driver)", log_every):
            folder = run_safely(
                lambda: pretrain_on_ray(
                    corpus, out, config, workers, gpus_per_worker, address, log_interval(log_every), evaluators
                )
            )
        _print_base_models(folder)
        return
    if not console.is_terminal:  # a job log, nohup, CI: lines at a fixed interval instead of bars
        with off_terminal("pretrain", log_every) as beat:
            folder = run_safely(
                lambda: ensure_base_models(
                    corpus,
                    out,
                    size,
                    seed,
                    progress=beat.update if beat else None,
                    config=config,
                    evaluators=evaluators,
                )
            )
        _print_base_models(folder)
        return
    columns = (
        TextColumn("{task.description:>15}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[loss]}"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
    )
    with Progress(*columns, console=console) as bars:
        tasks: dict[str, TaskID] = {}

        def progress(stage: str, step: int, total: int, metrics: dict[str, float]) -> None:
            if stage not in tasks:
                tasks[stage] = bars.add_task(stage, total=total, loss="")
            loss = next((f"{k} {v:.4f}" for k, v in metrics.items() if "loss" in k), "")
            bars.update(tasks[stage], completed=step, total=total, loss=loss)

        folder = run_safely(
            lambda: ensure_base_models(corpus, out, size, seed, progress=progress, config=config, evaluators=evaluators)
        )
    _print_base_models(folder)


def _print_base_models(folder: Path) -> None:
    from motionaug.augment.training.base_models import BaseModels

    info = BaseModels.load(folder).info
    console.print(_facts(f"base models in {folder}", [(k, f"{v:.4f}") for k, v in sorted(info.metrics.items())]))
    for note in info.notes:
        console.print(f"note: {note}")


RUN_COLUMNS = (
    TextColumn("{task.description:>12}"),
    BarColumn(),
    MofNCompleteColumn(),
    TimeElapsedColumn(),
    TimeRemainingColumn(),
)


class _Bars:
    """Rich progress bars fed by the executor's ``RunProgress`` calls."""

    def __init__(self, progress: Progress) -> None:
        self.progress = progress
        self.tasks: dict[str, TaskID] = {}

    def stage(self, name: str, total: int, done: int = 0) -> None:
        self.tasks[name] = self.progress.add_task(name, total=total, completed=done)

    def advance(self, name: str, n: int = 1) -> None:
        self.progress.advance(self.tasks[name], n)


@app.command("run")
def run_command(
    config: Annotated[Path, typer.Argument(help="Run config (YAML or JSON), see configs/.")],
    address: Annotated[str | None, typer.Option(help="Ray cluster address (default: an embedded local Ray).")] = None,
    out: Annotated[Path | None, typer.Option(help="Run folder (overrides the config's output).")] = None,
    force: Annotated[bool, typer.Option("--force", help="Delete what the run folder holds and start over.")] = False,
    overrides: Annotated[
        list[str] | None, typer.Option("--set", help="Override a config value: key.sub=value.")
    ] = None,
    dry_run: Annotated[
        bool, typer.Option("--dry-run", help="Print the plan, estimated time and disk; run and write nothing.")
    ] = False,
    dashboard: Annotated[
        bool, typer.Option("--dashboard", help="Embedded Ray: start its dashboard (127.0.0.1) and print the URL.")
    ] = False,
    keep_dashboard: Annotated[
        bool, typer.Option("--keep-dashboard", help="With --dashboard: keep it up after the run until Ctrl-C.")
    ] = False,
    log_every: Annotated[
        float, typer.Option(min=0, help="Off a terminal (a job's log): seconds between a stage's progress lines.")
    ] = 10.0,
    lock_wait: Annotated[
        float, typer.Option(min=0, help="Seconds to wait for the run folder's current writer to exit, then refuse.")
    ] = 0.0,
    allow_empty: Annotated[
        bool, typer.Option("--allow-empty", help="Accept a run whose filters select, or that writes, 0 clips.")
    ] = False,
) -> None:
    """Fine-tune every style and stylize the corpus into Parquet shards; re-running resumes."""
    from contextlib import nullcontext

    with usage_errors():
        cfg = _load_config(config, overrides or [], address, out)
        # torch and Ray load only now: a config that fails its schema is answered before their import seconds
        from motionaug.workflows.dashboard import dashboard_session, hold_dashboard
        from motionaug.workflows.preflight import preflight
        from motionaug.workflows.progress_log import LineProgress
        from motionaug.workflows.ray_executor import execute_run

        if dashboard or keep_dashboard:
            cfg = cfg.model_copy(update={"compute": cfg.compute.model_copy(update={"include_dashboard": True})})
        if allow_empty:
            cfg = cfg.model_copy(update={"allow_empty": True})
        preflight(cfg)
    if dry_run:
        from motionaug.workflows.dry_run import dry_run_report, plan_run

        for part in dry_run_report(run_safely(lambda: plan_run(cfg))):
            console.print(part, highlight=False, soft_wrap=isinstance(part, str))
        return
    if (dashboard or keep_dashboard) and cfg.compute.address:
        console.print("--dashboard: this run joins a cluster, whose own dashboard shows it (http://HEAD:8265)")
    with dashboard_session(cfg.compute) as url:
        if url:
            console.print(f"dashboard: {url} (its token: ray get-auth-token; docs/ray.md)", highlight=False)
        # rich bars redraw in place; off a terminal (a job's driver log) they would show only at the end
        with Progress(*RUN_COLUMNS, console=console) if console.is_terminal else nullcontext() as bars:
            progress = _Bars(bars) if bars is not None else LineProgress(every=log_every)
            summary = run_safely(lambda: execute_run(cfg, force=force, progress=progress, lock_wait_s=lock_wait))
        _print_run_summary(summary)
        if url and keep_dashboard:
            hold_dashboard(url, console.print)


def _print_run_summary(summary: RunSummary) -> None:
    table = Table(title=f"run {summary.run_id}")
    for column in ("stage", "tasks", "skipped", "seconds"):
        table.add_column(column, justify="right" if column != "stage" else "left")
    for name, timing in summary.manifest.stages.items():
        table.add_row(name, str(timing.tasks), str(timing.skipped), f"{timing.seconds:.1f}")
    console.print(table)
    m = summary.manifest
    console.print(
        f"rows {m.rows}, rejects {m.rejects}, {summary.clips_per_second:.1f} clips/s over {summary.seconds:.1f} s; "
        f"shards in {summary.run_dir / 'shards'}, manifest {summary.run_dir / 'manifest.json'}"
    )
    for note in summary.notes:
        err_console.print(f"[yellow]warning[/yellow] {note}", highlight=False)


def _load_config(path: Path, overrides: list[str], address: str | None, out: Path | None) -> RunConfig:
    from motionaug.schemas.run_config import load_run_config

    if path.is_dir():
        raise MotionDataError(str(path), "is a folder; give the run config file (YAML or JSON) in it")
    if not path.is_file():
        raise MotionDataError(str(path), "config file not found")
    try:
        config = load_run_config(path, overrides)
    except (ValueError, OSError) as err:
        if isinstance(err, ValidationError):
            raise
        raise MotionDataError(str(path), str(err).splitlines()[0]) from None
    from motionaug.workflows.pipeline import resolve_method_paths  # the method registry: torch

    config = resolve_method_paths(config, path.resolve().parent)
    updates: dict = {}
    if address is not None:
        updates["compute"] = config.compute.model_copy(update={"address": address})
    if out is not None:
        updates["output"] = out.resolve()
    config = config.model_copy(update=updates)
    note_output(config.output)
    return config


@app.command("status")
def status_command(
    run: Annotated[str, typer.Argument(help="A run folder, or a job/run id with --address.")],
    address: Annotated[str | None, typer.Option(help="Dashboard URL (http://HEAD:8265): RUN is a job id.")] = None,
) -> None:
    """Stages done, shards done/total and rows of a run; with --address also the job's state on the cluster."""
    from motionaug.workflows.pipeline import run_status

    run_dir: Path | None = Path(run)
    if address is not None:
        from motionaug.workflows.jobs import job_state

        job = run_safely(lambda: job_state(address, run))
        console.print(f"job {job.job_id}: {job.status}" + (f" ({job.message})" if job.message else ""), highlight=False)
        run_dir = job.run_dir if job.run_dir is not None and job.run_dir.is_dir() else None
        if run_dir is None:
            console.print("run folder not reachable from here; progress shows on the cluster's storage")
            return
    st = run_safely(lambda: run_status(run_dir))
    console.print(
        _facts(
            f"{st.run_dir} ({st.run_id})",
            [
                ("plan", f"{st.clips} clips" if st.planned else "not yet"),
                ("fine-tunes", f"{st.styles_done}/{st.styles_total}"),
                ("shards", f"{st.shards_done}/{st.shards_total}"),
                ("rows", st.rows),
                ("rejects", st.rejects),
                ("complete", "yes" if st.complete else "no"),
            ],
        )
    )


@app.command("submit")
def submit_command(
    config: Annotated[Path, typer.Argument(help="Run config (YAML or JSON); its paths must exist on the cluster.")],
    address: Annotated[str, typer.Option(help="Dashboard URL of the cluster, e.g. http://HEAD:8265.")],
    out: Annotated[Path | None, typer.Option(help="Run folder on the cluster (overrides the config's output).")] = None,
    overrides: Annotated[
        list[str] | None, typer.Option("--set", help="Override a config value: key.sub=value.")
    ] = None,
    retry: Annotated[
        bool, typer.Option("--retry", help="Resubmit a FAILED/STOPPED run as <job id>-<n>; it resumes.")
    ] = False,
    cluster_paths: Annotated[
        bool, typer.Option("--cluster-paths", help="Paths exist only on the cluster: check method params, not files.")
    ] = False,
) -> None:
    """Submit the run to a Ray cluster through the Jobs API; the job id is motionaug-<run id>."""
    from motionaug.augment.methods.registry import method_class, validate_method_params
    from motionaug.workflows.jobs import cluster_nodes, dashboard_url, submit_run
    from motionaug.workflows.preflight import check_cluster_resources, preflight

    with usage_errors():
        dashboard_url(address)
        cfg = _load_config(config, overrides or [], None, out)
        if cluster_paths:
            validate_method_params(cfg.method.name, cfg.method.params, cfg.hooks.modules)
            trains = method_class(cfg.method.name).trains
        else:
            trains = preflight(cfg, local=False).trains
    capacity = run_safely(lambda: cluster_nodes(address))
    if not capacity.autoscales:
        with usage_errors():
            check_cluster_resources(cfg, trains, capacity.nodes)
    job = run_safely(lambda: submit_run(cfg, address, retry=retry, name=config.stem))
    console.print(f"submitted job {job.job_id} ({job.name}; run {job.run_id}, folder {job.run_dir})", highlight=False)
    console.print(f"dashboard: {job.dashboard_url}/#/jobs/{job.job_id}", highlight=False)
    console.print(f"follow: motionaug logs {job.job_id} --address {address} --follow", highlight=False)


@app.command("logs")
def logs_command(
    job: Annotated[str, typer.Argument(help="Job id (motionaug-<run id>) or run id.")],
    address: Annotated[str, typer.Option(help="Dashboard URL of the cluster.")],
    follow: Annotated[bool, typer.Option("--follow", "-f", help="Stream until the job ends.")] = False,
) -> None:
    """Print the job driver's log (stdout and stderr of `motionaug run` on the cluster)."""
    from motionaug.workflows.jobs import follow_logs, job_logs

    if follow:
        run_safely(lambda: follow_logs(address, job, lambda chunk: print(chunk, end="", flush=True)))
    else:
        print(run_safely(lambda: job_logs(address, job)), end="")


@app.command("cancel")
def cancel_command(
    job: Annotated[str, typer.Argument(help="Job id (motionaug-<run id>) or run id.")],
    address: Annotated[str, typer.Option(help="Dashboard URL of the cluster.")],
) -> None:
    """Stop a submitted run; finished shards stay on disk and `submit --retry` resumes it."""
    from motionaug.workflows.jobs import cancel_job, job_id_for

    stopped = run_safely(lambda: cancel_job(address, job))
    verb = "stop requested for" if stopped else "already finished:"
    console.print(f"{verb} job {job_id_for(job)}", highlight=False)


@app.command("export")
def export_command(
    run: Annotated[Path, typer.Argument(help="A finished run folder.")],
    out: Annotated[Path, typer.Option(help="Output folder.")],
    fmt: Annotated[
        Literal["humanml3d", "parquet", "bvh"], typer.Option("--format", help="Output layout.")
    ] = "humanml3d",
    min_content_score: Annotated[float | None, typer.Option(help="Keep stylized clips scoring at least this.")] = None,
    keep_mean_std: Annotated[bool, typer.Option("--keep-mean-std", help="Keep the source Mean/Std.")] = False,
    style: Annotated[str | None, typer.Option(help="--format bvh: only this style.")] = None,
    allow_empty: Annotated[
        bool, typer.Option("--allow-empty", help="Accept an export that adds 0 stylized clips.")
    ] = False,
) -> None:
    """Original corpus + stylized train clips as a HumanML3D folder or one merged Parquet dataset.

    ``--format bvh``: the stylized clips as BVH files.
    """
    from motionaug.augment.outputs.export import export_run

    note_output(out)
    if fmt == "bvh":
        from motionaug.augment.outputs.bvh_export import export_bvh

        with off_terminal("export bvh", unit="files"):
            b = run_safely(lambda: export_bvh(run, out, style))
        console.print(
            f"wrote {b.files} BVH files to {b.out} ({b.with_positions} non-rigid, with position channels); "
            f"largest joint error {b.max_error_m * 1000:.3f} mm"
        )
        return
    with console.status(f"exporting {run} to {out}"), off_terminal("export", unit="clips") as beat:
        s = run_safely(
            lambda: export_run(
                run,
                out,
                fmt,
                min_content_score,
                keep_mean_std,
                progress=beat.update if beat else None,
                allow_empty=allow_empty,
            )
        )
    console.print(
        f"wrote {s.originals} original + {s.stylized} stylized clips to {s.out} ({s.format}); "
        f"splits {_counts(s.splits)}; "
        f"left out: {s.held_out} copies of val/test clips, {s.below_score} below the score"
    )


def main() -> None:  # pragma: no cover - console script entry
    app()


if __name__ == "__main__":  # pragma: no cover - ``python -m motionaug.workflows.cli``
    app()
