"""The held-out protocol's judges: two style classifiers and two content classifiers, trained apart from every method.

Judge 1 (style, content) is the evaluators' network on world joints. The second style judge reads facing-frame
joint positions (root height included), their velocities and the root velocity, each standardised over the clip's
own frames, so a post-process that sets channel means and variances cannot move it; the second content judge reads
facing-frame joints and their velocities without the root's motion, so keeping the content's root path cannot
satisfy it. Every judge is the same network and recipe (``models.evaluators``); only its input differs.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field

from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.io import atomic_write_text, read_json_model
from motionaug.augment.motion.batch import pad_batch
from motionaug.augment.motion.features import feature_slices, features_to_joints
from motionaug.augment.training.base_models import config_dict, load_module, save_module
from motionaug.augment.training.evaluators import classifier_accuracy, classifier_logits, fit_classifier
from motionaug.models.evaluators import ClassifierConfig, MotionClassifier, make_classifier
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.skeleton import T2M, Skeleton

JUDGES_JSON = "judges.json"
JUDGES = ("style", "style_clip", "content", "content_pose")
"""Style judge 1 and 2, content judge 1 and 2 (the protocol's names)."""


def motion_channels(features: np.ndarray, with_root: bool, skeleton: Skeleton = T2M, fps: float = 20.0) -> np.ndarray:
    """``(T, D)`` un-normalised features -> ``(T, C)``: facing-frame joint positions (root at its height), their
    velocities in m/s and, ``with_root``, the root's velocity (ground x/z in the facing frame, height, yaw rate)."""
    feats = np.asarray(features, dtype=np.float32)
    if feats.ndim != 2 or feats.shape[1] != skeleton.feature_dim:
        raise MotionDataError("judge input", f"expected (T, {skeleton.feature_dim}) features, got {feats.shape}")
    s = feature_slices(skeleton)
    t = feats.shape[0]
    root = np.zeros((t, 1, 3), np.float32)
    root[:, 0, 1] = feats[:, s["root_y"]][:, 0]
    positions = np.concatenate([root, feats[:, s["ric"]].reshape(t, -1, 3)], axis=1).reshape(t, -1)
    velocity = np.zeros_like(positions)
    velocity[1:] = (positions[1:] - positions[:-1]) * fps
    parts = [positions, velocity]
    if with_root:
        root_velocity = np.zeros((t, 4), np.float32)
        root_velocity[:, :2] = feats[:, s["root_lin_vel"]] * fps
        root_velocity[1:, 2] = (root[1:, 0, 1] - root[:-1, 0, 1]) * fps
        root_velocity[:, 3] = feats[:, s["root_rot_vel"]][:, 0] * fps
        parts.append(root_velocity)
    return np.concatenate(parts, axis=1)


def judge_input(name: str, features: np.ndarray, max_frames: int) -> np.ndarray:
    """What judge ``name`` reads of one clip (its first ``max_frames`` frames): joints or prepared channels."""
    clip = np.asarray(features)[:max_frames]
    if name in ("style", "content"):
        return features_to_joints(clip)
    return motion_channels(clip, with_root=name == "style_clip")


def _config(name: str) -> dict[str, object]:
    if name in ("style", "content"):
        return {}
    width = 6 * T2M.n_joints + (4 if name == "style_clip" else 0)
    return {"in_channels": width, "standardise": "clip" if name == "style_clip" else "train"}


class JudgesInfo(BaseModel):
    """``judges.json``: each judge's network config and labels, the train ids they saw, their held-out accuracy."""

    model_config = ConfigDict(extra="forbid")
    version: int = 1
    configs: dict[str, dict] = Field(description="judge name -> ClassifierConfig fields")
    labels: dict[str, list[str]] = Field(description="judge name -> its class labels, index order")
    trained_on: list[str] = Field(description="ids of the clips the judges were fit on")
    max_frames: int
    accuracy: dict[str, dict[str, float]] = Field(default_factory=dict, description="judge -> label -> accuracy")


class Judges:
    """The four judges, loaded; ``predict(name, motions)`` gives each clip's label index and pooled features."""

    def __init__(self, models: dict[str, MotionClassifier], info: JudgesInfo) -> None:
        self.models, self.info = models, info

    def labels(self, name: str) -> list[str]:
        return self.info.labels[name]

    @property
    def fingerprint(self) -> str:
        """12 hex digits of a hash over every judge's weights: which fit scored a figure.

        Why: the same fit command gives bit-identical judges on one machine but not across CPUs (kernels sum floats
        in another order), and one refit moves the same outputs' readings by several points, so figures compare
        only where their fingerprints agree."""
        digest = hashlib.sha256()
        for name in sorted(self.models):
            for key, tensor in sorted(self.models[name].state_dict().items()):
                digest.update(f"{name}.{key}{tuple(tensor.shape)}".encode())
                digest.update(tensor.detach().contiguous().numpy().tobytes())
        return digest.hexdigest()[:12]

    def predict(self, name: str, motions: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """(N,) predicted label indices (top-1) and (N, F) features, for un-normalised feature clips."""
        batch, mask = pad_batch([judge_input(name, m, self.info.max_frames) for m in motions])
        model = self.models[name]
        logits = classifier_logits(model, batch, mask)
        with torch.no_grad():
            feats = torch.cat([model.features(batch[i : i + 64], mask[i : i + 64]) for i in range(0, len(batch), 64)])
        return logits.argmax(dim=-1).numpy(), feats.numpy()


def fit_judges(
    train: Sequence[MotionClip],
    out: Path,
    *,
    epochs: int = 40,
    size: str = "default",
    max_frames: int = 196,
    seed: int = 0,
    held_out: Sequence[MotionClip] = (),
    which: Sequence[str] = JUDGES,
) -> Judges:
    """Fit the judges ``which`` (all four by default) on labelled ``train`` clips (the caller leaves the example
    takes out) and save them.

    ``held_out`` labelled clips, when given, measure each judge's per-label accuracy on real takes.
    """
    out.mkdir(parents=True, exist_ok=True)
    labels = {
        "style": sorted({c.style for c in train if c.style}),
        "content": sorted({c.content for c in train if c.content}),
    }
    labels |= {"style_clip": labels["style"], "content_pose": labels["content"]}
    models: dict[str, MotionClassifier] = {}
    accuracy: dict[str, dict[str, float]] = {}
    for name in which:
        if name not in JUDGES:
            raise MotionDataError("judges", f"no judge {name!r}; the judges are {', '.join(JUDGES)}")
        attr = "style" if name.startswith("style") else "content"
        names = labels[name]
        if len(names) < 2:
            raise MotionDataError("judges", f"the train clips have {len(names)} {attr} label(s); a judge needs two")
        clips = [c for c in train if getattr(c, attr) in names]
        batch, mask = pad_batch([judge_input(name, c.motion, max_frames) for c in clips])
        target = torch.tensor([names.index(getattr(c, attr)) for c in clips])
        torch.manual_seed(seed + JUDGES.index(name))
        model = make_classifier(len(names), T2M.n_joints, size, **_config(name))
        fit_classifier(model, (batch, mask, target), epochs, seed=seed)
        save_module(model, out / f"{name}.safetensors")
        models[name] = model
        accuracy[name] = _accuracy(model, name, names, [c for c in held_out if getattr(c, attr) in names], max_frames)
    info = JudgesInfo(
        configs={n: config_dict(m.config) for n, m in models.items()},
        labels=labels,
        trained_on=sorted(c.id for c in train),
        max_frames=max_frames,
        accuracy=accuracy,
    )
    atomic_write_text(out / JUDGES_JSON, info.model_dump_json(indent=1))
    return Judges(models, info)


def _accuracy(
    model: MotionClassifier, name: str, names: list[str], clips: Sequence[MotionClip], max_frames: int
) -> dict[str, float]:
    """Per-label top-1 accuracy on labelled clips, plus ``all``."""
    if not clips:
        return {}
    attr = "style" if name.startswith("style") else "content"
    batch, mask = pad_batch([judge_input(name, c.motion, max_frames) for c in clips])
    target = torch.tensor([names.index(getattr(c, attr)) for c in clips])
    out = {"all": classifier_accuracy(model, batch, mask, target)}
    for i, label in enumerate(names):
        rows = target == i
        if bool(rows.any()):
            out[label] = classifier_accuracy(model, batch[rows], mask[rows], target[rows])
    return out


def load_judges(folder: Path) -> Judges:
    """The judges saved by ``fit_judges``."""
    info = read_json_model(folder / JUDGES_JSON, JudgesInfo, "a judges folder (the held-out protocol)")
    models = {}
    for name in info.configs:
        model = MotionClassifier(ClassifierConfig(**info.configs[name]))
        load_module(model, folder / f"{name}.safetensors")
        models[name] = model.eval()
    return Judges(models, info)
