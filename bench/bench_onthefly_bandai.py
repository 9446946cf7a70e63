"""On-the-fly transfer with a REAL style example: one Bandai Namco motion-capture clip (retargeted to t2m).

Usage: python bench/bench_onthefly_bandai.py --bandai DIR --work DIR --base-dir DIR [--style proud]
       [--example-content walk] [--n-content 36] [--threads 2] [--params JSON]

``--bandai``: an imported Bandai corpus (``motionaug corpus import-bvh ../shared/data/bandai/dataset-1 --out DIR``);
``--work``: holds the default synthetic corpus (``work/corpus``, rendered when absent); ``--base-dir``: base
models pre-trained on that synthetic corpus (``bench/bench_pretrain.py``).

Protocol: fine-tune the synthetic base models on ONE Bandai clip of ``--style`` (its ``--example-content`` take),
with the synthetic neutral clips as the L_s pool, then transfer
  (a) neutral synthetic clips of the other contents: SRA / CRA with the synthetic evaluators (the Bandai style
      must be one of the synthetic styles, e.g. proud, old, angry), and
  (b) the Bandai ``normal`` clips of the other contents: SRA / CRA with content and style classifiers trained
      on the whole Bandai corpus (their held-out accuracy is in bench/RESULTS.md: content 0.71, style 0.53).
Prints one JSON object (also written to ``work/bench_onthefly_bandai.json``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from bench_onthefly import _joints, accuracies, load_corpus, pick_clips, style_words

from motionaug.augment.corpus.humanml3d import HumanML3DReader, read_labels
from motionaug.augment.corpus.style_examples import load_style_examples
from motionaug.augment.eval.inputs import pad_batch
from motionaug.augment.eval.metrics import recognition_accuracy
from motionaug.augment.methods.base import TransferOutput
from motionaug.augment.methods.onthefly import OnTheFlyMethod, parse_params
from motionaug.augment.training.base_models import BaseModels
from motionaug.augment.training.evaluators import fit_classifier
from motionaug.models.evaluators import make_classifier
from motionaug.schemas.styles import StyleExample, StyleSpec


def bandai_clips(root: Path) -> list[Any]:
    labels = read_labels(root)
    clips = []
    for clip in HumanML3DReader(root, split="all"):
        record = labels.get(clip.id)
        if record is not None:
            clip.content, clip.style = record["content"], record["style"]
            clips.append(clip)
    return clips


def bandai_judges(clips: list[Any], seed: int = 0) -> dict[str, tuple[Any, list[str]]]:
    """Content and style classifiers trained on every Bandai clip's first 196 frames (retargeted t2m joints)."""
    joints, mask = pad_batch([_joints(c.motion[:196]) for c in clips])
    judges = {}
    for attr in ("content", "style"):
        names = sorted({getattr(c, attr) for c in clips})
        labels = torch.tensor([names.index(getattr(c, attr)) for c in clips])
        torch.manual_seed(seed)
        model = make_classifier(len(names), joints.shape[2])
        fit_classifier(model, (joints, mask, labels), epochs=40, seed=seed)
        judges[attr] = (model, names)
    return judges


def judge(
    judges: dict[str, tuple[Any, list[str]]], motions: list[np.ndarray], contents: list[str], style: str
) -> dict[str, float]:
    joints, mask = pad_batch([_joints(m) for m in motions])
    out = {}
    with torch.no_grad():
        for key, attr, targets in (("sra", "style", [style] * len(motions)), ("cra", "content", contents)):
            model, names = judges[attr]
            out[key] = recognition_accuracy(model(joints, mask), [names.index(t) for t in targets])
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bandai", type=Path, required=True)
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--base-dir", type=Path, required=True)
    parser.add_argument("--style", default="proud")
    parser.add_argument("--example-content", default="walk")
    parser.add_argument("--n-content", type=int, default=36)
    parser.add_argument("--n-clips", type=int, default=1000, help="synthetic corpus size when it is rendered")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--params", default="{}", help="JSON overrides of OnTheFlyParams")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    os.environ["MOTIONAUG_TORCH_THREADS"] = str(args.threads)
    _, synthetic = load_corpus(args.work, args.n_clips, 0)
    real = bandai_clips(args.bandai)
    example = next(c for c in real if c.style == args.style and c.content == args.example_content)
    words = style_words(args.style)
    spec = StyleSpec(
        name=args.style,
        words=words,
        examples=[StyleExample(source=example.id, description=f"a person walks {words.adverb or words.phrases[0]}")],
    )
    examples = load_style_examples(spec, {example.id: example})
    _, synthetic_content = pick_clips(synthetic, "neutral", args.example_content, args.n_content)
    # takes run up to a minute; transfer (and the evaluators) take HumanML3D-length clips: the first 196 frames
    real_content = [
        dataclasses.replace(c, motion=c.motion[:196])
        for c in real
        if c.style == "normal" and c.content != args.example_content
    ]
    pool = [c for c in synthetic if c.style == "neutral" and c not in synthetic_content]

    method = OnTheFlyMethod(parse_params(json.loads(args.params)))
    start = time.perf_counter()
    artifact = method.prepare(spec, examples, args.base_dir, pool, args.work / "artifact-bandai")
    prepare_s = time.perf_counter() - start
    model = method.load(artifact, args.base_dir)
    base = BaseModels.load(args.base_dir)
    report: dict[str, Any] = {
        "example": example.id,
        "style": args.style,
        "prepare_s": round(prepare_s, 1),
        "params": json.loads(args.params),
    }
    for name, content in (("synthetic", synthetic_content), ("bandai", real_content)):
        outs = model.transfer(content, seed=0)
        done = [(o, c) for o, c in zip(outs, content) if isinstance(o, TransferOutput)]
        motions, contents = [o.motion for o, _ in done], [c.content or "" for _, c in done]
        if name == "synthetic":
            scores, before = (accuracies(base, m, contents, args.style) for m in (motions, [c.motion for _, c in done]))
        else:
            judges = bandai_judges(real)
            scores, before = (judge(judges, m, contents, args.style) for m in (motions, [c.motion for _, c in done]))
        report[name] = {
            "clips": len(content),
            "transferred": len(done),
            **scores,
            "input": before,
            "contents": sorted(set(contents)),
        }
    (args.work / "bench_onthefly_bandai.json").write_text(json.dumps(report, indent=2))
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
