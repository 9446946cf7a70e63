"""``motionaug view`` and ``motionaug corpus view``: the interactive 3D viewer of a run or a corpus.

Registered on the apps of ``workflows.cli_app`` (``workflows.cli`` imports this module). Thin commands: parse,
call ``augment.render.viewer``, print where the page is. ``motionaug preview RUN --html`` calls the same code.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

import typer

from motionaug.schemas.errors import MotionDataError
from motionaug.workflows.cli_app import app, console, corpus_app, note_output, run_safely, usage_errors

ByOption = Annotated[
    Literal["limb_agreement", "content_score", "style_prob", "foot_skating", "contact_agreement", "mpjpe"],
    typer.Option(
        "--by",
        help="Score --worst ranks by: limb_agreement (no classifier), or scores.parquet's content_score, style_prob, "
        "foot_skating, contact_agreement, mpjpe.",
    ),
]
IdsOption = Annotated[
    list[str] | None, typer.Option("--ids", help="Clip ids to show, comma-separated or repeated (default: all).")
]


def split_ids(ids: list[str] | None) -> list[str] | None:
    """``--ids a,b --ids c`` -> ``[a, b, c]``; None when not given."""
    if not ids:
        return None
    return [part.strip() for value in ids for part in value.split(",") if part.strip()]


def print_viewer(summary) -> None:  # noqa: ANN001 - augment.render.viewer.ViewerSummary, imported late
    size = summary.bytes / 2**20
    console.print(
        f"wrote {summary.page} ({summary.clips} clips, {summary.chunks} data chunks, {size:.1f} MiB); "
        f"open file://{summary.page.resolve()}",
        highlight=False,
        soft_wrap=True,
    )


@app.command("view")
def view_command(
    run: Annotated[Path, typer.Argument(help="A run folder.")],
    out: Annotated[Path | None, typer.Option(help="Folder for viewer.html and viewer/ (default: the run).")] = None,
    ids: IdsOption = None,
    worst: Annotated[
        int | None, typer.Option(min=1, help="Only the N worst clips by --by (default: limb agreement).")
    ] = None,
    by: ByOption = "limb_agreement",
) -> None:
    """Write the run's 3D viewer (viewer.html + viewer/ data chunks): content beside stylized, worst first."""
    from motionaug.augment.outputs.run_dir import RunDir
    from motionaug.augment.render.viewer import write_run_viewer

    with usage_errors():
        if not RunDir(run).is_run():
            raise MotionDataError(str(run), "not a run folder; for a corpus use `motionaug corpus view`")
    note_output(out or run)
    with console.status("writing the viewer"):
        summary = run_safely(lambda: write_run_viewer(run, out, split_ids(ids), worst, by=by))
    print_viewer(summary)


@corpus_app.command("view")
def corpus_view(
    corpus: Annotated[Path, typer.Argument(help="A HumanML3D folder or a Parquet corpus.")],
    out: Annotated[
        Path | None, typer.Option(help="Folder for viewer.html and viewer/ (default: CORPUS-viewer beside it).")
    ] = None,
    ids: IdsOption = None,
) -> None:
    """Write a corpus's 3D viewer (viewer.html + viewer/ data chunks), e.g. to look at an import before training."""
    from motionaug.augment.render.viewer import write_corpus_viewer

    with usage_errors():
        if not corpus.exists():
            raise MotionDataError(str(corpus), "not found")
    target = out if out is not None else corpus.parent / f"{corpus.name}-viewer"
    note_output(target)
    with console.status("writing the viewer"):
        summary = run_safely(lambda: write_corpus_viewer(corpus, target, split_ids(ids)))
    print_viewer(summary)
