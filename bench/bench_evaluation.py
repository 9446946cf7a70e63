"""Cost of looking at a run: ``evaluate`` (per-clip scores + report), one GIF preview, BVH export.

Builds a ``stats`` run on a synthetic corpus in-process (no Ray) and tiny classifiers, then times each
step on one CPU thread. Results go to stdout as JSON.

    .venv/bin/python bench/bench_evaluation.py --clips 200
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))


def timed(fn):  # noqa: ANN001, ANN201 - a tiny local helper
    start = time.perf_counter()
    result = fn()
    return result, time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clips", type=int, default=200)
    args = parser.parse_args()
    torch.set_num_threads(1)
    from fixtures.evaluation.tiny_run import build_base_models, build_run, make_corpus

    from motionaug.augment.eval.evaluation import evaluate_run, preview_transfer, write_scores
    from motionaug.augment.eval.report import write_report
    from motionaug.augment.motion.bvh_export import export_bvh

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        corpus = make_corpus(root / "corpus", args.clips)
        config = build_run(corpus, root / "run", unit_size=64)
        base = build_base_models(corpus, root / "base", epochs=3)
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
