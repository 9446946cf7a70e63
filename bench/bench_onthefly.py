"""On-the-fly style transfer against the synthetic corpus's paired ground truth, plus fine-tune time and throughput.

Usage: python bench/bench_onthefly.py [--work /tmp/otf-bench] [--size small] [--n-clips 600] [--style proud]
       [--example-content walk] [--n-content 36] [--split test|val|val+test] [--lora-rank 4] [--threads 2]
       [--random-base] [--quick] [--skip full,ablation,content_clock,lora,throughput]

Protocol: fine-tune on ONE example clip of ``--style`` (a train-split ``--example-content`` clip of the corpus), then
transfer held-out neutral clips (of ``--split``: choose settings on ``val``, report on ``test``) of the OTHER
contents. Reported: SRA/CRA with the base models' classifiers (style = target style, content = the clip's own; also of
the inputs, of the inputs at the variant's tempo and of the ground truth), MPJPE of the output to the ground-truth
stylised rendering of the same clip spec (``ClipSpec.with_style``) vs the neutral input's (global joints and
root-relative joints: the output keeps the neutral path while the stylised ground truth walks its own, so the global
figure mixes path and pose), and the same against the style rendered on the content's own clock and stride
(``mpjpe_timing_kept``; ``mpjpe_oracle_timing_kept`` scores that rendering itself against the ground truth: the
ceiling of a method that keeps the content's timing), fine-tune seconds, the ablation without L_s, the paper's content
clock (``tempo="content"``: no retiming to the style's tempo measured from the example), LoRA vs full fine-tuning, and
transfer throughput (small/paper, fp32/bf16).

Base models come from ``augment.training.pretrain.ensure_base_models(corpus, out, size)``; with ``--random-base``
(or when that module is absent) they are random of ``--size`` and the classifier figures are left out (null).
``--quick``: tiny sizes and few clips, a smoke run in well under a minute.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import time
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.corpus.style_examples import load_style_examples
from motionaug.augment.eval.evaluation import Classifiers, load_classifiers
from motionaug.augment.methods.onthefly import OnTheFlyMethod, OnTheFlyModel, longest_frames, parse_params, retimed
from motionaug.augment.metrics import mpjpe, recognition_accuracy
from motionaug.augment.motion.batch import pad_batch
from motionaug.augment.motion.features import features_to_joints
from motionaug.augment.outputs.checksums import TIMINGS_FILE
from motionaug.augment.outputs.shards import TransferOutput
from motionaug.augment.training.base_models import BaseModels, BaseModelsInfo, config_dict
from motionaug.augment.training.evaluators import evaluators_folder
from motionaug.models.mdm import MDM, MDMConfig
from motionaug.models.motion_encoder import MotionEncoder, MotionEncoderConfig
from motionaug.schemas.skeleton import T2M
from motionaug.schemas.styles import StyleExample, StyleSpec, StyleWords


def load_corpus(work: Path, n_clips: int, seed: int) -> tuple[Path, list[MotionClip]]:
    """The default synthetic corpus under ``work/corpus`` (generated once), read back with its specs."""
    from motionaug.augment.corpus.humanml3d import HumanML3DReader
    from motionaug.augment.synth.corpus import generate_corpus, read_labels

    root = work / "corpus"
    if not (root / "labels.jsonl").is_file():
        generate_corpus(root, n_clips=n_clips, seed=seed)
    labels = {r["id"]: r for r in read_labels(root)}
    clips = []
    for clip in HumanML3DReader(root, split="all"):
        record = labels.get(clip.meta.get("parent", clip.id))
        if record is not None:
            clip.content, clip.style = record["content"], record["style"]
            clip.meta = {**clip.meta, "spec": json.dumps(record["spec"]), "split": record.get("split") or ""}
        clips.append(clip)
    return root, clips


def random_base(size: str, normalizer_dir: Path, out: Path) -> Path:
    """Random base models of a named size (no classifiers), Mean/Std from the corpus: timing and smoke runs."""
    from motionaug.augment.motion.features import Normalizer

    torch.manual_seed(0)
    prior_cfg, enc_cfg = MDMConfig.named(size), MotionEncoderConfig.named(size)
    info = BaseModelsInfo(size=size, max_frames=240, prior=config_dict(prior_cfg), motion_encoder=config_dict(enc_cfg))
    base = BaseModels(
        info=info,
        prior=MDM(prior_cfg),
        motion_encoder=MotionEncoder(enc_cfg),
        normalizer=Normalizer.load(normalizer_dir),
    )
    return base.save(out)


def get_base(work: Path, corpus_dir: Path, size: str, random: bool, caps: dict[str, float]) -> tuple[Path, bool]:
    """(base-models folder, whether it is pretrained). ``caps``: PretrainConfig overrides for 2 cores."""
    if not random:
        try:
            from motionaug.augment.training.pretrain import PretrainConfig, ensure_base_models
        except ImportError:
            print("motionaug.augment.training.pretrain is not available: random base models, no classifier figures")
        else:
            config = PretrainConfig.for_size(size, **{k: v for k, v in caps.items() if v})
            return Path(ensure_base_models(corpus_dir, work / f"base-{size}", size, config=config)), True
    out = work / f"random-base-{size}"
    if not (out / "base.json").is_file():
        random_base(size, corpus_dir, out)
    return out, False


def style_words(style: str) -> StyleWords:
    from motionaug.augment.synth.styles import STYLE_WORDS

    w = STYLE_WORDS[style]
    return StyleWords(adjective=w.adjective, adverb=w.adverb, phrases=tuple(w.phrases))


HELD_OUT = {"val": ("val",), "test": ("test",), "val+test": ("val", "test")}
"""``--split`` choices: the splits the scored neutral clips come from (tune on ``val``, report on ``test``)."""


def pick_clips(
    clips: Sequence[MotionClip], style: str, content: str, n_content: int, split: str = "test"
) -> tuple[MotionClip, list[MotionClip]]:
    """One ``style`` clip of ``content`` from the train split, and held-out neutral clips (of ``split``: a key of
    ``HELD_OUT``) of every other content: no scored clip is one the prior or the evaluators trained on."""
    candidates = [c for c in clips if c.style == style and c.content == content]
    train = [c for c in candidates if c.meta.get("split") == "train"] or candidates
    if not train:
        raise SystemExit(f"no {style} {content} clip in the corpus")
    held_out = HELD_OUT[split]
    neutral = [c for c in clips if c.style == "neutral" and c.content != content and c.meta.get("split") in held_out]
    by_content: dict[str, list[MotionClip]] = {}
    for clip in neutral:
        by_content.setdefault(clip.content or "", []).append(clip)
    chosen: list[MotionClip] = []
    while len(chosen) < n_content and any(by_content.values()):  # round-robin over contents
        for group in by_content.values():
            if group and len(chosen) < n_content:
                chosen.append(group.pop(0))
    return train[0], chosen


def ground_truth(clip: MotionClip, style: str, keep_timing: bool = False) -> np.ndarray:
    """The same clip spec rendered in ``style``: the paired target features.

    ``keep_timing``: the style's posture, amplitudes and rhythmic accents on the content's own clock and stride
    (tempo 1, no hesitations, step 1). The method keeps the content's root trajectory by design (the paper's
    sec. 7.1), so it cannot follow a style's slower clock or shorter steps; this target isolates what it can.
    """
    import dataclasses

    from motionaug.augment.motion.features import extract_features
    from motionaug.augment.synth import ClipSpec, render
    from motionaug.augment.synth.styles import style_params

    spec = ClipSpec.from_json(clip.meta["spec"]).with_style(style)
    params = dataclasses.replace(style_params(style), tempo=1.0, hesitation=0.0, step=1.0) if keep_timing else None
    return extract_features(render(spec, params).joints, source=f"ground truth of {clip.id}")


def _joints(motion: np.ndarray) -> np.ndarray:
    return features_to_joints(torch.as_tensor(motion), T2M).numpy()


LEG_JOINTS = [i for i, name in enumerate(T2M.joint_names) if any(k in name for k in ("hip", "knee", "ankle", "foot"))]
UPPER_JOINTS = [i for i in range(1, len(T2M.joint_names)) if i not in LEG_JOINTS]


def pose_errors(
    outputs: Sequence[np.ndarray], inputs: Sequence[np.ndarray], targets: Sequence[np.ndarray]
) -> dict[str, float]:
    """Mean MPJPE (m) of outputs and of inputs to the targets: global, root-relative (pelvis subtracted), and
    root-relative over the legs and over the upper body (pelvis excluded), to see which part a style moves."""
    keys = ("global", "local", "legs", "upper")
    result: dict[str, list[float]] = {f"{w}_{k}": [] for k in keys for w in ("out", "in")}
    for out, inp, tgt in zip(outputs, inputs, targets):
        n = min(len(out), len(inp), len(tgt))
        jt = _joints(tgt[:n])
        for who, motion in (("out", out), ("in", inp)):
            j = _joints(motion[:n])
            local, local_t = j - j[:, :1], jt - jt[:, :1]
            result[f"{who}_global"].append(mpjpe(j, jt))
            result[f"{who}_local"].append(mpjpe(local, local_t))
            result[f"{who}_legs"].append(mpjpe(local[:, LEG_JOINTS], local_t[:, LEG_JOINTS]))
            result[f"{who}_upper"].append(mpjpe(local[:, UPPER_JOINTS], local_t[:, UPPER_JOINTS]))
    means = {k: float(np.mean(v)) for k, v in result.items()}
    for kind in keys:
        means[f"reduction_{kind}"] = 1.0 - means[f"out_{kind}"] / means[f"in_{kind}"]
    return means


def accuracies(
    judges: Classifiers | None, motions: Sequence[np.ndarray], contents: Sequence[str], style: str
) -> dict[str, Any]:
    """SRA (style classifier says ``style``), CRA (content classifier says the clip's content), what style it said
    and, for the clips whose content it missed, ``"true -> said"`` counts."""
    if judges is None or judges.content is None or judges.style is None:
        return {"sra": None, "cra": None, "styles_predicted": None, "contents_missed": None}
    joints, mask = pad_batch([_joints(m) for m in motions])
    with torch.no_grad():
        style_logits = judges.style(joints, mask)
        content_logits = judges.content(joints, mask)
    s_idx = [judges.style_labels.index(style)] * len(motions)
    c_idx = [judges.content_labels.index(c) for c in contents]
    said = Counter(judges.style_labels[i] for i in style_logits.argmax(-1).tolist())
    content_said = [judges.content_labels[i] for i in content_logits.argmax(-1).tolist()]
    missed = Counter(f"{c} -> {p}" for c, p in zip(contents, content_said) if c != p)
    return {
        "sra": recognition_accuracy(style_logits, s_idx),
        "cra": recognition_accuracy(content_logits, c_idx),
        "styles_predicted": dict(said.most_common()),
        "contents_missed": dict(missed.most_common()),
    }


def run_variant(
    name: str,
    params: dict[str, Any],
    spec: StyleSpec,
    examples: list[MotionClip],
    base_dir: Path,
    corpus: Sequence[MotionClip],
    content: list[MotionClip],
    work: Path,
    style: str,
) -> dict[str, Any]:
    """Fine-tune one variant, transfer the content clips, score them."""
    method = OnTheFlyMethod(parse_params(params))
    start = time.perf_counter()
    artifact = method.prepare(spec, examples, base_dir, corpus, work / f"artifact-{name}").folder
    prepare_s = time.perf_counter() - start
    info = json.loads((artifact / "artifact.json").read_text())
    timings = json.loads((artifact / TIMINGS_FILE).read_text())
    model: OnTheFlyModel = method.load(artifact, base_dir)
    judges = load_classifiers(base_dir) if evaluators_folder(base_dir) else None
    start = time.perf_counter()
    outs = model.transfer(content, seed=0)
    transfer_s = time.perf_counter() - start
    done = [o for o in outs if isinstance(o, TransferOutput)]
    motions = [o.motion for o in done]
    curve = info["loss_curve"]
    contents = [c.content or "" for c in content]
    targets = [ground_truth(c, style) for c in content]
    longest = longest_frames(model.model, model.base)
    inputs_retimed = [retimed(c.motion, model.tempo, model.base, longest) for c in content]
    k = max(1, len(curve) // 10)
    return {
        "variant": name,
        "prepare_s": prepare_s,
        "finetune_s": timings.get("finetune_s"),
        "pairs_and_pool_s": timings.get("pairs_and_pool_s"),
        "steps": len(curve),
        "pool_clips": info["pool_clips"],
        "tempo": info["tempo"],
        "tempo_note": info["tempo_note"],
        "weights_bytes": info["weights_bytes"],
        "weights_share": info["weights_bytes"] / info["full_model_bytes"],
        "l_rec_first_last": [
            float(np.mean([r["l_rec"] for r in curve[:k]])),
            float(np.mean([r["l_rec"] for r in curve[-k:]])),
        ],
        "l_s_first_last": [
            float(np.mean([r["l_s"] for r in curve[:k]])),
            float(np.mean([r["l_s"] for r in curve[-k:]])),
        ],
        "transferred": len(done),
        "rejected": len(outs) - len(done),
        "transfer_clips_per_s": len(done) / transfer_s,
        **accuracies(judges, motions, contents, style),
        "input_accuracy": accuracies(judges, [c.motion for c in content], contents, style),
        # what the classifiers make of the inputs at the variant's tempo (before any transfer) and of the ground truth
        "retimed_input_accuracy": accuracies(judges, inputs_retimed, contents, style),
        "ground_truth_accuracy": accuracies(judges, targets, contents, style),
        "mpjpe": pose_errors(motions, [c.motion for c in content], targets),
        "mpjpe_timing_kept": pose_errors(
            motions, [c.motion for c in content], [ground_truth(c, style, True) for c in content]
        ),
        "mean_scores": {key: float(np.mean([o.scores[key] for o in done])) for key in done[0].scores} if done else {},
    }


def throughput(
    sizes: Sequence[str], content: list[MotionClip], spec: StyleSpec, normalizer_dir: Path, work: Path, batch: int
) -> list[dict[str, Any]]:
    """Transfer clips/s of random transfer models (speed does not depend on weights), fp32 and bf16."""
    rows = []
    for size in sizes:
        base_dir = work / f"random-base-{size}"
        if not (base_dir / "base.json").is_file():
            random_base(size, normalizer_dir, base_dir)
        base = BaseModels.load(base_dir)
        for bf16 in (False, True):
            model = OnTheFlyModel(spec, base, base.prior, parse_params(bf16=bf16, batch_size=batch))
            model.transfer(content[:batch])  # warm-up (text encoder, kernels)
            start = time.perf_counter()
            outs = model.transfer(content)
            seconds = time.perf_counter() - start
            rows.append(
                {"size": size, "bf16": bf16, "clips": len(outs), "batch": batch, "clips_per_s": len(outs) / seconds}
            )
    return rows


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, default=Path("/tmp/otf-bench"))
    parser.add_argument("--size", default="small")
    parser.add_argument("--n-clips", type=int, default=600)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--style", default="proud")
    parser.add_argument("--example-content", default="walk")
    parser.add_argument("--n-content", type=int, default=36)
    parser.add_argument("--split", choices=sorted(HELD_OUT), default="test", help="split of the scored clips")
    parser.add_argument("--lora-rank", type=int, default=4)
    parser.add_argument("--threads", type=int, default=int(os.environ.get("MOTIONAUG_TORCH_THREADS", "2")))
    parser.add_argument("--random-base", action="store_true")
    parser.add_argument("--base-dir", type=Path, default=None, help="use this base-models folder as it is")
    parser.add_argument("--pretrain-batch", type=int, default=16, help="pretraining batch size (small preset: 64)")
    parser.add_argument("--pretrain-only", action="store_true", help="build the base models and stop")
    parser.add_argument("--quick", action="store_true", help="tiny sizes, few clips: a smoke run")
    parser.add_argument("--skip", default="", help="comma list of: full, ablation, content_clock, lora, throughput")
    parser.add_argument("--params", default="{}", help="JSON overrides of OnTheFlyParams for every variant")
    parser.add_argument("--lora-params", default="{}", help="JSON overrides of OnTheFlyParams for the LoRA variant")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    os.environ["MOTIONAUG_TORCH_THREADS"] = str(args.threads)
    skip = set(filter(None, args.skip.split(",")))
    overrides = json.loads(args.params)
    if args.quick:
        args.size, args.n_clips, args.n_content, args.random_base = (
            "tiny",
            min(args.n_clips, 48),
            min(args.n_content, 4),
            True,
        )
        overrides = {"pair_steps": 20, "max_steps": 2, "batch_size": 4, **overrides}
    args.work.mkdir(parents=True, exist_ok=True)
    corpus_dir, corpus = load_corpus(args.work, args.n_clips, args.seed)
    caps = {"batch_size": args.pretrain_batch}
    if args.base_dir is not None:
        base_dir, pretrained = args.base_dir, evaluators_folder(args.base_dir) is not None
    else:
        base_dir, pretrained = get_base(args.work, corpus_dir, args.size, args.random_base, caps)
    if args.pretrain_only:
        print(json.dumps({"base_dir": str(base_dir), "pretrained": pretrained}))
        return {"base_dir": str(base_dir)}
    example, content = pick_clips(corpus, args.style, args.example_content, args.n_content, args.split)
    words = style_words(args.style)
    description = next(
        (
            c.text
            for c in example.captions
            if words.adjective in c.text or (words.adverb or "@") in c.text or any(p in c.text for p in words.phrases)
        ),
        f"a person walks {words.adverb or words.phrases[0]}",
    )
    spec = StyleSpec(name=args.style, words=words, examples=[StyleExample(source=example.id, description=description)])
    examples = load_style_examples(spec, {example.id: example})
    pool = [c for c in corpus if c.id != example.id and c not in content]
    report: dict[str, Any] = {
        "args": {k: str(v) for k, v in vars(args).items()},
        "pretrained_base": pretrained,
        "base_dir": str(base_dir),
        "example": {"id": example.id, "content": example.content, "description": description},
        "n_content": len(content),
        "split": args.split,
        "content_splits": dict(Counter(c.meta.get("split") for c in content)),
        "contents": sorted({c.content or "" for c in content}),
        "corpus_clips": len(corpus),
        "threads": torch.get_num_threads(),
        "uptime_before": subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip(),
    }
    # the best any trajectory-keeping method can do: the style rendered perfectly on the content's clock and stride
    report["mpjpe_oracle_timing_kept"] = pose_errors(
        [ground_truth(c, args.style, True) for c in content],
        [c.motion for c in content],
        [ground_truth(c, args.style) for c in content],
    )
    variants = {} if "full" in skip else {"full": overrides}
    if "ablation" not in skip:
        variants["no_semantic_loss"] = {**overrides, "lambda_s": 0.0}
    if "content_clock" not in skip:
        variants["content_clock"] = {**overrides, "tempo": "content"}
    if "lora" not in skip:
        lora_lr = 10 * overrides.get("lr", 1e-4)  # adapters start at zero and learn slower: the usual 10x rate
        lora = {"lr": lora_lr, **overrides, "lora_rank": args.lora_rank, **json.loads(args.lora_params)}
        variants[f"lora{args.lora_rank}"] = lora
    report["variants"] = [
        run_variant(n, p, spec, examples, base_dir, pool, content, args.work, args.style) for n, p in variants.items()
    ]
    if "throughput" not in skip:
        sizes = ["tiny"] if args.quick else ["small", "paper"]
        report["throughput"] = throughput(sizes, content, spec, corpus_dir, args.work, batch=8)
    report["uptime_after"] = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    (args.work / "bench_onthefly.json").write_text(json.dumps(report, indent=2))
    print(json.dumps(report, indent=2))
    return report


if __name__ == "__main__":
    main()
