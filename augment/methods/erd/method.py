"""Style-ERD behind the method contract: trained once per run on a labelled style corpus; new styles from examples.

``train`` fits the network on the train split of the labelled corpus (all of it without split files), reused
while the corpus and the training config match. ``prepare`` records a style the network learnt, and fits a new
branch from the examples for any other (``branch.py``). ``load`` + ``transfer`` stylize whole clips offline
(``motionaug stream`` runs the trained styles frame by frame). Content clips reach the network without labels:
read as neutral (supp. C.4) with the unknown-content initial state, so a user's corpus and a scored clip are alike.
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, ClassVar

from pydantic import BaseModel, ConfigDict, Field
from safetensors.torch import load_file, save_file

from motionaug.augment.corpus import MotionClip, Reject
from motionaug.augment.io import atomic_write_text
from motionaug.augment.methods.base import (
    ARTIFACT_JSON,
    CostRates,
    Prepared,
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
from motionaug.augment.methods.erd.branch import BRANCH_FILE, ErdBranchFit, apply_branch, branch_tensors, fit_branch
from motionaug.augment.methods.erd.stream import transfer
from motionaug.augment.methods.erd.training import (
    CRITICS_FILE,
    ErdTrain,
    ErdTrainConfig,
    load_erd,
    read_artifact,
    train_erd,
)
from motionaug.models.style_erd import NEUTRAL, ErdNetwork
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.skeleton import T2M
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
    branch: ErdBranchFit = Field(default_factory=ErdBranchFit, description="a style the network has not learnt")
    neutral_style: str = Field("neutral", description="The labelled corpus's name for neutral (Bandai: normal).")
    intensity: float = Field(1.0, ge=0.0, le=1.0, description="Style intensity a (sec. 4.4): z' = r_0 + a r_S.")
    caption_variants: int = Field(1, ge=1, description="Revised captions per output clip.")


class ErdMethod(CorpusTrainedMethod):
    """Style-ERD (Tao et al., CVPR 2022) as a motionaug method."""

    name: ClassVar[str] = METHOD_NAME
    Params: ClassVar[type[BaseModel]] = ErdParams
    cost_rates: ClassVar[CostRates] = CostRates(transfer_clips_per_s=19.0, train_s=733.0)
    params: ErdParams
    smoke_params: ClassVar[dict[str, Any]] = {  # with base_models.size tiny
        "train": {"steps": 3, "batch_size": 4, "window_s": 0.8},
        "branch": {"steps": 3, "batch_size": 4},
    }
    removed_params: ClassVar[dict[str, str]] = REMOVED_TRAIN

    def content_clips(self) -> int:
        """Pool clips a new style's branch fit takes its content windows and references from."""
        return self.params.branch.pool_clips

    def training_config(self, spec: TrainingSpec) -> ErdTrainConfig:
        """``train`` with the network of the run's ``base_models.size`` and the run's seed."""
        return self.params.train.recipe(spec.size, spec.seed)

    # ---- once per run: the network ----------------------------------------------------------------------

    def fit_network(self, clips: list[MotionClip], out: Path, config: Any, progress: Progress | None) -> Path:
        return train_erd(clips, out, config, progress)

    # ---- once per style ---------------------------------------------------------------------------------

    def check_style(self, style: StyleSpec, trained: Path | None, corpus: Path | None = None) -> None:
        """Any style: one the network learnt uses its branch, another gets a branch fitted from its examples."""

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
        """A learnt style: its record. Any other: a branch fitted on the examples and the pool (``branch.py``)."""
        assert trained is not None  # checked by ``prepare``
        start = time.perf_counter()
        info = read_artifact(trained)
        if self._name(style.name) in info.styles:
            return super().prepare_style(style, examples, trained, content, out, seed, progress)
        for example in examples:
            if float(example.fps) != info.fps:
                raise MotionDataError(
                    f"style {style.name!r} example {example.id}", f"{example.fps} fps, the network's {info.fps}"
                )
        pool = {c.id: c.motion for c in content if c.motion.ndim == 2 and c.motion.shape[1] == T2M.feature_dim}
        if not pool:
            raise MotionDataError(f"style {style.name!r}", "Style-ERD fits a new style on the run's pool: it is empty")
        fit = self.params.branch
        net, history = fit_branch(
            load_erd(trained),
            load_file(str(Path(trained) / CRITICS_FILE)),
            style.name,
            [e.motion for e in examples],
            pool,
            fit,
            window=int(info.data["window_frames"]),
            disc_stride=info.train.frames(info.fps)[2],
            seed=0 if seed is None else seed,
        )
        out.mkdir(parents=True, exist_ok=True)
        save_file({k: v.detach().clone().contiguous() for k, v in branch_tensors(net).items()}, str(out / BRANCH_FILE))
        record = {
            "method": self.name,
            "style": style.model_dump(mode="json"),
            "examples": [c.id for c in examples],
            "branch": {"fit": fit.model_dump(), "pool": len(pool), "history": history},
        }
        atomic_write_text(out / ARTIFACT_JSON, json.dumps(record, indent=1, sort_keys=True) + "\n")
        return Prepared(out, {"branch_fit_s": time.perf_counter() - start})

    def _name(self, style: str) -> str:
        """``style`` as the network calls it (the corpus's neutral is ``neutral``)."""
        return NEUTRAL if style == self.params.neutral_style else style

    def load(self, artifact: Path, trained: Path | None) -> StyleModel:
        if trained is None:
            raise MotionDataError(f"{METHOD_NAME} load", "needs the trained network (the train step's folder)")
        record = json.loads((Path(artifact) / ARTIFACT_JSON).read_text(encoding="utf-8"))
        style = StyleSpec.model_validate(record["style"])
        net = load_erd(trained)
        branch = Path(artifact) / BRANCH_FILE
        if branch.is_file():
            net = apply_branch(net, style.name, load_file(str(branch)))
        return ErdStyleModel(style, net, self.params)


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
