"""Which of a synthetic style's numbers the style judge reads: real renders with parts of the style removed.

  python lab/synth_style_cues.py --corpus SYNTH/corpus --base EVALS [--split val] [--styles strutting,sneaky]

Each ``neutral`` clip of the split is rendered again (``augment.synth.render``, the same spec: path, duration,
phase) with one group of a style's numbers (``StyleParams``) kept or removed, and the synthetic style judge
(``EVALS/evaluators``, fit on the train split) labels the render. A group the judge needs shows as the style's
count falling when the group is removed. Groups: posture (the per-frame offsets), amplitude (step, swings,
gestures), timing (tempo, hesitation, sharpness) and rhythm (bounce, sway, swagger, head bob at the step rate).
It tells what a transfer must produce for its output to be read as the style; no model is trained or scored.
Writes ``BASE/style_cues-<split>.json`` and prints a Markdown table.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from motionaug.augment.corpus import Corpus  # noqa: E402
from motionaug.augment.eval.evaluation import classify, load_classifiers  # noqa: E402
from motionaug.augment.motion.features import (
    extract_features,  # noqa: E402
    features_to_joints,
)
from motionaug.augment.synth.animator import ClipSpec, render  # noqa: E402
from motionaug.augment.synth.styles import NEUTRAL, STYLES, StyleParams  # noqa: E402

GROUPS: dict[str, tuple[str, ...]] = {
    "posture": (
        "spine_lean",
        "chest",
        "head_pitch",
        "head_roll",
        "shrug",
        "shoulders_forward",
        "arm_out",
        "arm_forward",
        "elbow_bend",
        "knee_bend",
        "hip_bend",
        "stance_width",
    ),
    "amplitude": ("step", "arm_swing", "knee_lift", "gesture"),
    "timing": ("tempo", "hesitation", "hesitation_period", "sharpness"),
    "rhythm": ("bounce", "sway", "swagger", "head_bob"),
}


def only(style: StyleParams, group: str) -> StyleParams:
    """Neutral except ``group``'s numbers, which keep the style's."""
    return replace(NEUTRAL, **{name: getattr(style, name) for name in GROUPS[group]})


def without(style: StyleParams, group: str) -> StyleParams:
    """The style with ``group``'s numbers back at neutral."""
    return replace(style, **{name: getattr(NEUTRAL, name) for name in GROUPS[group]})


def scaled(style: StyleParams, group: str, factor: float) -> StyleParams:
    """The style with ``group``'s offsets from neutral times ``factor`` (what style guidance does to an output)."""
    return replace(
        style, **{n: getattr(NEUTRAL, n) + factor * (getattr(style, n) - getattr(NEUTRAL, n)) for n in GROUPS[group]}
    )


def variants(style: StyleParams) -> dict[str, StyleParams]:
    out: dict[str, StyleParams] = {"full": style}
    for group in GROUPS:
        out[f"{group} only"] = only(style, group)
        out[f"without {group}"] = without(style, group)
    out["posture x0.5"] = scaled(style, "posture", 0.5)
    out["rhythm x0.5"] = scaled(style, "rhythm", 0.5)
    out["posture x2, rhythm x0.5"] = scaled(scaled(style, "posture", 2.0), "rhythm", 0.5)
    return out


def judged(specs: list[ClipSpec], params: StyleParams, judge: Callable, labels: list[str]) -> dict[str, int]:
    joints = [features_to_joints(extract_features(render(s, params).joints, source="cue render")) for s in specs]
    predicted = np.bincount(judge(joints).argmax(1), minlength=len(labels))
    return {label: int(n) for label, n in zip(labels, predicted) if n}


def main(argv: list[str] | None = None) -> dict[str, object]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--corpus", type=Path, required=True)
    parser.add_argument("--base", type=Path, required=True, help="folder with evaluators/ (motionaug pretrain)")
    parser.add_argument("--split", default="val")
    parser.add_argument("--styles", default="", help="comma-separated; default every style but neutral")
    args = parser.parse_args(argv)
    clips = Corpus(args.corpus, split=args.split, split_spans=False)
    specs = [ClipSpec.from_json(c.meta["spec"]) for c in clips if c.style == "neutral"]
    judges = load_classifiers(args.base)

    def judge(joints: list[np.ndarray]) -> np.ndarray:
        return classify(judges.style, joints)[0]

    names = [s for s in args.styles.split(",") if s] or [s for s in STYLES if s != "neutral"]
    report: dict[str, object] = {"split": args.split, "clips": len(specs), "styles": {}}
    print(f"{len(specs)} {args.split} neutral specs; counts of the judge's labels\n")
    print("| style | variant | read as the style | labels |\n|---|---|---:|---|")
    for name in names:
        rows = {v: judged(specs, p, judge, judges.style_labels) for v, p in variants(STYLES[name]).items()}
        report["styles"][name] = rows  # type: ignore[index]
        for variant, counts in rows.items():
            print(f"| {name} | {variant} | {counts.get(name, 0) / len(specs):.0%} | {counts} |", flush=True)
    (args.base / f"style_cues-{args.split}.json").write_text(json.dumps(report, indent=1) + "\n")
    return report


if __name__ == "__main__":
    main()
