"""The ``motionaug`` command line: thin commands that parse, call one library function, render its result.

Errors a user can fix print one line (the thing and the reason): exit 2 for usage, 1 for failure.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated, Literal, TypeVar

import typer
from pydantic import ValidationError
from rich.console import Console
from rich.table import Table

from augment.errors import MotionDataError

app = typer.Typer(help="Stylistic expansion of text-to-motion datasets.", no_args_is_help=True, add_completion=False)
corpus_app = typer.Typer(help="Make, import and inspect motion corpora.", no_args_is_help=True)
app.add_typer(corpus_app, name="corpus")

console = Console()
err_console = Console(stderr=True, soft_wrap=True)
T = TypeVar("T")


@contextmanager
def user_errors() -> Iterator[None]:
    """Turn bad-input errors into one red line and exit code 1 instead of a traceback."""
    try:
        yield
    except (MotionDataError, ValidationError, FileNotFoundError) as err:
        err_console.print(f"[red]error:[/red] {_one_line(err)}", highlight=False)
        raise typer.Exit(1) from None


def _one_line(err: Exception) -> str:
    if isinstance(err, ValidationError):
        first = err.errors()[0]
        where = ".".join(str(part) for part in first["loc"]) or err.title
        return f"{err.title}: {where}: {first['msg']}"
    return str(err).splitlines()[0]


def run_safely(fn: Callable[[], T]) -> T:
    with user_errors():
        return fn()


def _counts(counts: dict[str, int]) -> str:
    return ", ".join(f"{k} {v}" for k, v in counts.items()) or "-"


@corpus_app.command("synth")
def corpus_synth(
    out: Annotated[Path, typer.Option(help="Output folder (HumanML3D layout).")],
    clips: Annotated[int, typer.Option(min=1, help="Number of clips.")] = 1000,
    seed: Annotated[int, typer.Option(help="Seed; the same seed gives byte-identical output.")] = 0,
) -> None:
    """Render the procedural style corpus (the embedded default) in the HumanML3D layout."""
    from augment.synth import generate_corpus

    with console.status(f"rendering {clips} synthetic clips"):
        summary = run_safely(lambda: generate_corpus(out, clips, seed=seed))
    console.print(f"wrote {summary.n_clips} clips ({summary.frames} frames) to {summary.out_dir} in {summary.seconds:.1f} s")


@corpus_app.command("inspect")
def corpus_inspect(path: Annotated[Path, typer.Argument(help="A HumanML3D folder or a Parquet corpus.")]) -> None:
    """Count clips, frames, hours, captions, labels and rejects of a corpus."""
    from augment.corpus import inspect_corpus

    info = run_safely(lambda: inspect_corpus(path))
    table = Table(title=f"{info.path} ({info.format})", show_header=False)
    for key, value in [
        ("clips", info.clips), ("frames", info.frames), ("hours", f"{info.hours:.2f}"), ("captions", info.captions),
        ("splits", _counts(info.splits)), ("contents", _counts(info.contents)),
        ("styles", _counts(info.styles)), ("rejects", info.rejects),
    ]:  # fmt: skip
        table.add_row(key, str(value))
    console.print(table)


@corpus_app.command("import-bvh")
def corpus_import_bvh(
    src: Annotated[Path, typer.Argument(help="A .bvh file or a folder searched recursively.")],
    out: Annotated[Path, typer.Option(help="Output corpus folder.")],
    fmt: Annotated[Literal["humanml3d", "parquet"], typer.Option("--format", help="Output layout.")] = "humanml3d",
    content: Annotated[str | None, typer.Option(help="Content label for every file (else from names/JSON).")] = None,
    style: Annotated[str | None, typer.Option(help="Style label for every file (else from names/JSON).")] = None,
    joint_map: Annotated[Path | None, typer.Option(help="Joint map JSON/YAML (docs/retargeting.md).")] = None,
) -> None:
    """Retarget BVH files to the t2m skeleton at 20 fps and write them as a corpus."""
    from augment.corpus.import_bvh import import_bvh

    with console.status(f"importing BVH from {src}"):
        summary = run_safely(lambda: import_bvh(src, out, fmt, content, style, joint_map))
    for reject in summary.rejects:
        err_console.print(f"[yellow]skipped[/yellow] {reject}", highlight=False)
    console.print(f"wrote {summary.clips} clips ({summary.frames} frames) to {summary.out}; {len(summary.rejects)} rejected")


@app.command()
def demo(
    out: Annotated[Path, typer.Option(help="Where the demo writes everything.")] = Path("demo-out"),
    clips: Annotated[int, typer.Option(min=10, help="Synthetic clips to render.")] = 1000,
) -> None:
    """The embedded default end to end (for now: render the synthetic corpus and inspect it)."""
    corpus = out / "corpus"
    corpus_synth(out=corpus, clips=clips, seed=0)
    corpus_inspect(corpus)


def main() -> None:  # pragma: no cover - console script entry
    app()
