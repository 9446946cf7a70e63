"""Does a trained UMSD network use its noisy input? The diagnosis of bench/RESULTS.md section 13.3.

Usage: python bench/bench_umsd_xt.py --model MODEL_DIR --corpus BANDAI2 [--clip ID] [--example ID]

For one content clip and one style example (default: the first `normal` val clip, the first train `elderly` walk):
the prediction's mean absolute change when x_t is swapped for another clip's x_t at the same t, and the
prediction's error against the content at t = 10, 100, 500 (x_t noised from the content). A network that denoises
changes its prediction with x_t and errs less at small t; one that copies its conditions does neither.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_umsd_quality import load_clips, splits  # noqa: E402

from motionaug.augment.diffusion import NoiseSchedule, q_sample  # noqa: E402
from motionaug.augment.methods.umsd import load_umsd  # noqa: E402
from motionaug.augment.methods.umsd.training import x0_from_output  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--model", type=Path, required=True)
    parser.add_argument("--corpus", type=Path, required=True)
    args = parser.parse_args()
    torch.set_num_threads(1)
    torch.manual_seed(0)
    clips, parts = load_clips(args.corpus), splits(args.corpus)
    sources = [clips[i] for i in parts["val"] if clips[i].style == "normal"][:2]
    example = next(
        clips[i] for i in sorted(parts["train"]) if clips[i].style == "elderly" and clips[i].content == "walk"
    )
    model = load_umsd(args.model)
    as_tensor = lambda m: torch.from_numpy(model.normalizer.normalize(m[:96]).astype(np.float32))[None]  # noqa: E731
    content, other, style = as_tensor(sources[0].motion), as_tensor(sources[1].motion), as_tensor(example.motion)
    other = other[:, : content.shape[1]]
    schedule = NoiseSchedule.cosine()

    def predict(x_t: torch.Tensor, step: torch.Tensor) -> torch.Tensor:
        out = model.net(x_t, step, content, None, style, None)
        return x0_from_output(model.info.train.skip, schedule, x_t, step, out, model.skip_prior, content)

    with torch.no_grad():
        for t in (10, 100, 500):
            step = torch.tensor([t])
            own = predict(q_sample(schedule, content, step, torch.randn_like(content)), step)
            swapped = predict(q_sample(schedule, other, step, torch.randn_like(other)), step)
            print(
                f"t={t}: change when x_t is swapped {(own - swapped).abs().mean().item():.3f}, "
                f"error against the content {(own - content).abs().mean().item():.3f}"
            )


if __name__ == "__main__":
    main()
