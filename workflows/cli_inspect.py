"""``motionaug preview`` and ``motionaug evaluate``: looking at and judging a run's output.

Registered on the app of ``workflows.cli_app`` (``workflows.cli`` imports this module). Thin commands:
parse, call one library function (``augment.eval.evaluation``, ``augment.eval.report``), print where things went.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from motionaug.schemas.errors import MotionDataError
from motionaug.workflows.cli_app import app, console, note_output, off_terminal, run_safely, usage_errors
from motionaug.workflows.cli_view import ByOption, IdsOption, print_viewer, split_ids


@app.command("preview")
def preview_command(
    path: Annotated[Path, typer.Argument(help="A run folder, or a corpus (HumanML3D folder or Parquet).")],
    clip: Annotated[str | None, typer.Option(help="Clip id (the source clip's id for a run).")] = None,
    style: Annotated[str | None, typer.Option(help="Style of the run to show the clip in.")] = None,
    out: Annotated[Path | None, typer.Option(help="Output file: .gif, .mp4 (or .png with --grid).")] = None,
    grid: Annotated[int | None, typer.Option(min=1, help="Contact sheet of N random transfers across styles.")] = None,
    seed: Annotated[int, typer.Option(help="Seed for --grid's choice of clips.")] = 0,
    html: Annotated[
        bool, typer.Option("--html", help="The 3D viewer (a folder: viewer.html + viewer/) of --ids, --worst or all.")
    ] = False,
    ids: IdsOption = None,
    worst: Annotated[
        int | None, typer.Option(min=1, help="With --html: the N worst clips of a run by --by (limb agreement).")
    ] = None,
    by: ByOption = "limb_agreement",
    max_frames: Annotated[
        int, typer.Option(min=1, max=20_000, help="Animate at most this many frames (a long clip is cut short).")
    ] = 600,
) -> None:
    """Animate a clip beside its stylized version (a run), or one clip of a corpus; --grid: a PNG contact sheet;
    --html: the 3D viewer of a chosen subset (default folder: previews/viewer in the run, ./previews/viewer-NAME)."""
    from motionaug.augment.eval.evaluation import preview_corpus, preview_grid, preview_transfer
    from motionaug.augment.outputs.run_dir import RunDir

    is_run = RunDir(path).is_run()
    if html:
        with usage_errors():
            _check_html_args(path, grid, worst, is_run)
        _preview_html(path, out, split_ids(ids) or ([clip] if clip else None), worst, by, is_run)
        return
    with usage_errors():
        _check_preview_args(path, clip, style, grid, is_run)
    note_output(out or path)
    with console.status("rendering preview"):
        if grid is not None:
            written = run_safely(lambda: preview_grid(path, grid, out, seed=seed))
        elif RunDir(path).is_run():
            written = run_safely(lambda: preview_transfer(path, clip, style, out, max_frames=max_frames))
        else:
            written = run_safely(lambda: preview_corpus(path, clip, out, max_frames=max_frames))
    console.print(f"wrote {written}")


def _preview_html(
    path: Path, out: Path | None, ids: list[str] | None, worst: int | None, by: str, is_run: bool
) -> None:
    from motionaug.augment.render.viewer import write_corpus_viewer, write_run_viewer

    target = out or (path / "previews" / "viewer" if is_run else Path("previews") / f"viewer-{path.name}")
    note_output(target)
    with console.status("writing the viewer"):
        if is_run:
            summary = run_safely(lambda: write_run_viewer(path, target, ids, worst, by=by))
        else:
            summary = run_safely(lambda: write_corpus_viewer(path, target, ids))
    print_viewer(summary)


def _check_html_args(path: Path, grid: int | None, worst: int | None, is_run: bool) -> None:
    if not path.exists():
        raise MotionDataError(str(path), "not found")
    if grid is not None:
        raise MotionDataError("--html/--grid", "give one: --html writes the 3D viewer, --grid a PNG sheet")
    if worst is not None and not is_run:
        raise MotionDataError("--worst", f"{path} is a corpus, not a run: it has no content scores")


def _check_preview_args(path: Path, clip: str | None, style: str | None, grid: int | None, is_run: bool) -> None:
    if not path.exists():
        raise MotionDataError(str(path), "not found")
    if grid is not None:
        if not is_run:
            raise MotionDataError("--grid", f"{path} is not a run folder; a grid shows a run's transfers")
        return
    if clip is None:
        raise MotionDataError("--clip", "give the id of the clip to show (or --grid N)")
    if is_run and style is None:
        raise MotionDataError("--style", "a run folder needs --style to pick the stylized version")
    if not is_run and style is not None:
        raise MotionDataError("--style", f"{path} is a corpus, not a run: it has no stylized versions")


@app.command("evaluate")
def evaluate_command(
    run: Annotated[Path, typer.Argument(help="A finished run folder.")],
    reference: Annotated[
        Path | None, typer.Option(help="Corpus of real labelled clips for FMD (default: the run's corpus).")
    ] = None,
    base_models: Annotated[
        Path | None,
        typer.Option(
            "--evaluators",
            "--base-models",
            help="The judges: an evaluators folder or base models holding one (default: the config's evaluators, "
            "else the run's base models).",
        ),
    ] = None,
) -> None:
    """Score every stylized clip; write report.md, report.html and scores.parquet into the run folder."""
    from motionaug.augment.eval.evaluation import evaluate_run, write_scores
    from motionaug.augment.eval.report import SUMMARY_COLUMNS, format_value, write_report
    from motionaug.augment.render.viewer import viewer_beside_report

    note_output(run)
    with console.status(f"evaluating {run}"), off_terminal("evaluate", unit="clips") as beat:
        evaluation = run_safely(
            lambda: evaluate_run(run, reference, base_models, progress=beat.update if beat else None)
        )
        scores = run_safely(lambda: write_scores(evaluation))
    with console.status(f"writing the 3D viewer of {run}"), off_terminal("evaluate viewer"):
        viewer, why_not = run_safely(lambda: viewer_beside_report(run))
    md, page = run_safely(lambda: write_report(evaluation))
    shown = [
        c
        for c in SUMMARY_COLUMNS
        if c[0] in ("clips", "sra", "cra", "fmd", "foot_skating", "contact_agreement", "mpjpe")
    ]
    table = Table(title=f"run {evaluation.run_id} ({evaluation.method})")
    for header in ("style", *[h for _, h, _ in shown]):
        table.add_column(header, justify="left" if header == "style" else "right")
    for summary in [*evaluation.styles, evaluation.overall]:
        table.add_row(summary.style, *[format_value(kind, getattr(summary, attr)) for attr, _, kind in shown])
    console.print(table)
    for note in evaluation.notes:
        console.print(f"[yellow]not measured:[/yellow] {note}", highlight=False)
    for leak in evaluation.leaks:
        console.print(f"[red]not held out:[/red] {leak}", highlight=False)
    console.print(f"wrote {md}, {page} and {scores}")
    if viewer is not None:
        print_viewer(viewer)
    else:
        console.print(f"[yellow]no 3D viewer:[/yellow] {why_not}", highlight=False, soft_wrap=True)
