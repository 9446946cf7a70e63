"""Fingerprints of every shipped method config's outputs, to compare two commits.

Each shipped ``configs/*.yaml`` method's params are taken as they are, with ``train`` sized down to the method's
own ``smoke_params`` and fewer sampling steps, then run through the method contract (train, prepare, load,
transfer) without Ray. Printed per config: sha256 of every weight file written and of the motion and caption
columns of the outputs. Run it in two worktrees (``--root``) and diff the two outputs:

    .venv/bin/python bench/bench_behaviour.py --root ../base > /tmp/base.txt
    .venv/bin/python bench/bench_behaviour.py --root . > /tmp/new.txt && diff /tmp/base.txt /tmp/new.txt

``--demo SIZE`` runs ``motionaug demo --size SIZE`` (corpus, base models, run) and prints the same fingerprints.
``--bandai2 CORPUS`` runs the four Bandai-2 configs instead through ``motionaug run``'s executor (real Ray) at
reduced steps (tiny networks, the smoke params), on the ``walk`` takes of the test split in two styles, then
``evaluate`` with the on-the-fly run's evaluators: printed are the motion and caption columns of every shard row,
every weight file (run folder and trained models) and ``scores.parquet``'s columns.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import yaml

CONFIGS = (
    "umsd-synthetic",
    "bandai2-umsd",
    "bandai2-erd",
    "stats-synthetic",
    "bandai2-stats",
    "bandai2-onthefly",
    "onthefly-lora-synthetic",
)
STYLES = ("proud", "old")
N_CLIPS = 40
BANDAI2_METHODS = ("onthefly", "stats", "erd", "umsd")  # on-the-fly first: its evaluators score every run
BANDAI2_STYLES = 2


def tree_env(root: Path) -> dict[str, str]:
    """An environment whose ``motionaug`` is the worktree at ``root``, ahead of the installed (editable) copy."""
    shim = Path(tempfile.mkdtemp()) / "motionaug"
    shim.mkdir()
    for layer in ("schemas", "models", "augment", "workflows"):
        (shim / layer).symlink_to((root / layer).resolve())
    return {**os.environ, "PYTHONPATH": str(shim.parent), "RAY_USAGE_STATS_ENABLED": "0"}


def digest(chunks) -> str:
    h = hashlib.sha256()
    for chunk in chunks:
        h.update(chunk)
    return h.hexdigest()[:16]


def run_config(name: str, root: Path, corpus: Path, work: Path) -> list[str]:
    from motionaug.augment.corpus import Corpus
    from motionaug.augment.methods.base import TrainingSpec
    from motionaug.augment.methods.registry import create_method, method_class

    config = yaml.safe_load((root / "configs" / f"{name}.yaml").read_text())
    method_name = config["method"]["name"]
    params = dict(config["method"].get("params") or {})
    smoke = method_class(method_name).smoke_params
    if "train" in smoke:
        params["train"] = {**params.get("train", {}), **smoke["train"]}
    for key in ("ddim_steps", "batch_size"):
        if key in smoke and key in method_class(method_name).Params.model_fields:
            params[key] = smoke[key]
    if "neutral_style" in params:
        params["neutral_style"] = "neutral"  # the synthetic stand-in's plain style
    method = create_method(method_name, params)
    clips = list(Corpus(corpus))
    trained = None
    if method.trains:
        older = "options" in TrainingSpec.__dataclass_fields__  # a baseline commit before the settings moved
        spec = TrainingSpec(size="tiny", seed=0, **({"options": {}} if older else {}))
        trained = method.train(corpus, work / "trained", spec)
    lines = []
    content = [c for c in clips if c.style == "neutral" and c.n_frames >= 40]
    for style_name in STYLES:
        from motionaug.schemas.styles import StyleSpec

        example = next(c for c in clips if c.style == style_name)
        spec = {"adjective": style_name}
        style = StyleSpec(name=style_name, words=spec, examples=[{"source": example.id, "description": "a walk"}])
        prepared = method.prepare(style, [example], trained, content[:8], work / style_name, seed=0)
        artifact = Path(getattr(prepared, "folder", prepared))  # a tree before prepare returned its timings too
        model = method.load(artifact, trained)
        outputs = model.transfer(content[:6], seed=0)
        done = [o for o in outputs if hasattr(o, "motion")]
        motions = digest(o.motion.tobytes() for o in done)
        captions = digest(repr([c.model_dump() for c in o.captions]).encode() for o in done)
        lines.append(f"{name} {style_name} motion {motions} captions {captions} rows {len(outputs)}")
    for path in sorted(work.rglob("*.safetensors")):
        lines.append(f"{name} weights {path.relative_to(work)} {digest([path.read_bytes()])}")
    return lines


def run_bandai2(method_name: str, root: Path, corpus: Path, work: Path, evaluators: Path | None) -> list[str]:
    """One shipped Bandai-2 config through the executor at reduced steps, evaluated; its fingerprint lines."""
    import pyarrow.parquet as pq

    from motionaug.augment.eval.evaluation import evaluate_run, write_scores
    from motionaug.augment.methods.registry import method_class
    from motionaug.augment.outputs.shards import iter_shard_rows, row_motion
    from motionaug.schemas.run_config import load_run_config
    from motionaug.workflows.ray_executor import execute_run

    data = yaml.safe_load((root / "configs" / f"bandai2-{method_name}.yaml").read_text())
    smoke = {k: v for k, v in method_class(method_name).smoke_params.items() if k != "shapers"}  # none shipped
    params = dict(data["method"].get("params") or {})
    for key, value in smoke.items():
        params[key] = {**params.get(key, {}), **value} if isinstance(value, dict) else value
    data["method"]["params"] = params
    data["styles"] = data["styles"][:BANDAI2_STYLES]
    data["corpus"] |= {"path": str(corpus), "split": "test", "pool_split": "train"}
    data["corpus"]["filters"]["contents"] = ["walk"]
    data["base_models"] = {"path": str(work / "trained"), "corpus": str(corpus), "size": "tiny"}
    data["output"] = str(work / "run")
    data["compute"] |= {"num_cpus": 2}
    execute_run(load_run_config(None, data=data))
    scores = write_scores(evaluate_run(work / "run", base_models=evaluators or work / "trained"))
    columns = ["source_id", "style", "motion", "n_frames", "n_feats", "captions"]
    rows = sorted(iter_shard_rows(work / "run", columns=columns), key=lambda r: (r["source_id"], r["style"]))
    lines = [
        f"bandai2-{method_name} rows {len(rows)} motion {digest(row_motion(r).tobytes() for r in rows)} "
        f"captions {digest(repr(r['captions']).encode() for r in rows)}"
    ]
    table = pq.read_table(scores).sort_by("output_id")
    for name in table.column_names:
        lines.append(f"bandai2-{method_name} scores {name} {digest([repr(table.column(name).to_pylist()).encode()])}")
    for path in sorted(work.rglob("*.safetensors")):
        lines.append(f"bandai2-{method_name} weights {path.relative_to(work)} {digest([path.read_bytes()])}")
    return lines


def run_demo_size(size: str, work: Path) -> list[str]:
    """The demo's run at ``size`` from an empty folder; its fingerprint lines."""
    from motionaug.augment.outputs.shards import iter_shard_rows, row_motion
    from motionaug.workflows.demo import run_demo

    result = run_demo(work, size=size)
    columns = ["source_id", "style", "motion", "n_frames", "n_feats", "captions"]
    rows = sorted(iter_shard_rows(result.run.run_dir, columns=columns), key=lambda r: (r["source_id"], r["style"]))
    lines = [
        f"demo-{size} rows {len(rows)} motion {digest(row_motion(r).tobytes() for r in rows)} "
        f"captions {digest(repr(r['captions']).encode() for r in rows)}"
    ]
    for path in sorted(work.rglob("*.safetensors")):
        lines.append(f"demo-{size} weights {path.relative_to(work)} {digest([path.read_bytes()])}")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=Path("."), help="the worktree whose code and configs to run")
    parser.add_argument("--configs", default=",".join(CONFIGS), help="comma-separated shipped config names")
    parser.add_argument("--bandai2", type=Path, help="the Bandai-2 corpus: run its four configs through Ray")
    parser.add_argument("--demo", choices=["tiny", "small"], help="run the demo at this size instead")
    parser.add_argument("--in-tree", action="store_true", help=argparse.SUPPRESS)  # the child run in --root's code
    args = parser.parse_args()
    if not args.in_tree:
        command = [sys.executable, __file__, "--root", str(args.root), "--configs", args.configs, "--in-tree"]
        command += ["--bandai2", str(args.bandai2.resolve())] if args.bandai2 else []
        command += ["--demo", args.demo] if args.demo else []
        raise SystemExit(subprocess.run(command, env=tree_env(args.root)).returncode)
    import torch

    import motionaug.augment

    print(f"code: {list(motionaug.augment.__path__)}", file=sys.stderr)
    torch.set_num_threads(1)
    if args.demo:
        with tempfile.TemporaryDirectory() as tmp:
            for line in run_demo_size(args.demo, Path(tmp) / "demo"):
                print(line, flush=True)
        return
    if args.bandai2:
        with tempfile.TemporaryDirectory() as tmp:
            for name in BANDAI2_METHODS:
                evaluators = Path(tmp) / "onthefly" / "trained" if name != "onthefly" else None
                for line in run_bandai2(name, args.root, args.bandai2, Path(tmp) / name, evaluators):
                    print(line, flush=True)
        return
    from motionaug.augment.synth import generate_corpus

    with tempfile.TemporaryDirectory() as tmp:
        corpus = Path(tmp) / "corpus"
        generate_corpus(corpus, N_CLIPS, seed=0)
        for name in args.configs.split(","):
            for line in run_config(name, args.root, corpus, Path(tmp) / name):
                print(line, flush=True)


if __name__ == "__main__":
    main()
