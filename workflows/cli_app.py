"""The ``motionaug`` typer app and what every command module shares: consoles and one-line errors.

Command modules (``workflows.cli``, ``workflows.cli_inspect``) import from here and register on ``app``;
nothing here imports them, so there is no import cycle.

Every failure a user sees is one line, ``error: <thing>: <reason>``, and a non-zero exit: 2 for a bad config
or argument, 1 for anything else. The line comes from ``error_line``, which looks through the exception chain
(and through a Ray task's error to its cause), so an error raised inside a Ray task reads the same as one raised
in the driver. ``motionaug --debug ...`` prints the traceback as well (docs/errors.md lists the errors).
"""

from __future__ import annotations

import errno
import os
import re
import sys
import traceback
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Annotated, Any, TypeVar

import click
import typer
from pydantic import ValidationError
from rich.console import Console
from rich.markup import escape

from motionaug.schemas.errors import MotionConfigError, MotionDataError, first_error
from motionaug.workflows.progress_log import Heartbeat

EXIT_FAILURE = 1
EXIT_USAGE = 2
DEBUG_ENV = "MOTIONAUG_DEBUG"

# short reasons for the OSErrors a full, read-only or foreign disk gives
OS_REASONS = {
    errno.ENOSPC: "no space left on device",
    errno.EDQUOT: "disk quota exceeded",
    errno.EROFS: "read-only file system",
    errno.EACCES: "permission denied",
    errno.EPERM: "permission denied",
    errno.ENOENT: "not found",
    errno.ENOTDIR: "a path component is not a folder",
    errno.EISDIR: "is a folder, not a file",
    errno.EEXIST: "already exists",
    errno.ENOTEMPTY: "folder is not empty",
    errno.ENAMETOOLONG: "file name too long",
    errno.EIO: "input/output error (failing disk?)",
}


# errors of writing, which name a path only when the command has said where it writes (``note_output``)
WRITE_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EROFS}
_SHORT_WRITE = re.compile(r"\d+ requested and \d+ written")  # numpy's ``tofile`` on a full disk: no errno
_outputs: list[str] = []
_debug: list[bool] = []


def note_output(path: str | os.PathLike[str]) -> None:
    """Say where this command writes: a disk-full or read-only error that names no file then names this."""
    _outputs.append(str(path))


class _App(typer.Typer):
    """A Typer app whose uncaught errors become one line (the traceback only with ``--debug``)."""

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        try:
            return super().__call__(*args, **kwargs)
        except Exception as err:  # noqa: BLE001 - the last line of defence: one line, never a traceback
            sys.exit(report_error(err, EXIT_FAILURE))


