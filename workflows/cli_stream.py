"""``motionaug stream``: Style-ERD frame by frame, from a file or stdin to a file or stdout.

Registered on the app of ``workflows.cli_app`` (``workflows.cli`` imports this module). Thin: parse, call
``augment.methods.erd.stream_files.run_stream``, report on stderr (stdout may be the motion itself).
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated, Literal

import typer

from motionaug.schemas.errors import MotionDataError
from motionaug.workflows.cli_app import app, err_console, run_safely, usage_errors


@app.command("stream")
def stream_command(
    style: Annotated[str, typer.Option(help="Target style (one the network learnt).")],
    model: Annotated[
        Path,
        typer.Option(envvar="MOTIONAUG_ERD_MODEL", help="A trained Style-ERD folder (a run's base_models with erd)."),
    ],
    source: Annotated[Path | None, typer.Option("--input", help="A .bvh or features .npy; default stdin.")] = None,
    kind: Annotated[
        Literal["bvh", "npy"] | None, typer.Option("--input-format", help="Default: the suffix; stdin is bvh.")
    ] = None,
    out: Annotated[Path | None, typer.Option(help="Output file; default stdout.")] = None,
    fmt: Annotated[
        Literal["bvh", "npy", "text"] | None,
        typer.Option("--format", help="Default: the output suffix; stdout gets bvh for bvh input, else text."),
    ] = None,
    intensity: Annotated[float, typer.Option(min=0.0, max=1.0, help="Style intensity (paper sec. 4.4).")] = 1.0,
) -> None:
    """Stylize a motion one frame at a time (Style-ERD), writing frames as they come (one frame of lag)."""
    from motionaug.augment.methods.erd.stream_files import run_stream

    with usage_errors():
        kind = kind or (source.suffix.lstrip(".").lower() if source else "bvh")
        if kind not in ("bvh", "npy"):
            given = "--input-format" if source is None or kind != source.suffix.lstrip(".").lower() else "--input"
            raise MotionDataError(given, f"reads .bvh or .npy motion, not {kind!r}; pass --input-format bvh or npy")
        fmt = fmt or (out.suffix.lstrip(".").lower() if out else ("bvh" if kind == "bvh" else "text"))
    reader = source if source is not None else sys.stdin.buffer
    writer = out if out is not None else (sys.stdout if fmt == "text" else sys.stdout.buffer)
    frames = run_safely(lambda: run_stream(model, style, reader, kind, writer, fmt, intensity))  # type: ignore[arg-type]
    err_console.print(f"stylized {frames} frames as {style}", highlight=False)
