"""Cost of looking at a run: ``evaluate`` (per-clip scores + report), one GIF preview, BVH export.

Renders a synthetic corpus, fits ``tiny`` evaluators for a few epochs on its train split, runs the shipped
``configs/stats-synthetic.yaml`` on it (embedded Ray), then times each step on one CPU thread. Results go to
stdout as JSON; no accuracy figure comes from this bench.

    .venv/bin/python bench/bench_evaluation.py --clips 200
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import torch

from motionaug.augment.eval.evaluation import evaluate_run, preview_transfer, write_scores
from motionaug.augment.eval.report import write_report
from motionaug.augment.outputs.bvh_export import export_bvh
from motionaug.augment.synth import generate_corpus
from motionaug.augment.training.pretrain import PretrainConfig, fit_evaluators
from motionaug.schemas.run_config import load_run_config
from motionaug.workflows.ray_executor import execute_run

REPO = Path(__file__).resolve().parents[1]


def timed(fn):  # noqa: ANN001, ANN201 - a tiny local helper
    start = time.perf_counter()
    result = fn()
    return result, time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clips", type=int, default=200)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        corpus = root / "corpus"
        generate_corpus(corpus, args.clips, seed=0)
        evaluators = PretrainConfig.for_size("small", threads=1, classifier_epochs=3, classifier_size="tiny")
        fit_evaluators(corpus, root / "base", evaluators)
        overrides = [f"corpus.path={corpus}", f"output={root / 'run'}", "compute.unit_size=64"]
        config = load_run_config(REPO / "configs" / "stats-synthetic.yaml", overrides)
        execute_run(config)
        torch.set_num_threads(1)
        base = root / "base"
        evaluation, t_eval = timed(lambda: evaluate_run(config.output, base_models=base))
        _, t_scores = timed(lambda: write_scores(evaluation))
        _, t_report = timed(lambda: write_report(evaluation))
        clip = evaluation.scores[0]
        gif, t_gif = timed(lambda: preview_transfer(config.output, clip["source_id"], clip["style"], root / "p.gif"))
        bvh, t_bvh = timed(lambda: export_bvh(config.output, root / "bvh"))
        frames = sum(r["n_frames"] for r in evaluation.scores)
        print(
            json.dumps(
                {
                    "stylized_clips": len(evaluation.scores),
                    "frames": frames,
                    "evaluate_s": round(t_eval, 2),
                    "evaluate_clips_per_s": round(len(evaluation.scores) / t_eval, 1),
                    "scores_parquet_s": round(t_scores, 3),
                    "report_s": round(t_report, 2),
                    "gif_preview_s": round(t_gif, 2),
                    "gif_frames": clip["n_frames"],
                    "gif_bytes": gif.stat().st_size,
                    "bvh_export_s": round(t_bvh, 2),
                    "bvh_files": bvh.files,
                    "bvh_with_positions": bvh.with_positions,
                    "bvh_max_error_m": bvh.max_error_m,
                },
                indent=1,
            )
        )


if __name__ == "__main__":
    main()
