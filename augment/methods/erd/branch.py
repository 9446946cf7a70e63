"""A style Style-ERD was not trained on, learnt from k examples: one new residual branch, fitted alone.

The paper trains a branch per style of a labelled corpus, all jointly (sec. 3.1-3.2). A style met later gets
``ErdNetwork.with_style``'s new branch, fitted with every trained part frozen but that branch and the decoder's
column for the style. The losses are training's own (``training.py``), with the examples standing in for the
style's class: the moment loss against each example's change from its reference (the pool clip whose root moves
most like it, the output shapers' rule), Eq. 7's perceptual loss on the frozen content classifier, and Eq. 4 against
the trained FT-Att critic, which goes on training (Eqs. 5-6) with the examples' windows as the style's real ones.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field
from torch import Tensor

from motionaug.augment.methods.shaping import nearest_root_motion
from motionaug.models.style_erd import ContentClassifier, ErdNetwork, FtAttDiscriminator
from motionaug.schemas.errors import MotionDataError

BRANCH_FILE = "branch.safetensors"
BRANCH_KEYS = ("w_ih", "w_hh", "bias", "h0", "c0", "decoder_target")


class ErdBranchFit(BaseModel):
    """How a new style's branch is fitted (``method.params.branch``); steps are fixed, never a time cap."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    steps: int = Field(400, ge=1, description="branch and critic updates per new style (chosen on LSO val)")
    batch_size: int = Field(16, ge=2, description="content windows per step")
    lr: float = Field(3e-3, gt=0, description="Adam on the branch; training's generator rate")
    lr_discriminator: float = Field(5e-4, gt=0, description="Adam on the critic; training's rate")
    w_moments: float = Field(1.0, ge=0, description="moment loss against the examples' change from their references")
    w_per: float = Field(1.0, ge=0, description="Eq. 7, content features kept")
    w_adv: float = Field(0.1, ge=0, description="Eq. 4, against the critic")
    w_gp: float = Field(0.5, ge=0, description="Eq. 6 on the examples' windows")
    pool_clips: int = Field(64, ge=1, description="content clips of the run's pool: windows and references")


def branch_tensors(net: ErdNetwork) -> dict[str, Tensor]:
    """The last style's own weights: its branch's stacked slices, initial states and decoder target column."""
    rec, cfg = net.recurrent, net.config
    column = cfg.latent + cfg.n_styles - 1
    return {
        "w_ih": rec.w_ih[:, -1],
        "w_hh": rec.w_hh[:, -1],
        "bias": rec.bias[:, -1],
        "h0": rec.h0_style[:, -1],
        "c0": rec.c0_style[:, -1],
        "decoder_target": net.decoder.layers[0].weight[:, column],
    }


def apply_branch(net: ErdNetwork, name: str, tensors: dict[str, Tensor]) -> ErdNetwork:
    """``net`` grown by style ``name`` with a fitted branch's weights (``branch_tensors`` of the fit)."""
    missing = sorted(set(BRANCH_KEYS) - set(tensors))
    if missing:
        raise MotionDataError(f"style {name!r} branch", f"missing weights {missing}")
    grown = net.with_style(name)
    with torch.no_grad():
        for key, slot in branch_tensors(grown).items():
            if tuple(tensors[key].shape) != tuple(slot.shape):
                reason = f"{key} has shape {tuple(tensors[key].shape)}, the network wants {tuple(slot.shape)}"
                raise MotionDataError(f"style {name!r} branch", reason)
            slot.copy_(tensors[key])
    return grown.eval()


def _windows(motions: Sequence[np.ndarray], length: int, count: int, rng: np.random.Generator) -> Tensor:
    rows = []
    for i in rng.integers(0, len(motions), size=count):
        motion = motions[int(i)]
        start = int(rng.integers(0, len(motion) - length + 1))
        rows.append(motion[start : start + length])
    return torch.from_numpy(np.stack(rows))


def _sub_windows(x: Tensor, length: int, stride: int) -> Tensor:
    return x.unfold(1, length, stride).permute(0, 1, 3, 2).reshape(-1, length, x.shape[-1])


def moment_targets(
    net: ErdNetwork, examples: Sequence[np.ndarray], pool: dict[str, np.ndarray]
) -> tuple[Tensor, Tensor]:
    """Mean over the examples of each one's per-channel change in mean and std over time from its reference,
    in the network's normalised units: the class averages' change of training's moment loss, from k clips."""
    mean, std = net.mean.numpy(), net.std.numpy()
    d_mu, d_sd = [], []
    for example in examples:
        reference = nearest_root_motion(example, pool)[1]
        e, r = (example - mean) / std, (reference - mean) / std
        d_mu.append(e.mean(0) - r.mean(0))
        d_sd.append(e.std(0) - r.std(0))
    return torch.from_numpy(np.mean(d_mu, 0).astype(np.float32)), torch.from_numpy(np.mean(d_sd, 0).astype(np.float32))