app = _App(
    help="Stylistic expansion of text-to-motion datasets.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
corpus_app = typer.Typer(help="Make, import and inspect motion corpora.", no_args_is_help=True)
app.add_typer(corpus_app, name="corpus")

console = Console()
err_console = Console(stderr=True, soft_wrap=True)
T = TypeVar("T")


@app.callback()
def _global_options(
    debug: Annotated[
        bool, typer.Option("--debug", help="On an error, print the full traceback as well as the one line.")
    ] = False,
) -> None:
    """Stylistic expansion of text-to-motion datasets."""
    _outputs.clear()  # a new command (several run in one process under tests)
    _debug[:] = [debug]


def debugging() -> bool:
    """``--debug`` given, or MOTIONAUG_DEBUG=1 in the environment."""
    return any(_debug) or os.environ.get(DEBUG_ENV, "") not in ("", "0")


def _causes(err: BaseException) -> Iterator[BaseException]:
    """``err``, then what it wraps: a Ray task error's original exception, ``__cause__``, ``__context__``."""
    seen: set[int] = set()
    todo = [err]
    while todo:
        current = todo.pop(0)
        if id(current) in seen:
            continue
        seen.add(id(current))
        yield current
        cause = getattr(current, "cause", None)  # ray.exceptions.RayTaskError carries the task's exception here
        todo += [e for e in (cause, current.__cause__, current.__context__) if isinstance(e, BaseException)]


def os_error_line(err: OSError) -> str:
    """``<path>: <short reason>`` for an OSError: the path it names, else (writing) the command's output."""
    code = errno.ENOSPC if err.errno is None and _SHORT_WRITE.search(str(err)) else err.errno
    reason = OS_REASONS.get(code or -1) or (err.strerror or str(err)).splitlines()[0].lower()
    paths = [str(p) for p in (err.filename, err.filename2) if p is not None]
    if not paths and code in WRITE_ERRNOS and _outputs:
        paths = [f"writing {_outputs[-1]}"]
    return f"{' -> '.join(paths)}: {reason}" if paths else reason


def error_line(err: BaseException) -> str | None:
    """The one line for an error a user can act on, or None when it is unexpected (a bug: see --debug)."""
    for e in _causes(err):
        if isinstance(e, ValidationError):
            where, message = first_error(e, e.title)
            return f"{e.title}: {where}: {message}"
        if isinstance(e, MotionDataError):
            return _bounded(str(e).splitlines()[0])
        if isinstance(e, OSError) and (e.errno in OS_REASONS or e.filename is not None or _SHORT_WRITE.search(str(e))):
            return os_error_line(e)
        if isinstance(e, MemoryError):
            return "out of memory; use smaller units or batches (compute.unit_size, compute.batch_size)"
    return None


MAX_LINE = 600


def _bounded(line: str) -> str:
    """A line of at most ``MAX_LINE`` characters: an error naming 10,000 joints stays one readable line. Its start
    (the thing) and its end (the fix, where there is one) are kept; the middle is cut."""
    if len(line) <= MAX_LINE:
        return line
    head, tail = MAX_LINE * 3 // 5, MAX_LINE * 2 // 5 - 5
    return f"{line[:head]} ... {line[-tail:]}"


def report_error(err: BaseException, code: int) -> int:
    """Print the error's one line (and, with --debug, its traceback first); returns the exit code to use."""
    if debugging():
        traceback.print_exception(err, file=sys.stderr)
    line = error_line(err)
    if any(isinstance(e, MotionConfigError) for e in _causes(err)):
        code = EXIT_USAGE  # a config setting, even when a Ray task or the cluster found it out
    if line is None:
        first = (str(err).splitlines() or [""])[0]
        line = f"unexpected {type(err).__name__}: {_bounded(first)} (rerun with --debug for the traceback)"
        code = EXIT_FAILURE
    err_console.print(f"[red]error:[/red] {escape(line)}", highlight=False)
    return code


@contextmanager
def _errors_exit(code: int) -> Iterator[None]:
    try:
        yield
    except (click.exceptions.Exit, click.ClickException, click.Abort, KeyboardInterrupt, SystemExit):
        raise
    except Exception as err:  # noqa: BLE001 - every error becomes one line and an exit code
        raise typer.Exit(report_error(err, code)) from None


@contextmanager
def user_errors() -> Iterator[None]:
    """Turn any error into one red line and exit code 1 instead of a traceback."""
    with _errors_exit(EXIT_FAILURE):
        yield


@contextmanager
def usage_errors() -> Iterator[None]:
    """Like ``user_errors`` for a bad config or argument: one line, exit code 2."""
    with _errors_exit(EXIT_USAGE):
        yield


LOG_EVERY_ENV = "MOTIONAUG_LOG_EVERY"  # seconds between progress lines off a terminal (default 10)


def log_interval(given: float | None = None) -> float:
    """Seconds between progress lines: ``given``, else MOTIONAUG_LOG_EVERY, else 10."""
    return given or float(os.environ.get(LOG_EVERY_ENV) or 10.0)


@contextmanager
def off_terminal(command: str, every: float | None = None, unit: str = "steps") -> Iterator[Heartbeat | None]:
    """Progress lines every ``every`` seconds (default: MOTIONAUG_LOG_EVERY, else 10) when stdout is not a terminal
    (a job log, ``nohup``, CI), where rich spinners and bars show nothing until the end; None on a terminal."""
    if console.is_terminal:
        yield None
        return
    with Heartbeat(command, log_interval(every), unit) as beat:
        yield beat


def run_safely(fn: Callable[[], T]) -> T:
    with user_errors():
        return fn()
