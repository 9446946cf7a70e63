"""On-the-fly style transfer by fine-tuning a diffusion prior (Hu, Zhang, Ye, Xu, Xia, CGF 2024, secs. 3.2-3.5).

1. Style-neutral pair (Eqs. 3-5): the example noised to G and denoised by the prior on the neutral description, its
root trajectory inpainted. 2. Fine-tuning: a copy of the prior (or LoRA adapters) learns m_sn -> m_s along the DDIM
path from K (L_rec) while L_s keeps transferred corpus motions near their revised captions. 3. Transfer: a content
clip noised to K and denoised by the tuned model, its root trajectory inpainted. Beyond the paper, content is
retimed to the style's tempo measured from its examples (``tempo="content"``: the paper's clock). Modules:
``params``, ``pairs`` (step 1), ``finetuning`` (step 2), ``model`` (step 3), ``artifact``, ``method`` (the
workflow's contract); what diffusion methods share is in ``augment.methods.common``. Notes: docs/internals.md.
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
