"""Style-ERD behind the method contract: trained once per run on a labelled style corpus, no per-style learning.

``train`` fits the network on the train split of the labelled corpus (all of it without split files) and is
reused while the corpus and the training config match; ``check_style`` refuses, before Ray starts, a style the
network has not learnt; ``prepare`` records the style; ``load`` + ``transfer`` stylize whole clips offline with
the recurrent layers run over each sequence at once (``motionaug stream`` runs the same network frame by frame).
Content clips reach the network without their labels: read as neutral (supp. C.4) with the learned
unknown-content initial state, so a corpus without labels and a scored clip are treated alike.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any, ClassVar

from pydantic import BaseModel, ConfigDict, Field

from motionaug.augment.corpus import MotionClip, Reject
from motionaug.augment.corpus.humanml3d import read_labels
from motionaug.augment.methods.base import (
    ARTIFACT_JSON,
    CostRates,
    Progress,
    StyleModel,
    TrainingSpec,
    TransferOutput,
)
from motionaug.augment.methods.common import (
    CorpusTrainedMethod,
    revised_texts,
    style_vocab,
)
from motionaug.augment.methods.erd.stream import transfer
from motionaug.augment.methods.erd.training import ErdTrain, ErdTrainConfig, load_erd, read_artifact, train_erd
from motionaug.models.style_erd import NEUTRAL, ErdNetwork
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.styles import StyleSpec

METHOD_NAME = "erd"


NETWORK = "the network's size is the run's base_models.size (tiny, small, paper); drop the setting"
FIXED = "fixed at its default; the lab sets it on ErdTrainConfig (lab/README.md); drop the setting"
REMOVED_TRAIN = {
    **{f"train.{n}": NETWORK for n in ("latent", "enc_hidden", "neutral_layers", "style_layers", "dec_hidden")},
    **{f"train.{n}": NETWORK for n in ("disc_channels", "cls_channels", "classifier_steps", "classifier_batch_size")},
    **{f"train.{n}": FIXED for n in ("disc_stride_s", "lr_classifier", "w_style", "w_moments", "neutral_share")},
    **{f"train.{n}": FIXED for n in ("content_dropout", "residual_output", "threads")},
    "train.seed": "the run's seed trains the network; drop the setting",
    "seed": "Style-ERD's transfer draws no noise; drop the setting",
}


class ErdParams(BaseModel):
    model_config = ConfigDict(extra="forbid")

    train: ErdTrain = Field(default_factory=ErdTrain)
    neutral_style: str = Field("neutral", description="The labelled corpus's name for neutral (Bandai: normal).")
    intensity: float = Field(1.0, ge=0.0, le=1.0, description="Style intensity a (sec. 4.4): z' = r_0 + a r_S.")
    caption_variants: int = Field(1, ge=1, description="Revised captions per output clip.")


class ErdMethod(CorpusTrainedMethod):
    """Style-ERD (Tao et al., CVPR 2022) as a motionaug method."""

    name: ClassVar[str] = METHOD_NAME
    Params: ClassVar[type[BaseModel]] = ErdParams
    cost_rates: ClassVar[CostRates] = CostRates(transfer_clips_per_s=19.0, train_s=733.0)
    params: ErdParams
    smoke_params: ClassVar[dict[str, Any]] = {
        "train": {"steps": 3, "batch_size": 4, "window_s": 0.8}  # with base_models.size tiny
    }
    removed_params: ClassVar[dict[str, str]] = REMOVED_TRAIN

    def training_config(self, spec: TrainingSpec) -> ErdTrainConfig:
        """``train`` with the network of the run's ``base_models.size`` and the run's seed."""
        return self.params.train.recipe(spec.size, spec.seed)

    # ---- once per run: the network ----------------------------------------------------------------------

    def fit_network(self, clips: list[MotionClip], out: Path, config: Any, progress: Progress | None) -> Path:
        return train_erd(clips, out, config, progress)

    # ---- once per style ---------------------------------------------------------------------------------

    def check_style(self, style: StyleSpec, trained: Path | None, corpus: Path | None = None) -> None:
        """The style must be one the network learnt (or, before training, one the labelled corpus has)."""
        if trained is not None and self.is_trained(trained):
            known = read_artifact(trained).styles
        elif corpus is not None and Path(corpus).is_dir():
            known = sorted({r.get("style") for r in read_labels(Path(corpus)).values() if r.get("style")})
        else:
            return
        known = [self.params.neutral_style if s == NEUTRAL else s for s in known]
        if style.name not in known:
            raise MotionDataError(
                f"config styles: {style.name}", f"Style-ERD has no style {style.name!r}; it knows {sorted(known)}"
            )

    def load(self, artifact: Path, trained: Path | None) -> StyleModel:
        if trained is None:
            raise MotionDataError(f"{METHOD_NAME} load", "needs the trained network (the train step's folder)")
        record = json.loads((Path(artifact) / ARTIFACT_JSON).read_text(encoding="utf-8"))
        style = StyleSpec.model_validate(record["style"])
        return ErdStyleModel(style, load_erd(trained), self.params)


class ErdStyleModel:
    """The network and one target style; stylizes batches of whole clips."""

    def __init__(self, style: StyleSpec, net: ErdNetwork, params: ErdParams) -> None:
        self.spec = style
        self.style = style.name
        self.net = net
        self.params = params
        self.vocab = style_vocab(style.words, style.name)

    def _name(self, label: str | None) -> str | None:
        return NEUTRAL if label in (None, self.params.neutral_style) else label

    def transfer(self, clips: Sequence[MotionClip], seed: int = 0) -> list[TransferOutput | Reject]:
        results: list[TransferOutput | Reject] = []
        for i, clip in enumerate(clips):
            try:
                # A transferred clip's labels never reach the network (a user's corpus has none, and a scored
                # clip's must not): it is read as neutral with the learned unknown-content initial state, where the
                # paper (sec. 3.1) conditions that state on the content label.
                (motion,) = transfer(
                    self.net, [clip.motion], self._name(self.style), None, None, intensity=self.params.intensity
                )
                captions = revised_texts(clip, self.spec.words, self.params.caption_variants, seed + i, self.vocab)
                results.append(TransferOutput(source_id=clip.id, style=self.style, motion=motion, captions=captions))
            except MotionDataError as err:
                results.append(Reject.from_error(clip.id, err))
        return results
