"""``motionaug expansion``: measure whether an expansion helps a text-to-motion model, on your own labelled corpus.

Thin commands over ``augment.eval.expansion``: ``split`` makes the base corpus lacking some styles (A), ``truth`` the
base plus the true stylized clips (C); ``merge`` A plus a ``motionaug run`` over A's ``expand`` split (B);
``motionaug pretrain`` trains a prior on each; ``score`` samples every held-out caption and judges the motion.
docs/expansion.md walks through it, including the one command that runs all of it.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Literal

import typer
from rich.table import Table

from motionaug.workflows.cli_app import console, off_terminal, run_safely

expansion_app = typer.Typer(
    help="Does an expansion help a text-to-motion model? Split, merge, score.", no_args_is_help=True
)


@expansion_app.command("split")
def split_command(
    corpus: Annotated[Path, typer.Argument(help="A labelled HumanML3D folder with train/val/test splits.")],
    out: Annotated[Path, typer.Option(help="New folder: base/ (A), held_out/, examples/, split.json.")],
    missing: Annotated[str, typer.Option(help="Comma-separated styles A lacks, e.g. angry,old.")],
    neutral: Annotated[str, typer.Option(help="The corpus's neutral style label.")] = "neutral",
    expand: Annotated[int | None, typer.Option(help="Neutral train clips of A to stylize (default: all).")] = None,
    seed: Annotated[int, typer.Option(help="Seed of the --expand draw.")] = 0,
    halves: Annotated[
        bool, typer.Option(help="Set half the missing styles' train takes aside for a judge (see judge-corpus).")
    ] = False,
) -> None:
    """Write A (the corpus without the missing styles, in motions and captions), the held-out set and examples."""
    from motionaug.augment.eval.expansion import split_by_style
    from motionaug.augment.synth import STYLE_WORDS

    styles = [s for s in missing.split(",") if s]
    with off_terminal("expansion split"):
        s = run_safely(
            lambda: split_by_style(corpus, out, styles, neutral, expand, seed, words=STYLE_WORDS, halves=halves)
        )
    console.print(
        f"A: {s.base_splits} clips (styles {s.present}); held out {s.held_out}; {len(s.expand_ids)} clips to expand; "
        f"examples {[e['path'] for e in s.examples.values()]}; {s.dropped_for_captions} dropped for naming a "
        f"missing style; {len(s.judge_ids)} set aside for the judge; in {out}"
    )


@expansion_app.command("judge-corpus")
def judge_corpus_command(
    split: Annotated[Path, typer.Argument(help="A folder made by `motionaug expansion split --halves`.")],
    out: Annotated[Path, typer.Option(help="New folder: A plus the missing styles' takes set aside for the judge.")],
) -> None:
    """Write the judge's corpus when it must come from the same corpus: A plus the half of the missing styles' train
    takes that neither C nor the examples use, so the judge never saw a clip C adds or B learnt from."""
    from motionaug.augment.eval.expansion import BASE_DIR, judge_clips, merge_clips
    from motionaug.schemas.errors import MotionDataError

    def write() -> dict[str, int]:
        clips = judge_clips(split)
        if not clips:
            raise MotionDataError(str(split), "no takes were set aside for a judge (make the split with --halves)")
        return merge_clips(split / BASE_DIR, clips, out)

    with off_terminal("expansion judge-corpus"):
        sizes = run_safely(write)
    console.print(f"judge corpus: {sizes} clips per split, in {out}")


@expansion_app.command("truth")
def truth_command(
    split: Annotated[Path, typer.Argument(help="A folder made by `motionaug expansion split`.")],
    out: Annotated[Path, typer.Option(help="New folder for C: A plus the true stylized clips.")],
    mode: Annotated[
        Literal["auto", "rerender", "corpus"],
        typer.Option(help="rerender: synthetic clips in each missing style; corpus: its train clips of them."),
    ] = "auto",
) -> None:
    """Write C, the upper bound: A plus the true stylized clips, in its train split."""
    from motionaug.augment.eval.expansion import BASE_DIR, merge_clips, true_stylized

    with off_terminal("expansion truth"):
        sizes = run_safely(lambda: merge_clips(split / BASE_DIR, true_stylized(split, mode), out))
    console.print(f"C: {sizes} clips per split, in {out}")


@expansion_app.command("merge")
def merge_command(
    split: Annotated[Path, typer.Argument(help="A folder made by `motionaug expansion split`.")],
    run: Annotated[Path, typer.Option(help="A finished `motionaug run` over A's expand split.")],
    out: Annotated[Path, typer.Option(help="New folder for B: A plus the run's stylized clips.")],
) -> None:
    """Write B, the expanded corpus: A plus every stylized clip of the run, in its train split."""
    from motionaug.augment.eval.expansion import BASE_DIR, merge_clips, run_clips

    with off_terminal("expansion merge"):
        sizes = run_safely(lambda: merge_clips(split / BASE_DIR, run_clips(run), out))
    console.print(f"B: {sizes} clips per split, in {out}")


@expansion_app.command("score")
def score_command(
    split: Annotated[Path, typer.Argument(help="A folder made by `motionaug expansion split`.")],
    judge: Annotated[Path, typer.Option(help="Base models trained apart from the priors: the evaluators.")],
    priors: Annotated[list[str], typer.Option("--prior", help="NAME=BASE_MODELS_DIR, repeatable (e.g. A=..).")],
    guidance: Annotated[float, typer.Option(help="Classifier-free guidance scale (0 = none).")] = 3.0,
    steps: Annotated[int, typer.Option(help="DDIM steps.")] = 20,
    seed: Annotated[int, typer.Option(help="Sampling seed.")] = 0,
    out: Annotated[Path | None, typer.Option(help="Write every figure here as JSON.")] = None,
) -> None:
    """Sample every held-out caption with each prior and judge the motion; a table per caption group."""
    from motionaug.augment.eval.expansion import HELD_OUT_DIR, Judge, StyleSplit, score_prior
    from motionaug.schemas.errors import MotionDataError

    def score_all() -> dict[str, dict]:
        info = StyleSplit.read(split)
        named = dict(p.split("=", 1) for p in priors if "=" in p)
        if len(named) != len(priors) or not named:
            raise MotionDataError("--prior", "give each as NAME=BASE_MODELS_DIR")
        evaluators = Judge(judge)
        return {
            name: score_prior(path, split / HELD_OUT_DIR, evaluators, info.missing, info.neutral, guidance, steps, seed)
            for name, path in named.items()
        }

    with off_terminal("expansion score"):
        scores = run_safely(score_all)
    for group in ("style_prompted", "neutral", "present", "all"):
        if not any(group in figures for figures in scores.values()):
            continue
        table = Table(title=f"{group} captions")
        for column in ("prior", "samples", "style %", "content %", "FMD", "R@1 %", "R@3 %", "diversity"):
            table.add_column(column, justify="left" if column == "prior" else "right")
        for name, figures in scores.items():
            if group in figures:
                f = figures[group]
                cells = [f["style"], f["content"], f["fmd"], f["r1"], f["r3"], f["diversity"]]
                scaled = [v * 100 if i in (0, 1, 3, 4) and v is not None else v for i, v in enumerate(cells)]
                table.add_row(name, str(f["samples"]), *("n/a" if v is None else f"{v:.1f}" for v in scaled))
        console.print(table)
    if out is not None:
        out.write_text(json.dumps(scores, indent=1), encoding="utf-8")
        console.print(f"figures in {out}")
