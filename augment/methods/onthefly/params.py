"""The method's parameters: every knob, their range checks, and how many content clips ``prepare`` learns from."""

from __future__ import annotations

from typing import Any, Literal, TypeVar

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from motionaug.augment.diffusion.schedule import NUM_TRAIN_TIMESTEPS
from motionaug.augment.methods.hooks import HookSpec, LossTerms, sampler_callbacks
from motionaug.augment.motion.tempo import TEMPO_RANGE
from motionaug.models.lora import DEFAULT_TARGETS as LORA_TARGETS
from motionaug.schemas.errors import MotionDataError, first_error

METHOD_NAME = "onthefly"

POOL_CLIPS = 256
"""Content clips the semantic loss draws from (paper sec. 3.4: "motions from the dataset"), chosen by the plan."""


PAIR_GUIDANCE_SCALE = 2.5
"""Classifier-free guidance of the neutral twin (pair generation)."""
REMOVED = {  # settings that left the params, with the default every artefact made before holds
    "pair_guidance_scale": 2.5,
    "transfer_guidance_scale": None,
    "style_guidance_reference": "neutral",
    "neutralise_content": True,
}
REMOVED_HOW = {name: f"fixed at {default!r} (set by no config); drop the setting" for name, default in REMOVED.items()}
RECIPE_ONLY = ("inpaint_feet", "lora_biases", "ema_decay", "tempo_references", "styled_corpus")
REMOVED_HOW |= {
    name: "fixed at its default in the product; experiments set it on OnTheFlyRecipe (lab/README.md); drop the setting"
    for name in RECIPE_ONLY
}