def fit_branch(
    net: ErdNetwork,
    critics: dict[str, Tensor],
    name: str,
    examples: Sequence[np.ndarray],
    pool: dict[str, np.ndarray],
    fit: ErdBranchFit,
    window: int,
    disc_stride: int,
    seed: int,
) -> tuple[ErdNetwork, list[dict[str, float]]]:
    """``net`` grown by ``name`` with its branch fitted on raw (T, 263) ``examples`` and content ``pool`` clips;
    ``critics``: the trained folder's critic weights. Returns the network (eval) and the loss history (every
    ``steps // 5`` steps). Same inputs and threads, same weights."""
    cfg_net = net.config
    usable = [m for m in pool.values() if len(m) >= window]
    if not usable:
        raise MotionDataError(f"style {name!r} branch fit", f"no content clip has the {window} frames of a window")
    grown = net.with_style(name).train()
    cfg = grown.config
    critic = FtAttDiscriminator(cfg_net)
    classifier = ContentClassifier(cfg_net)
    try:
        critic.load_state_dict(
            {k[len("discriminator.") :]: v for k, v in critics.items() if k.startswith("discriminator.")}
        )
        classifier.load_state_dict(
            {k[len("classifier.") :]: v for k, v in critics.items() if k.startswith("classifier.")}
        )
    except RuntimeError as err:
        raise MotionDataError("Style-ERD critics", f"unreadable ({str(err).splitlines()[0]})") from None
    critic = critic.with_style(cfg)
    classifier.requires_grad_(False).eval()
    mean, std = net.mean.numpy(), net.std.numpy()
    contents = [((m - mean) / std).astype(np.float32) for m in usable]
    styled = [((m - mean) / std).astype(np.float32) for m in examples]
    d_mu, d_sd = moment_targets(net, examples, pool)

    grown.requires_grad_(False)
    rec, column = grown.recurrent, cfg.latent + cfg.n_styles - 1
    trained = [rec.w_ih, rec.w_hh, rec.bias, rec.h0_style, rec.c0_style, grown.decoder.layers[0].weight]
    for p in trained:
        mask = torch.zeros_like(p)
        if p is grown.decoder.layers[0].weight:
            mask[:, column] = 1.0
        else:
            mask[:, -1] = 1.0
        p.requires_grad_(True)
        p.register_hook(lambda g, m=mask: g * m)  # Adam leaves a parameter whose gradient is always 0 as it is
    opt_g = torch.optim.Adam(trained, lr=fit.lr)
    opt_d = torch.optim.Adam(critic.parameters(), lr=fit.lr_discriminator)
    rng = np.random.default_rng([seed, 11])
    rows = fit.batch_size
    source = grown.style_onehot(torch.zeros(rows, dtype=torch.long))
    unknown = grown.content_onehot(torch.full((rows,), cfg.unknown_content, dtype=torch.long))
    target = grown.style_onehot(torch.full((rows,), cfg.n_styles - 1, dtype=torch.long))
    dw = cfg.disc_window

    def judged(x: Tensor) -> Tensor:
        n = x.shape[0]
        return critic(x, target[:1].expand(n, -1), unknown[:1].expand(n, -1))

    history: list[dict[str, float]] = []
    every = max(1, fit.steps // 5)
    window_sums: dict[str, float] = {}
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        for step in range(fit.steps):
            x = _windows(contents, window, rows, rng)
            fake, _ = grown(x, source, unknown, target, skip_idle=True)
            fake_windows = _sub_windows(fake, dw, disc_stride)
            real = _windows(styled, dw, fake_windows.shape[0], rng).requires_grad_(True)
            d_real = judged(real)
            cri = (d_real - 1).pow(2).mean() + (judged(fake_windows.detach()) + 1).pow(2).mean()
            (grad,) = torch.autograd.grad(d_real.sum(), real, create_graph=True)
            opt_d.zero_grad(set_to_none=True)
            (cri + fit.w_gp * grad.pow(2).sum(dim=(1, 2)).mean()).backward()
            opt_d.step()

            critic.requires_grad_(False)
            adv = judged(fake_windows).pow(2).mean()
            critic.requires_grad_(True)
            per = (classifier.features(fake) - classifier.features(x)).pow(2).mean()
            mom = ((fake.mean(1) - x.mean(1)) - d_mu).pow(2).mean() + ((fake.std(1) - x.std(1)) - d_sd).pow(2).mean()
            loss = fit.w_moments * mom + fit.w_per * per + fit.w_adv * adv
            opt_g.zero_grad(set_to_none=True)
            loss.backward()
            opt_g.step()
            values = {"moments": mom.item(), "per": per.item(), "adv": adv.item(), "cri": cri.item()}
            if not all(np.isfinite(v) for v in values.values()):
                raise MotionDataError(f"style {name!r} branch fit", f"non-finite loss at step {step + 1}: {values}")
            for key, value in values.items():
                window_sums[key] = window_sums.get(key, 0.0) + value
            if (step + 1) % every == 0 or step + 1 == fit.steps:
                count = step % every + 1
                history.append({"step": float(step + 1)} | {k: v / count for k, v in window_sums.items()})
                window_sums = {}
    grown.requires_grad_(False)
    return grown.eval(), history
