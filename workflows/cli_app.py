"""The ``motionaug`` typer app and what every command module shares: consoles and one-line errors.

Command modules (``workflows.cli``, ``workflows.cli_inspect``) import from here and register on ``app``;
nothing here imports them, so there is no import cycle.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TypeVar

import typer
from pydantic import ValidationError
from rich.console import Console

from motionaug.schemas.errors import MotionDataError, first_error

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


@contextmanager
def usage_errors() -> Iterator[None]:
    """Like ``user_errors`` for a bad config or argument: one line, exit code 2."""
    try:
        yield
    except (MotionDataError, ValidationError, FileNotFoundError) as err:
        err_console.print(f"[red]error:[/red] {_one_line(err)}", highlight=False)
        raise typer.Exit(2) from None


def _one_line(err: Exception) -> str:
    if isinstance(err, ValidationError):
        where, message = first_error(err, err.title)
        return f"{err.title}: {where}: {message}"
    return str(err).splitlines()[0]


def run_safely(fn: Callable[[], T]) -> T:
    with user_errors():
        return fn()
