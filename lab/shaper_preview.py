"""Contact sheet of output shapers on held-out content clips: the content, each shaper chain, and a real take of the
same content in the style (for the eye only; it reaches no shaper).

    .venv/bin/python lab/shaper_preview.py --corpus BANDAI2 --style elderly --draw 0 --split val \
        --chains moments "coordination,moments,lock_feet" --hook-modules lab.style_coordination --out sheet.png

The example is the LSO draw's k = 1 take (``bench/lso/<kind>-draws.json``), its reference the nearest plain train
clip by root motion (plain clips are in every fold's corpus), as ``bench/bench_lso.py run --row shapers`` does.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from motionaug.augment.corpus import Corpus
from motionaug.augment.eval.protocol import ExampleDraws
from motionaug.augment.methods.hooks import ShapeContext, import_hook_modules, output_shapers
from motionaug.augment.methods.shaping import nearest_root_motion
from motionaug.augment.motion.features import features_to_joints
from motionaug.augment.render.previews import Panel, SheetRow, render_contact_sheet

REPO = Path(__file__).resolve().parents[1]
NEUTRAL = "normal"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--corpus", type=Path, required=True)
    parser.add_argument("--kind", default="bandai2")
    parser.add_argument("--style", required=True)
    parser.add_argument("--draw", type=int, default=0)
    parser.add_argument("--split", default="val")
    parser.add_argument("--contents", nargs="+", default=["walk", "raise-up-both-hands", "run", "wave-right-hand"])
    parser.add_argument("--chains", nargs="+", required=True, help="comma-separated shaper names per panel")
    parser.add_argument("--hook-modules", nargs="*", default=[])
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    import_hook_modules(args.hook_modules)
    sys.path.insert(0, str(REPO / "bench"))  # the LSO bench's shaper specs (NAME:KEY=VALUE)
    from bench_lso import shaper_specs  # noqa: E402

    path = REPO / "bench" / "lso" / f"{args.kind}-draws.json"
    draws = ExampleDraws.model_validate_json(path.read_text(encoding="utf-8"))
    train = {c.id: c for c in Corpus(args.corpus, split="train")}
    example = train[draws.draws[args.style][args.draw][0]].motion
    plain = {i: c.motion for i, c in train.items() if c.style == NEUTRAL}  # in every fold's corpus
    reference = nearest_root_motion(example, plain)[1]
    scored = list(Corpus(args.corpus, split=args.split))
    rows = []
    for content in args.contents:
        source = next((c for c in scored if c.style == NEUTRAL and c.content == content), None)
        real = next((c for c in scored if c.style == args.style and c.content == content), None)
        if source is None:
            continue
        context = ShapeContext(content=source.motion, example=example, reference=reference, fps=source.fps)
        panels = [Panel(features_to_joints(source.motion), "content")]
        for chain in args.chains:
            motion = source.motion
            for shaper in output_shapers.create_all(shaper_specs(chain)):
                motion = shaper(motion, context)
            panels.append(Panel(features_to_joints(motion), chain, color="#c05621"))
        if real is not None:
            panels.append(Panel(features_to_joints(real.motion), f"real {args.style}", color="#2f855a"))
        rows.append(SheetRow(f"{content}: {source.id}", panels))
    print(render_contact_sheet(rows, args.out, n_keyposes=8))


if __name__ == "__main__":
    main()
