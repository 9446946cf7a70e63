"""On-the-fly style transfer by fine-tuning a diffusion prior (Hu, Zhang, Ye, Xu, Xia, CGF 2024).

Learning a style from one (or a few) example clips, paper sections 3.2-3.5:

1. Style-neutral pair (Eqs. 3-5): noise the example to step G and denoise it with the *prior* (DDPM) conditioned
   on the neutral description, inpainting the example's root trajectory at every step. The result m_sn does
   what the example does, on the same path, without the style.
2. Fine-tuning: a copy of the prior (all of it, or LoRA adapters) learns m_sn -> m_s along the deterministic DDIM
   path from step K (L_rec), while a semantic loss L_s keeps corpus motions it transfers close to their
   style-revised captions in the motion-text space (the motion encoder and text encoder stay frozen).
3. Transfer (sec. 3.5.2): noise a content clip to K and DDIM-denoise it with the transfer model conditioned on
   its revised caption, keeping the content's root trajectory by inpainting (sec. 7.1).

Beyond the paper: the transfer keeps the content's clock, but styles change tempo (a depressed walk cycles slower).
By default the style's tempo is measured from its examples against neutral corpus clips described alike
(``augment.motion.tempo``) and content clips are retimed to it before the transfer (and in the L_s pool, so the model
is tuned on what it will see); ``tempo="content"`` keeps the paper's behaviour.

Everything runs in the normalised feature space of the base models (``BaseModels.normalizer``).

The package, by concern: ``params`` (the knobs and their checks), ``pairs`` (step 1 and the inpainted channels),
``finetuning`` (step 2: losses, trainable selection, the L_s pool, the tempo), ``model`` (step 3: the loaded style),
``artifact`` (what ``prepare`` writes and ``load`` reads), ``method`` (``OnTheFlyMethod``, the workflow's contract).
What other diffusion methods share lives in ``augment.methods.common``.
"""

from motionaug.augment.methods.common import (
    MAX_TEMPO_CANDIDATES,
    THREADS_ENV,
    MotionBatch,
    carries_style,
    clip_noise,
    configure_threads,
    longest_frames,
    neutral_text,
    retimed,
    revised_texts,
    seeded_generator,
    style_vocab,
    tempo_references,
    tensor_bytes,
    trajectory_channels,
)
from motionaug.augment.methods.onthefly.artifact import (
    OnTheFlyArtifact,
    base_fingerprint,
    read_artifact,
    rebuild_transfer_model,
    weights_state,
)
from motionaug.augment.methods.onthefly.finetuning import (
    LORA_OUTPUT_LAYERS,
    ContentPool,
    FitResult,
    WeightAverage,
    finetune,
    make_pool,
    reconstruction_loss,
    resolve_tempo,
    semantic_guidance_loss,
    transferred_path_end,
)
from motionaug.augment.methods.onthefly.method import OnTheFlyMethod, pretrain_config
from motionaug.augment.methods.onthefly.model import OnTheFlyModel
from motionaug.augment.methods.onthefly.pairs import StylePairs, kept_channels, make_pairs, neutral_twins
from motionaug.augment.methods.onthefly.params import (
    METHOD_NAME,
    POOL_CLIPS,
    OnTheFlyParams,
    OnTheFlyRecipe,
    parse_params,
    recipe_of,
    validate_params,
)

__all__ = [
    "LORA_OUTPUT_LAYERS",
    "MAX_TEMPO_CANDIDATES",
    "METHOD_NAME",
    "POOL_CLIPS",
    "THREADS_ENV",
    "ContentPool",
    "FitResult",
    "MotionBatch",
    "OnTheFlyArtifact",
    "OnTheFlyMethod",
    "OnTheFlyModel",
    "OnTheFlyParams",
    "OnTheFlyRecipe",
    "StylePairs",
    "WeightAverage",
    "base_fingerprint",
    "carries_style",
    "clip_noise",
    "configure_threads",
    "finetune",
    "kept_channels",
    "longest_frames",
    "make_pairs",
    "make_pool",
    "neutral_text",
    "neutral_twins",
    "parse_params",
    "pretrain_config",
    "read_artifact",
    "recipe_of",
    "rebuild_transfer_model",
    "reconstruction_loss",
    "resolve_tempo",
    "retimed",
    "revised_texts",
    "seeded_generator",
    "semantic_guidance_loss",
    "style_vocab",
    "tempo_references",
    "tensor_bytes",
    "trajectory_channels",
    "transferred_path_end",
    "validate_params",
    "weights_state",
]
