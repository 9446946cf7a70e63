"""``OnTheFlyMethod``: the method behind the workflow's contract (``augment.methods.base``).

``train``: the base models (the T2M prior, the motion encoder); ``prepare``: pairs + fine-tuning -> artefact;
``load``: artefact -> ``OnTheFlyModel``. ``prepare`` and ``load`` put the base models on ``pick_device()`` (CUDA when
present, ``$MOTIONAUG_DEVICE`` to choose); everything after runs where they are.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

from pydantic import BaseModel, ValidationError

from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.device import pick_device
from motionaug.augment.methods.base import (
    ARTIFACT_WEIGHTS,
    CostRates,
    Prepared,
    Progress,
    StyleTransferMethod,
    TrainingSpec,
    TrainProgress,
)
from motionaug.augment.methods.common import (
    configure_threads,
    place_models,
    seeded_generator,
    style_vocab,
    tensor_bytes,
    write_artifact,
)
from motionaug.augment.methods.onthefly.artifact import (
    OnTheFlyArtifact,
    base_fingerprint,
    read_artifact,
    rebuild_transfer_model,
    weights_state,
)
from motionaug.augment.methods.onthefly.finetuning import ContentPool, FitResult, finetune, make_pool, resolve_tempo
from motionaug.augment.methods.onthefly.model import OnTheFlyModel
from motionaug.augment.methods.onthefly.pairs import make_pairs
from motionaug.augment.methods.onthefly.params import (
    METHOD_NAME,
    POOL_CLIPS,
    REMOVED_HOW,
    OnTheFlyParams,
    OnTheFlyRecipe,
    recipe_of,
    validate_params,
)
from motionaug.augment.training.base_models import BASE_JSON, BaseModels
from motionaug.models.text_encoder import TextEncoder
from motionaug.schemas.errors import MotionDataError, first_error
from motionaug.schemas.styles import StyleSpec

if TYPE_CHECKING:
    from motionaug.augment.training.pretrain import PretrainConfig


def pretrain_config(spec: TrainingSpec, options: dict[str, Any]) -> PretrainConfig:
    """The size's pre-training preset plus the params' ``train`` overrides; a bad one is one line naming it."""
    from motionaug.augment.training.pretrain import PretrainConfig

    try:
        return PretrainConfig.for_size(spec.size, seed=spec.seed, **options)
    except ValidationError as err:
        field, message = first_error(err, "")
        raise MotionDataError(f"config method.params.train.{field}", message) from None
    except TypeError as err:  # a key given twice (size, seed): the run's own settings
        raise MotionDataError("config method.params.train", f"{err}; the size and seed are the run's") from None


class OnTheFlyMethod(StyleTransferMethod):
    """``prepare``: pair generation + fine-tuning -> artefact; ``load``: artefact -> ``OnTheFlyModel``."""

    name: ClassVar[str] = METHOD_NAME
    Params: ClassVar[type[BaseModel]] = OnTheFlyParams
    params: OnTheFlyRecipe
    trains: ClassVar[bool] = True
    cost_rates: ClassVar[CostRates] = CostRates(prepare_s=25.0, transfer_clips_per_s=26.3, train_s=800.0)

    def content_clips(self) -> int:
        """The clips the semantic loss L_s draws from (paper sec. 3.4: "motions from the dataset")."""
        return POOL_CLIPS

    smoke_params: ClassVar[dict[str, Any]] = {"max_steps": 2, "pair_steps": 10, "batch_size": 4}
    removed_params: ClassVar[dict[str, str]] = REMOVED_HOW
    path_params: ClassVar[tuple[str, ...]] = ("train.from_mdm", "train.clip_weights", "train.mdm_stats")

    def __init__(
        self, params: OnTheFlyParams | dict[str, Any] | None = None, text_encoder: TextEncoder | None = None
    ) -> None:
        super().__init__(params)
        self.params: OnTheFlyRecipe = recipe_of(self.params)  # the recipe-only settings at the product's defaults
        self.text_encoder = text_encoder

    @classmethod
    def parse_params(cls, raw: Any) -> OnTheFlyParams:
        """Pydantic's field checks, then the ranges across fields (``validate_params``)."""
        return validate_params(super().parse_params(raw))  # type: ignore[arg-type]

    # ---- once per run: the base models (the T2M prior, the motion encoder) --------------------------------

    def check_training(self, spec: TrainingSpec) -> None:
        pretrain_config(spec, self.params.train)

    def is_trained(self, folder: Path) -> bool:
        return (Path(folder) / BASE_JSON).is_file()

    def train(self, corpus: Path, out: Path, spec: TrainingSpec, progress: TrainProgress | None = None) -> Path:
        """Pre-train the base models on ``corpus`` into ``out`` (reused when ``out`` holds matching ones)."""
        from motionaug.augment.training.pretrain import ensure_base_models

        config = pretrain_config(spec, self.params.train)
        return ensure_base_models(corpus, out, config.size, config.seed, progress, config)

    # ---- once per style: pairs + fine-tuning -> artefact ---------------------------------------------------

    def fit(
        self,
        style: StyleSpec,
        examples: Sequence[MotionClip],
        base: BaseModels,
        corpus: Sequence[MotionClip],
        seed: int | None = None,
        progress: Progress | None = None,
    ) -> tuple[OnTheFlyModel, FitResult, ContentPool, int]:
        """Everything ``prepare`` does except writing: (loaded model, fit result, L_s pool, clips skipped)."""
        if not examples:
            raise MotionDataError(f"style {style.name!r}", "no example clips")
        # a caller's seed (the workflow's per-style seed) wins over the params'
        params = self.params if seed is None else self.params.model_copy(update={"seed": seed})
        generator = seeded_generator(params.seed)
        start = time.perf_counter()
        vocab = style_vocab(style.words, style.name)
        pairs = make_pairs(base, examples, params, generator, vocab)
        tempo, fit_note = resolve_tempo(params, base, examples, corpus, vocab)
        pool, skipped = make_pool(base, corpus, style, params, generator, tempo)  # also sets steps when lambda_s=0
        prep_s = time.perf_counter() - start
        fit = finetune(base, pairs, pool, params, progress)
        fit.timings["pairs_and_pool_s"] = prep_s
        fit.tempo_note = fit_note
        return OnTheFlyModel(style, base, fit.model, params, tempo=tempo), fit, pool, skipped

    def prepare_style(
        self,
        style: StyleSpec,
        examples: Sequence[MotionClip],
        trained: Path | None,
        content: Sequence[MotionClip],
        out: Path,
        seed: int | None,
        progress: Progress | None,
    ) -> Prepared:
        """Pairs + fine-tuning from the base models in ``trained``; ``content`` is the semantic loss's pool."""
        assert trained is not None  # checked by ``prepare``
        configure_threads()
        base = place_models(BaseModels.load(trained, text_encoder=self.text_encoder), pick_device())
        model, fit, pool, skipped = self.fit(style, examples, base, content, seed, progress)
        return self.save(Path(out), Path(trained), model, fit, pool, skipped)

    def save(
        self, out_dir: Path, base_dir: Path, model: OnTheFlyModel, fit: FitResult, pool: ContentPool, skipped: int
    ) -> Prepared:
        """Write ``weights.safetensors`` (adapters only for LoRA) and ``artifact.json`` (written last)."""
        weights = weights_state(fit.model, model.params)
        info = OnTheFlyArtifact(
            style=model.spec,
            params=model.params,
            base_fingerprint=base_fingerprint(base_dir),
            weights="lora" if model.params.lora_rank > 0 else "full",
            weights_bytes=tensor_bytes(weights),
            full_model_bytes=tensor_bytes(model.base.prior.state_dict()),
            trainable_parameters=sum(t.numel() for t in weights.values()),
            pool_clips=len(pool),
            pool_skipped=skipped,
            tempo=model.tempo,
            tempo_note=fit.tempo_note,
            loss_curve=[{k: v for k, v in point.items() if k != "seconds"} for point in fit.curve],
        )
        write_artifact(out_dir, info, weights)
        return Prepared(out_dir, {**fit.timings, "curve_seconds": [point.get("seconds") for point in fit.curve]})

    # ---- per worker: artefact -> loaded style ----------------------------------------------------------------

    def load(self, artifact: Path, trained: Path | None) -> OnTheFlyModel:
        return self.load_tuned(artifact, trained)

    def load_tuned(
        self, artifact: Path, trained: Path | None, *, merge: bool = False, bf16: bool | None = None
    ) -> OnTheFlyModel:
        """``load`` with serving choices: ``merge`` folds LoRA adapters into the weights (faster, not
        bit-identical); ``bf16`` overrides the artefact's autocast choice (None: the artefact's)."""
        if trained is None:
            raise MotionDataError(f"{METHOD_NAME} load", "needs base models (the train step's folder)")
        artifact_dir, base_dir = Path(artifact), Path(trained)
        configure_threads()
        info = read_artifact(artifact_dir)
        found = base_fingerprint(base_dir)
        if found != info.base_fingerprint:
            raise MotionDataError(
                str(artifact_dir), f"tuned from base models {info.base_fingerprint}, {base_dir} is {found}"
            )
        base = place_models(BaseModels.load(base_dir, text_encoder=self.text_encoder), pick_device())
        model = rebuild_transfer_model(base, info, artifact_dir / ARTIFACT_WEIGHTS, merge)
        params = info.params if bf16 is None else info.params.model_copy(update={"bf16": bf16})
        return OnTheFlyModel(info.style, base, model, params, None, tempo=info.tempo)
