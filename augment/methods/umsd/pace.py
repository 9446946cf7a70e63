"""The pace a transfer should walk at: fit ``models.pace.PaceNet`` on the labelled pairs, and apply it.

UMSD's sampler keeps the content's root path by inpainting (the paper's outputs keep the content's trajectory), so
every output walks at the content's speed, where a depressed walk covers less ground than a neutral one and a
childlike one more. ``pace_steps`` > 0 fits a small regressor after the diffusion network, on the same pairs as
the ``rec`` and ``dcc`` rows (sec. 3.4): content clip + style example -> log(target's ground speed / content's).
At transfer the content's root is carried at that many times its speed (``augment.motion.tempo.paced``) before
sampling, so the style decides the pace in both directions, from the example alone. Not in the paper.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from torch import Tensor

from motionaug.augment.methods.umsd.training import NEUTRAL, UmsdData, UmsdTrainConfig
from motionaug.augment.motion.tempo import TEMPO_RANGE, ground_speed
from motionaug.models.pace import PaceNet, clip_summary

PACE_FLOOR = 0.1  # m/s added to both speeds of a ratio: clips that stand still have no pace to scale
PACE_BATCH = 256
PACE_LR = 1e-3
PACE_HIDDEN = 128


def summaries(motions: Sequence[np.ndarray]) -> Tensor:
    """(N, 2F) ``clip_summary`` of whole normalised clips."""
    rows = [clip_summary(torch.from_numpy(m).float()[None], torch.ones(1, len(m), dtype=torch.bool)) for m in motions]
    return torch.cat(rows)


def log_paces(data: UmsdData) -> np.ndarray:
    """(N,) log(ground speed + ``PACE_FLOOR``) of every clip, speeds in metres per frame."""
    speeds = np.array([ground_speed(data.normalizer.denormalize(m)) for m in data.motions])
    return np.log(speeds + PACE_FLOOR / data.fps)


def pace_rows(data: UmsdData, rng: np.random.Generator, size: int) -> np.ndarray:
    """(size, 3) rows of (target, content, style example): half ``rec``'s (the content a partner of the target in
    another style, neutral where there is one), half ``dcc``'s (content = target: its own pace, ratio 1)."""
    transfer = [i for i in range(len(data.motions)) if data.same_motion[i] and data.same_style[i]]
    own = [i for i in range(len(data.motions)) if data.same_style[i]]
    pick = lambda options: int(options[int(rng.integers(0, len(options)))])  # noqa: E731
    rows = []
    for n in range(size):
        if transfer and (n % 2 == 0 or not own):
            target = pick(transfer)
            neutral = [j for j in data.same_motion[target] if data.styles[j] == NEUTRAL]
            content = pick(neutral or data.same_motion[target])
        else:
            target = content = pick(own)
        rows.append((target, content, pick(data.same_style[target])))
    return np.array(rows, dtype=np.int64)


def fit_pace(data: UmsdData, config: UmsdTrainConfig) -> tuple[PaceNet, dict[str, float]]:
    """``config.pace_steps`` Adam steps of MSE on the log pace ratio; deterministic for the same data and seed, and
    independent of the diffusion network's training (its own generators). Returns the net and its first and final
    batch losses."""
    rng = np.random.default_rng([config.seed, 3])
    stats, paces = summaries(data.motions), torch.from_numpy(log_paces(data)).float()
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(config.seed + 3)
        net = PaceNet(stats.shape[1] // 2, PACE_HIDDEN)
    opt = torch.optim.AdamW(net.parameters(), lr=PACE_LR, weight_decay=config.weight_decay)
    losses = []
    for _ in range(config.pace_steps):
        rows = pace_rows(data, rng, PACE_BATCH)
        target = paces[rows[:, 0]] - paces[rows[:, 1]]
        loss = torch.nn.functional.mse_loss(net(stats[rows[:, 1]], stats[rows[:, 2]]), target)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        losses.append(loss.item())
    return net.eval().requires_grad_(False), {"pace_first": losses[0], "pace_final": float(np.mean(losses[-20:]))}


@torch.no_grad()
def pace_ratio(net: PaceNet, content: np.ndarray, example: Tensor) -> float:
    """The speed factor for a normalised content clip (T, F) in the style of a normalised example (Te, F),
    clamped to ``TEMPO_RANGE``."""
    c = clip_summary(torch.from_numpy(content).float()[None], torch.ones(1, len(content), dtype=torch.bool))
    s = clip_summary(example.float()[None], torch.ones(1, len(example), dtype=torch.bool))
    return float(np.clip(np.exp(float(net(c, s)[0])), *TEMPO_RANGE))
