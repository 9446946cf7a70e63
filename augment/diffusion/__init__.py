"""Diffusion math without networks: schedule, q/p formulas, DDPM/DDIM loops with inpainting and guidance hooks."""

from motionaug.augment.diffusion.gaussian import (
    DenoiseFn,
    PMeanVar,
    masked_mse,
    p_mean_variance,
    predict_eps_from_x0,
    q_mean_variance,
    q_posterior_mean_variance,
    q_sample,
    sample_timesteps,
    x0_training_loss,
)
from motionaug.augment.diffusion.samplers import (
    InpaintSpec,
    SamplerStep,
    bind_model,
    contrast_guided,
    ddim_path,
    ddim_sample,
    ddim_step,
    ddpm_sample,
    ddpm_step,
    guided_x0,
)
from motionaug.augment.diffusion.schedule import NoiseSchedule, cosine_betas, space_timesteps, start_step_for

__all__ = [
    "DenoiseFn",
    "InpaintSpec",
    "NoiseSchedule",
    "PMeanVar",
    "SamplerStep",
    "bind_model",
    "contrast_guided",
    "cosine_betas",
    "ddim_path",
    "ddim_sample",
    "ddim_step",
    "ddpm_sample",
    "ddpm_step",
    "guided_x0",
    "masked_mse",
    "p_mean_variance",
    "predict_eps_from_x0",
    "q_mean_variance",
    "q_posterior_mean_variance",
    "q_sample",
    "sample_timesteps",
    "space_timesteps",
    "start_step_for",
    "x0_training_loss",
]
