"""Contact sheet of output shapers on held-out content clips: the content, each shaper chain, and a real take of the
same content in the style (for the eye only; it reaches no shaper).

    .venv/bin/python lab/shaper_preview.py --corpus BANDAI2 --style elderly --draw 0 --split val \
        --chains moments "coordination,moments,lock_feet" --hook-modules lab.style_spectrum --out sheet.png

The example is the LSO draw's k = 1 take (``bench/lso/<kind>-draws.json``), its reference the nearest plain train
clip by root motion (plain clips are in every fold's corpus), as ``bench/bench_lso.py run --row shapers`` does.
``--bones``: no sheet; per chain, the mean change of a bone's length (against the content's mean length) over every
plain clip of the split shaped into each ``--style``, the mean over the styles (real takes: 0).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from motionaug.augment.corpus import Corpus
from motionaug.augment.eval.protocol import ExampleDraws
from motionaug.augment.methods.hooks import ShapeContext, import_hook_modules, output_shapers, parse_hook_specs
from motionaug.augment.methods.shaping import nearest_root_motion
from motionaug.augment.motion.features import features_to_joints
from motionaug.augment.motion.travel import travels
from motionaug.augment.render.previews import Panel, SheetRow, render_contact_sheet
from motionaug.schemas.skeleton import T2M

REPO = Path(__file__).resolve().parents[1]
NEUTRAL = {"bandai2": "normal", "synthetic": "neutral"}  # each corpus kind's plain style


def bone_lengths(joints: np.ndarray) -> np.ndarray:
    """(T, bones) length of every bone of the kinematic chains."""
    pairs = [(a, b) for chain in T2M.kinematic_chain for a, b in zip(chain[:-1], chain[1:])]
    return np.stack([np.linalg.norm(joints[:, b] - joints[:, a], axis=-1) for a, b in pairs], axis=-1)


def shaped(motion: np.ndarray, chain: list, context: ShapeContext) -> np.ndarray:
    for shaper in output_shapers.create_all(chain):
        motion = shaper(motion, context)
        context = shaper.context_after(context)
    return motion


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--corpus", type=Path, required=True)
    parser.add_argument("--kind", default="bandai2")
    parser.add_argument("--style", nargs="+", required=True, help="the sheet shows the first")
    parser.add_argument("--draw", type=int, default=0)
    parser.add_argument("--split", default="val")
    parser.add_argument("--contents", nargs="+", default=["walk", "raise-up-both-hands", "run", "wave-right-hand"])
    parser.add_argument("--chains", nargs="+", required=True, help="comma-separated shaper names per panel")
    parser.add_argument("--hook-modules", nargs="*", default=[])
    parser.add_argument("--bones", action="store_true", help="print each chain's bone-length change, no sheet")
    parser.add_argument("--out", type=Path)
    parser.add_argument(
        "--example-content",
        help="also each chain with the style's val take of this content as the example, "
        "against the plain train clip of its content nearest by root motion (the B2w scenario, bench/RESULTS.md 0)",
    )
    args = parser.parse_args()
    import_hook_modules(args.hook_modules)
    neutral = NEUTRAL[args.kind]
    path = REPO / "bench" / "lso" / f"{args.kind}-draws.json"
    draws = ExampleDraws.model_validate_json(path.read_text(encoding="utf-8"))
    train = {c.id: c for c in Corpus(args.corpus, split="train")}
    plain = {i: c.motion for i, c in train.items() if c.style == neutral}  # in every fold's corpus
    scored = list(Corpus(args.corpus, split=args.split))
    chains = {chain: parse_hook_specs(chain) for chain in args.chains}

    def context_for(style: str, source: np.ndarray) -> ShapeContext:
        example = train[draws.draws[style][args.draw][0]].motion
        return ShapeContext(content=source, example=example, reference=nearest_root_motion(example, plain)[1], fps=20.0)

    def example_of_content(style: str, source: np.ndarray) -> ShapeContext:
        takes = sorted(
            (c for c in Corpus(args.corpus, split="val") if c.style == style and c.content == args.example_content),
            key=lambda c: c.id,
        )
        example = takes[args.draw % len(takes)].motion
        alike = {i: c.motion for i, c in train.items() if c.style == neutral and c.content == args.example_content}
        return ShapeContext(content=source, example=example, reference=nearest_root_motion(example, alike)[1], fps=20.0)

    if args.bones:
        sources = [c.motion for c in scored if c.style == neutral]
        for chain, specs in chains.items():
            change = [
                np.abs(
                    bone_lengths(features_to_joints(shaped(m, specs, context_for(style, m))))
                    / bone_lengths(features_to_joints(m)).mean(0)
                    - 1
                ).mean()
                for style in args.style
                for m in sources
            ]
            print(f"{chain or 'content'}: bones {100 * np.mean(change):.1f}% (worst clip {100 * max(change):.1f}%)")
        return
    if args.out is None:
        parser.error("--out is needed for the sheet")
    style, rows = args.style[0], []
    for content in args.contents:
        source = next((c for c in scored if c.style == neutral and c.content == content), None)
        real = next((c for c in scored if c.style == style and c.content == content), None)
        if source is None:
            continue
        context = context_for(style, source.motion)
        panels = [Panel(features_to_joints(source.motion), "content")]
        # the run picks the other example for in-place clips only
        other = (
            example_of_content(style, source.motion)
            if args.example_content and not travels(source.motion, 20.0)
            else None
        )
        for chain, specs in chains.items():
            panels.append(Panel(features_to_joints(shaped(source.motion, specs, context)), chain, color="#c05621"))
            if other is not None:
                label = f"{chain}, {args.example_content} example"
                panels.append(Panel(features_to_joints(shaped(source.motion, specs, other)), label, color="#6b46c1"))
        if real is not None:
            panels.append(Panel(features_to_joints(real.motion), f"real {style}", color="#2f855a"))
        rows.append(SheetRow(f"{content}: {source.id}", panels))
    print(render_contact_sheet(rows, args.out, n_keyposes=8))


if __name__ == "__main__":
    main()