class OnTheFlyParams(BaseModel):
    """What a user sets: the paper's hyper-parameters and what the shipped configs use; ``extra="forbid"`` so a typo
    in a config is an error, not a default."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    version: int = 1
    pair_noise_step: int = Field(950, description="G: training timestep the example is noised to for its neutral twin.")
    pair_steps: int = Field(
        100, description="DDPM steps of pair generation (respaced; 1000 = unspaced as the paper, ~10x slower on CPU)."
    )
    transfer_noise_step: int = Field(
        300, description="K: training timestep content is noised to (fine-tune and transfer)."
    )
    ddim_steps: int = Field(20, description="S: DDIM steps of the whole process (K=300 of 1000 runs 6 of 20).")
    style_guidance: float | None = Field(
        None,
        description="w: transfer with x0 = x0_base + w (x0_tuned - x0_base), the base prior on the content's neutral "
        "caption, the tuned model on the revised one (augment.diffusion.contrast_guided); above 1 pushes further "
        "along what the fine-tune learnt, for subtle styles; None = the tuned model alone (the paper).",
    )
    trajectory: Literal["horizontal", "root"] = Field(
        "horizontal", description="Inpainted channels: root rotation + linear velocity, or also the root height."
    )
    foot_lock: bool = Field(
        False,
        description="Correct each output's root steps so a planted toe does not slide (augment.motion.foot_lock): "
        "the body travels what its stylized legs walk, so the content's path is no longer kept exactly.",
    )
    lambda_rec: float = 1.0
    lambda_s: float = 0.1
    lr: float = 1e-4
    grad_clip: float | None = 1.0
    epochs: int = Field(1, description="Passes over the corpus pool of L_s (ignored when max_steps is set).")
    max_steps: int | None = None
    batch_size: int = 8
    lora_rank: int = Field(
        0,
        description="0: full fine-tune; >0: LoRA adapters on lora_targets (they start at zero: give them a larger "
        "lr and alpha, but not more passes, which memorise the example; configs/onthefly-lora-synthetic.yaml is the "
        "shipped recipe).",
    )
    lora_alpha: float | None = Field(None, description="LoRA scale numerator; defaults to the rank.")
    lora_targets: tuple[str, ...] = Field(
        LORA_TARGETS, description="Modules given adapters, by their last name components (models.lora)."
    )
    caption_variants: int = 3
    tempo: Literal["example", "content"] | float = Field(
        "example",
        description="Clock of the outputs: 'example' retimes content to the style's tempo measured from its "
        "examples (augment.motion.tempo); 'content' keeps the content's clock (the paper); a number sets it "
        "(below 1: slower).",
    )
    callbacks: list[HookSpec] = Field(
        default_factory=list,
        description="Sampler callbacks by name (augment.methods.hooks) called on every transfer step's x0 prediction, "
        "in order; none by default.",
    )
    loss_terms: LossTerms = Field(
        (),
        description="Fine-tuning loss terms by name (augment.methods.hooks), with weights, on L_rec's last x0 against "
        "the style example; none by default.",
    )
    train: dict[str, Any] = Field(
        default_factory=dict,
        description="The base models' pre-training: overrides of the size's preset (augment.training.pretrain's "
        "PretrainConfig), e.g. prior_steps, or from_mdm/clip_weights/mdm_stats to import an official MDM prior.",
    )
    min_frames: int = 20
    bf16: bool | None = Field(
        None, description="bf16 autocast; None = on CUDA (tensor cores) and on CPUs with bf16 units, else fp32."
    )
    seed: int = 0

    @field_validator("callbacks")
    @classmethod
    def _known_callbacks(cls, specs: list[HookSpec]) -> list[HookSpec]:
        return sampler_callbacks.checked(specs)

    @model_validator(mode="before")
    @classmethod
    def _older_artefacts(cls, data: Any) -> Any:
        """An artefact made before a setting left holds it at its default: dropped; any other value is an error."""
        if isinstance(data, dict) and any(name in data for name in REMOVED):
            data = dict(data)
            for name, default in REMOVED.items():
                if name in data and data.pop(name) != default:
                    raise ValueError(f"{name} was removed: {REMOVED_HOW[name]}")
        return data


class OnTheFlyRecipe(OnTheFlyParams):
    """The product's params plus settings only experiments change, at the defaults the product runs with: the
    method turns every ``OnTheFlyParams`` into one, and artefacts store it, so a lab variant's artefact says how it
    was made."""

    inpaint_feet: bool = Field(
        False, description="Also inpaint the foot-contact channels (pairs and transfer keep the gait's phase)."
    )
    lora_biases: bool = Field(
        False,
        description="LoRA: also train the biases of the adapted layers and of the output layer (BitFit): "
        "shifts a style holds over the whole clip cost low-rank deltas rank, a bias carries them.",
    )
    ema_decay: float | None = Field(
        None, description="Keep an exponential moving average of the trained weights and ship it (None: the last step)."
    )
    tempo_references: int = Field(
        16,
        description="Neutral corpus clips (captions nearest the examples' neutral descriptions) giving the neutral "
        "cycle.",
    )
    styled_corpus: Literal["skip", "neutralise"] = Field(
        "skip",
        description="L_s pool: drop corpus clips whose captions name a style, or neutralise them (slow: DDPM from G).",
    )


P = TypeVar("P", bound=OnTheFlyParams)


def _fail(field: str, reason: str) -> MotionDataError:
    return MotionDataError(f"config method.params.{field}", f"{METHOD_NAME}: {reason}")


def validate_params(params: P, num_timesteps: int = NUM_TRAIN_TIMESTEPS) -> P:
    """Range checks across fields, each failing with the field's name (pydantic only checks types)."""
    for name in ("pair_noise_step", "transfer_noise_step"):
        value = getattr(params, name)
        if not 0 < value <= num_timesteps:
            raise _fail(name, f"{value} outside (0, {num_timesteps}]")
    for name in ("pair_steps", "ddim_steps"):
        value = getattr(params, name)
        if not 1 <= value <= num_timesteps:
            raise _fail(name, f"{value} outside [1, {num_timesteps}]")
    positive = {
        "lr": params.lr,
        "epochs": params.epochs,
        "batch_size": params.batch_size,
        "caption_variants": params.caption_variants,
    }
    for name, value in positive.items():
        if not value > 0:
            raise _fail(name, f"must be > 0, got {value}")
    for name in ("lambda_rec", "lambda_s"):
        if not getattr(params, name) >= 0:
            raise _fail(name, f"must be >= 0, got {getattr(params, name)}")
    if params.lambda_rec == 0 and params.lambda_s == 0:
        raise _fail("lambda_rec", "lambda_rec and lambda_s are both 0: nothing to learn")
    if params.max_steps is not None and params.max_steps < 1:
        raise _fail("max_steps", f"must be >= 1, got {params.max_steps}")
    if params.style_guidance is not None and params.style_guidance <= 0:
        raise _fail("style_guidance", f"must be > 0 or null, got {params.style_guidance}")
    if params.lora_rank < 0:
        raise _fail("lora_rank", f"must be >= 0, got {params.lora_rank}")
    if params.lora_rank > 0 and not params.lora_targets:
        raise _fail("lora_targets", "empty: LoRA needs at least one module to adapt")
    if params.min_frames < 2:
        raise _fail("min_frames", f"must be >= 2, got {params.min_frames}")
    if params.grad_clip is not None and params.grad_clip <= 0:
        raise _fail("grad_clip", f"must be > 0 or null, got {params.grad_clip}")
    if isinstance(params.tempo, float) and not TEMPO_RANGE[0] <= params.tempo <= TEMPO_RANGE[1]:
        raise _fail("tempo", f"{params.tempo} outside [{TEMPO_RANGE[0]}, {TEMPO_RANGE[1]}]")
    if isinstance(params, OnTheFlyRecipe):
        if params.ema_decay is not None and not 0.0 < params.ema_decay < 1.0:
            raise _fail("ema_decay", f"{params.ema_decay} outside (0, 1)")
        if params.tempo_references < 1:
            raise _fail("tempo_references", f"must be >= 1, got {params.tempo_references}")
    return params


def parse_params(data: dict[str, Any] | None = None, **overrides: Any) -> OnTheFlyRecipe:
    """The recipe the method runs from a dict (a config file) plus overrides, validated; errors name the field.
    Recipe-only settings are accepted here (experiments, tests), not in a run config."""
    from motionaug.augment.methods.onthefly.method import OnTheFlyMethod  # the method imports these params

    raw = {**(data or {}), **overrides}
    lab = {name: raw.pop(name) for name in RECIPE_ONLY if name in raw}
    return recipe_of(OnTheFlyMethod.parse_params(raw), **lab)


def recipe_of(params: OnTheFlyParams, **lab: Any) -> OnTheFlyRecipe:
    """``params`` as the recipe the method runs: the product's settings, the recipe-only ones at their defaults
    unless ``lab`` sets them."""
    if isinstance(params, OnTheFlyRecipe) and not lab:
        return params
    try:
        recipe = OnTheFlyRecipe.model_validate({**params.model_dump(), **lab})
    except ValidationError as err:
        where, message = first_error(err, "")
        raise MotionDataError(f"config method.params.{where}".rstrip("."), f"{METHOD_NAME}: {message}") from None
    return validate_params(recipe)
