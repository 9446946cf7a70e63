"""Judging a finished run: per-clip scores and per-style summaries of its stylized clips (no Ray).

Per stylized clip (``scores.parquet``, one row per ``output_id``): the method's own scores where it gives them; the
base models' predicted content and style and the probability of the target labels; foot skating and foot-contact
agreement against the content clip; MPJPE to the paired ground truth when the corpus is synthetic. ``content_score``
(what ``motionaug export --min-content-score`` filters on) is the method's content score, else the classifier's
probability of the right content. Per style and overall: SRA, CRA, FMD against real clips of the style, diversity
and the means of the per-clip figures. What cannot be measured stays ``None`` and its reason goes to ``notes``, so
the report never shows a made-up number.
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import torch
from scipy.linalg import LinAlgWarning

from motionaug.augment.corpus import Corpus
from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.corpus.humanml3d import check_id
from motionaug.augment.eval.protocol import held_out_leaks
from motionaug.augment.io import atomic_path
from motionaug.augment.metrics import (
    diversity,
    foot_contact_accuracy,
    foot_contacts_from_joints,
    foot_skating_ratio,
    frechet_distance,
    mpjpe,
)
from motionaug.augment.motion.batch import pad_batch
from motionaug.augment.motion.features import features_to_joints
from motionaug.augment.outputs.run_dir import CONTENT_SCORE, SCORES_FILE, RunDir
from motionaug.augment.outputs.shards import iter_shard_rows, row_motion
from motionaug.augment.outputs.verify import verified_shards
from motionaug.augment.training.base_models import (
    BASE_JSON,
    CONTENT_CLASSIFIER,
    STYLE_CLASSIFIER,
    BaseModelsInfo,
    load_module,
    read_base_info,
)
from motionaug.augment.training.evaluators import EvaluatorsInfo, evaluators_folder, read_evaluators_info
from motionaug.models.evaluators import ClassifierConfig, MotionClassifier
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.run_config import RunConfig
from motionaug.schemas.shards import Manifest
from motionaug.schemas.skeleton import T2M, Skeleton

# method score names (shard ``scores`` map) -> scores.parquet columns
METHOD_SCORES = {
    "style_score": "method_style_score",
    "content_score": "method_content_score",
    "style": "method_style_score",
    "content": "method_content_score",
}
# Hu et al., "Diffusion-based Human Motion Style Transfer with Semantic Guidance", CGF 2024, Xia dataset
PAPER_REFERENCE = {"name": "Hu et al. CGF 2024 (Xia)", "sra": 0.7077, "cra": 0.8372, "sra_without_ls": 0.2801}
SCORES_SCHEMA = pa.schema(
    [
        pa.field("output_id", pa.string(), nullable=False),
        pa.field("source_id", pa.string(), nullable=False),
        pa.field("style", pa.string(), nullable=False),
        pa.field("content", pa.string()),
        pa.field("split", pa.string()),
        pa.field("evaluators_trained_on", pa.bool_()),
        pa.field("n_frames", pa.int32()),
        pa.field("fps", pa.float32()),
        pa.field("method_style_score", pa.float64()),
        pa.field("method_content_score", pa.float64()),
        pa.field("content_pred", pa.string()),
        pa.field("content_prob", pa.float64()),
        pa.field("content_correct", pa.bool_()),
        pa.field("style_pred", pa.string()),
        pa.field("style_prob", pa.float64()),
        pa.field("style_correct", pa.bool_()),
        pa.field(CONTENT_SCORE, pa.float64()),
        pa.field("foot_skating", pa.float64()),
        pa.field("foot_skating_source", pa.float64()),
        pa.field("contact_agreement", pa.float64()),
        pa.field("mpjpe", pa.float64()),
    ]
)
_ROW_COLUMNS = [
    "source_id",
    "output_id",
    "style",
    "method",
    "motion",
    "n_frames",
    "n_feats",
    "fps",
    "content",
    "split",
    "scores",
]


@dataclass
class Classifiers:
    """The two evaluators and their label lists (either may be missing)."""

    content: MotionClassifier | None
    style: MotionClassifier | None
    content_labels: list[str]
    style_labels: list[str]
    source: str
    corpus_fingerprint: str = ""  # the corpus whose train split they were fit on


@dataclass
class StyleSummary:
    """One row of the summary table: a style, or ``all``."""

    style: str
    clips: int
    sra: float | None = None
    cra: float | None = None
    trained_on: int = 0  # scored clips whose source the evaluators were trained on (the base corpus's train split)
    held_out: int = 0
    sra_held_out: float | None = None
    cra_held_out: float | None = None
    fmd: float | None = None
    diversity: float | None = None
    diversity_real: float | None = None
    foot_skating: float | None = None
    foot_skating_source: float | None = None
    contact_agreement: float | None = None
    mpjpe: float | None = None
    method_style_score: float | None = None
    method_content_score: float | None = None


@dataclass
class Evaluation:
    """Everything the report shows: per-clip scores, summaries, loss curves, timings, notes."""

    run_dir: Path
    run_id: str
    method: str
    corpus: str
    reference: str
    base_models: str | None
    scores: list[dict]  # per clip, sorted by output_id; columns of SCORES_SCHEMA
    styles: list[StyleSummary]
    overall: StyleSummary
    loss_curves: dict[str, list[dict[str, float]]] = field(default_factory=dict)
    stages: dict[str, dict[str, float]] = field(default_factory=dict)
    throughput: float | None = None
    rows: int = 0
    rejects: int = 0
    notes: list[str] = field(default_factory=list)
    leaks: list[str] = field(default_factory=list)  # why the figures are not held out (empty: they are)


# ---- loading -------------------------------------------------------------------------------------


def load_classifiers(path: str | Path) -> Classifiers:
    """The evaluators at ``path``: an evaluators folder, a base-models folder's ``evaluators/``, or (older base-models
    folders) the classifiers listed in its ``base.json``."""
    folder = evaluators_folder(path)
    info: EvaluatorsInfo | BaseModelsInfo = read_evaluators_info(folder) if folder else read_base_info(Path(path))
    folder = folder or Path(path)
    loaded: dict[str, MotionClassifier | None] = {}
    for name in (CONTENT_CLASSIFIER, STYLE_CLASSIFIER):
        config = getattr(info, name)
        if config is None:
            loaded[name] = None
            continue
        model = MotionClassifier(ClassifierConfig(**config))
        load_module(model, folder / f"{name}.safetensors")
        loaded[name] = model.eval().requires_grad_(False)
    return Classifiers(
        loaded[CONTENT_CLASSIFIER],
        loaded[STYLE_CLASSIFIER],
        list(info.content_labels),
        list(info.style_labels),
        str(folder),
        info.corpus_fingerprint,
    )


def _base_models_dir(run_dir: Path, manifest: Manifest, config: dict, given: Path | None) -> Path | None:
    """``--evaluators``, else the config's ``evaluators``, else the run's recorded or configured base models, else
    ``<run>/base_models``."""
    if given is not None:
        return Path(given)
    if config.get("evaluators"):
        return Path(config["evaluators"])
    configured = (config.get("base_models") or {}).get("path")
    for candidate in (manifest.base_models, configured, run_dir / "base_models"):
        if candidate and (evaluators_folder(candidate) or (Path(candidate) / BASE_JSON).is_file()):
            return Path(candidate)
    return None


def loss_curves(run_dir: Path, styles: Iterable[str]) -> dict[str, list[dict[str, float]]]:
    """Per style, the fine-tuning curve from ``styles/<s>/artifact.json`` (``loss_curve`` or ``losses``).

    Entries are dicts (``step`` plus named losses) or plain numbers (taken as ``total``); styles without
    a curve are left out.
    """
    run = RunDir(run_dir)
    curves: dict[str, list[dict[str, float]]] = {}
    for style in styles:
        for path in sorted(run.artifact_dir(style).rglob("artifact.json")):
            try:
                info = json.loads(path.read_text(encoding="utf-8"))
            except (OSError, ValueError):
                continue
            raw = info.get("loss_curve") or info.get("losses") if isinstance(info, dict) else None
            if isinstance(raw, list) and raw:
                curves[style] = [_curve_point(i, p) for i, p in enumerate(raw) if isinstance(p, (int, float, dict))]
                break
    return curves


def _curve_point(index: int, point: float | dict) -> dict[str, float]:
    if isinstance(point, dict):
        record = {k: float(v) for k, v in point.items() if isinstance(v, (int, float))}
        record.setdefault("step", float(index))
        return record
    return {"step": float(index), "total": float(point)}


# ---- corpus side ---------------------------------------------------------------------------------


@dataclass
class _Source:
    """What the evaluation keeps of one content clip (small: no joints): contacts, skating, spec."""

    contacts: np.ndarray  # (T-1, 4) bool, HumanML3D contact rule
    foot_skating: float | None
    spec: str | None


def _read_sources(corpus: Path, ids: set[str], notes: list[str]) -> dict[str, _Source]:
    if not corpus.exists():
        notes.append(f"source corpus {corpus} is gone: no foot-contact agreement or MPJPE")
        return {}
    found: dict[str, _Source] = {}
    for clip in Corpus(corpus, feature_dim=T2M.feature_dim):
        if clip.id in ids and clip.id not in found:
            joints = features_to_joints(clip.motion, T2M, source=f"clip {clip.id}")
            skating = foot_skating_ratio(joints, T2M, clip.fps) if len(joints) > 1 else None
            found[clip.id] = _Source(foot_contacts_from_joints(joints, T2M), skating, clip.meta.get("spec"))
    missing = len(ids) - len(found)
    if missing:
        notes.append(f"{missing} content clips not found in {corpus}: their contact agreement/MPJPE are empty")
    return found


def paired_ground_truth(spec_json: str, style: str, skeleton: Skeleton = T2M) -> np.ndarray | None:
    """Joints (T, J, 3) of a synthetic clip's spec rendered in ``style``, through the feature round trip.

    None when ``style`` is not one the synthetic animator knows (no ground truth exists then).
    """
    from motionaug.augment.motion.features import extract_features
    from motionaug.augment.synth import STYLES, ClipSpec, render

    if style not in STYLES:
        return None
    rendered = render(ClipSpec.from_json(spec_json).with_style(style))
    features = extract_features(rendered.joints, skeleton, source=f"ground truth ({style})")
    return features_to_joints(features, skeleton, source=f"ground truth ({style})")


# ---- per clip --------------------------------------------------------------------------------------


def _clip_figures(joints: np.ndarray, fps: float, source: _Source | None, style: str) -> dict[str, float | None]:
    """Foot skating, contact agreement with the content clip and MPJPE to the paired ground truth."""
    figures: dict[str, float | None] = {
        "foot_skating": foot_skating_ratio(joints, T2M, fps) if len(joints) > 1 else None,
        "foot_skating_source": None,
        "contact_agreement": None,
        "mpjpe": None,
    }
    if source is None:
        return figures
    figures["foot_skating_source"] = source.foot_skating
    n = min(len(joints) - 1, len(source.contacts))  # contacts cover frame transitions
    if n > 0:
        ours = foot_contacts_from_joints(joints[: n + 1], T2M)
        figures["contact_agreement"] = foot_contact_accuracy(ours, source.contacts[:n])
    truth = paired_ground_truth(source.spec, style) if source.spec else None
    if truth is not None:
        m = min(len(truth), len(joints))
        figures["mpjpe"] = mpjpe(joints[:m], truth[:m])
    return figures


def _method_scores(scores: Sequence[tuple[str, float]] | None) -> dict[str, float]:
    found: dict[str, float] = {}
    for key, value in scores or []:
        if key in METHOD_SCORES:
            found.setdefault(METHOD_SCORES[key], float(value))
    return found


@torch.no_grad()
def classify(model: MotionClassifier, joints: Sequence[np.ndarray], batch: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """(probabilities (N, C), pooled features (N, F)) of joint clips, batched with a frame mask."""
    probs, feats = [], []
    for start in range(0, len(joints), batch):
        padded, mask = pad_batch(list(joints[start : start + batch]))
        f = model.features(padded, mask)
        feats.append(f.numpy())
        probs.append(torch.softmax(model.classifier(f), dim=-1).numpy())
    width = model.config.n_classes, model.config.feat_dim
    if not probs:
        return np.zeros((0, width[0])), np.zeros((0, width[1]))
    return np.concatenate(probs).astype(np.float64), np.concatenate(feats).astype(np.float64)


def _predictions(probs: np.ndarray, labels: list[str], targets: Sequence[str | None], prefix: str) -> dict[str, list]:
    """Predicted label, probability of the target label and whether it was right (None when no target)."""
    index = {name: i for i, name in enumerate(labels)}
    preds = [labels[i] if i < len(labels) else str(i) for i in probs.argmax(axis=1)] if len(probs) else []
    prob, correct = [], []
    for row, target, pred in zip(probs, targets, preds):
        known = target is not None and target in index
        prob.append(float(row[index[target]]) if known else None)
        correct.append(bool(pred == target) if known else None)
    return {f"{prefix}_pred": preds, f"{prefix}_prob": prob, f"{prefix}_correct": correct}


# ---- the evaluation ------------------------------------------------------------------------------


def _held_out_leaks(config: dict) -> list[str]:
    """How a scored clip of the run may have reached its method (``protocol.held_out_leaks``); empty: none."""
    try:
        return held_out_leaks(RunConfig.model_validate(config))
    except (ValueError, MotionDataError) as err:
        return [f"its pool could not be checked ({str(err).splitlines()[0]})"]


def evaluate_run(
    run_dir: str | Path,
    reference: str | Path | None = None,
    base_models: str | Path | None = None,
    seed: int = 0,
    progress: Callable[[str, int, int, dict[str, float]], None] | None = None,
) -> Evaluation:
    """Score every stylized clip of a complete run and summarise per style (see the module docstring).

    ``reference`` is the corpus whose labelled clips FMD compares against (default: the run's corpus);
    ``base_models`` holds the classifiers (default: the run's base models); ``progress(stage, done, total, {})``
    hears of each scored batch.
    """
    run_dir = Path(run_dir)
    manifest = RunDir(run_dir).manifest()
    config = manifest.config
    notes: list[str] = []
    corpus = Path(config["corpus"]["path"])
    reference = Path(reference) if reference is not None else corpus
    classifiers = _classifiers(run_dir, manifest, config, Path(base_models) if base_models else None, notes)
    evaluators_saw_train = classifiers is not None and _evaluators_trained_on(classifiers, corpus)
    shards = verified_shards(RunDir(run_dir))
    source_ids = {r["source_id"] for r in iter_shard_rows(run_dir, columns=["source_id"], files=shards)}
    if not source_ids:
        raise MotionDataError(str(run_dir), "run has no stylized clips to evaluate")
    sources = _read_sources(corpus, source_ids, notes)
    rows = iter_shard_rows(run_dir, columns=_ROW_COLUMNS, files=shards)
    records, out_feats = _score_rows(rows, sources, classifiers, progress=progress, total=manifest.rows)
    styles = [s["name"] for s in config.get("styles", [])] or sorted({r["style"] for r in records})
    real_feats = _real_features(reference, styles, classifiers, notes)
    style_of = np.array([r["style"] for r in records])
    for record in records:
        record["evaluators_trained_on"] = evaluators_saw_train and record["split"] == "train"
    summaries = [
        _summarise([r for r in records if r["style"] == s], out_feats[style_of == s], real_feats.get(s), s, seed, notes)
        for s in styles
    ]
    overall = _summarise(records, out_feats, None, "all", seed, notes)
    if evaluators_saw_train and overall.trained_on:
        notes.append(
            f"{overall.trained_on} of {overall.clips} scored clips come from the train split the evaluators were "
            "trained on: SRA and CRA over every clip are optimistic; the held-out columns score val/test clips only"
        )
    fmds = [s.fmd for s in summaries if s.fmd is not None]
    overall.fmd = float(np.mean(fmds)) if fmds else None
    _explain_gaps(records, summaries, classifiers, notes)
    stages = {k: manifest.stages[k] for k in sorted(manifest.stages, key=_stage_rank)}
    return Evaluation(
        run_dir=run_dir,
        run_id=manifest.run_id,
        method=manifest.method,
        corpus=str(corpus),
        reference=str(reference),
        base_models=classifiers.source if classifiers else None,
        scores=records,
        styles=summaries,
        overall=overall,
        loss_curves=loss_curves(run_dir, styles),
        stages={
            k: {"seconds": v.seconds, "tasks": float(v.tasks), "skipped": float(v.skipped)} for k, v in stages.items()
        },
        throughput=_throughput(manifest),
        rows=manifest.rows,
        rejects=manifest.rejects,
        notes=notes,
        leaks=_held_out_leaks(config),
    )


STAGE_ORDER = ("plan", "train", "prepare", "transfer", "manifest")


def _stage_rank(name: str) -> tuple[int, str]:
    return (STAGE_ORDER.index(name) if name in STAGE_ORDER else len(STAGE_ORDER), name)


def _throughput(manifest: Manifest) -> float | None:
    """Stylized clips per second of the transfer stage (its clock starts with the fine-tunes it waits for)."""
    transfer = manifest.stages.get("transfer")
    return manifest.rows / transfer.seconds if transfer is not None and transfer.seconds > 0 else None


def _evaluators_trained_on(classifiers: Classifiers, corpus: Path) -> bool:
    """Whether the evaluators were fit on this corpus (its train split), from the corpus fingerprint."""
    from motionaug.augment.corpus.fingerprint import corpus_fingerprint

    try:
        return bool(classifiers.corpus_fingerprint) and corpus_fingerprint(corpus) == classifiers.corpus_fingerprint
    except MotionDataError:
        return False


def _classifiers(
    run_dir: Path, manifest: Manifest, config: dict, given: Path | None, notes: list[str]
) -> Classifiers | None:
    folder = _base_models_dir(run_dir, manifest, config, given)
    if folder is None:
        notes.append("no base models (give --base-models): SRA, CRA, FMD and diversity are not measured")
        return None
    classifiers = load_classifiers(folder)
    for name, model in (("content", classifiers.content), ("style", classifiers.style)):
        if model is None:
            missing = "CRA" if name == "content" else "SRA, FMD, diversity"
            notes.append(f"base models at {folder} have no {name} classifier: {missing} not measured")
    return classifiers


def _score_rows(
    rows: Iterable[dict],
    sources: dict[str, _Source],
    classifiers: Classifiers | None,
    batch: int = 64,
    progress: Callable[[str, int, int, dict[str, float]], None] | None = None,
    total: int = 0,
) -> tuple[list[dict], np.ndarray]:
    """Per-clip records sorted by output_id, and the style-classifier features (N, F) in the same order.

    Rows are handled a batch at a time so only features, not joints, stay in memory.
    """
    records: list[dict] = []
    feats: list[np.ndarray] = []
    pending: list[dict] = []
    for row in rows:
        pending.append(row)
        if len(pending) == batch:
            _score_batch(pending, sources, classifiers, records, feats)
            pending = []
            if progress is not None:
                progress("score", len(records), max(total, len(records)), {})
    if pending:
        _score_batch(pending, sources, classifiers, records, feats)
    if progress is not None:
        progress("score", len(records), len(records), {})
    order = sorted(range(len(records)), key=lambda i: records[i]["output_id"])
    all_feats = np.concatenate(feats) if feats else np.zeros((len(records), 0))
    return [records[i] for i in order], all_feats[order]


def _score_batch(
    rows: list[dict],
    sources: dict[str, _Source],
    classifiers: Classifiers | None,
    records: list[dict],
    feats: list[np.ndarray],
) -> None:
    joints = [features_to_joints(row_motion(r), T2M, source=f"stylized clip {r['output_id']}") for r in rows]
    columns: dict[str, list] = {}
    for prefix in ("content", "style"):
        model = getattr(classifiers, prefix) if classifiers else None
        if model is None:
            columns.update({f"{prefix}_{k}": [None] * len(rows) for k in ("pred", "prob", "correct")})
            continue
        probs, f = classify(model, joints)
        labels = classifiers.content_labels if prefix == "content" else classifiers.style_labels
        targets = [r["content"] if prefix == "content" else str(r["style"]) for r in rows]
        columns.update(_predictions(probs, labels, targets, prefix))
        if prefix == "style":
            feats.append(f)
    for i, (row, clip_joints) in enumerate(zip(rows, joints)):
        fps = float(np.float32(row["fps"]))
        record = {
            "output_id": row["output_id"],
            "source_id": row["source_id"],
            "style": str(row["style"]),
            "content": row["content"],
            "split": row["split"],
            "n_frames": int(row["n_frames"]),
            "fps": fps,
            "method_style_score": None,
            "method_content_score": None,
            **_method_scores(row["scores"]),
            **{name: values[i] for name, values in columns.items()},
            **_clip_figures(clip_joints, fps, sources.get(row["source_id"]), str(row["style"])),
        }
        record[CONTENT_SCORE] = _content_score(record)
        records.append(record)


def _content_score(record: dict) -> float | None:
    """The method's content score where given, else the content classifier's probability of the right content."""
    method = record["method_content_score"]
    return method if method is not None else record["content_prob"]


def _real_features(
    reference: Path, styles: list[str], classifiers: Classifiers | None, notes: list[str]
) -> dict[str, np.ndarray]:
    """Style-classifier features of the reference corpus's clips labelled with each run style."""
    if classifiers is None or classifiers.style is None:
        return {}
    if not reference.exists():
        notes.append(f"reference corpus {reference} not found: no FMD")
        return {}
    wanted = set(styles)
    joints: dict[str, list[np.ndarray]] = {s: [] for s in styles}
    feats: dict[str, list[np.ndarray]] = {s: [] for s in styles}
    for clip in Corpus(reference, feature_dim=T2M.feature_dim):
        if clip.style in wanted:
            joints[clip.style].append(features_to_joints(clip.motion, T2M, source=f"clip {clip.id}"))
            if len(joints[clip.style]) == 64:  # features only are kept, never a whole corpus of joints
                feats[clip.style].append(classify(classifiers.style, joints[clip.style])[1])
                joints[clip.style] = []
    for style, rest in joints.items():
        if rest:
            feats[style].append(classify(classifiers.style, rest)[1])
    if not any(feats.values()):
        notes.append(f"reference corpus {reference} has no clips labelled with the run's styles: no FMD")
    return {s: np.concatenate(f) for s, f in feats.items() if f}


def column(records: Sequence[dict], name: str) -> np.ndarray:
    """One per-clip column as float64 with NaN where it is empty (booleans become 0/1)."""
    return np.array([np.nan if r.get(name) is None else float(r[name]) for r in records], dtype=np.float64)


def _mean(records: Sequence[dict], name: str) -> float | None:
    values = column(records, name)
    values = values[~np.isnan(values)]
    return float(values.mean()) if len(values) else None


def _summarise(
    records: list[dict], feats: np.ndarray, real: np.ndarray | None, name: str, seed: int, notes: list[str]
) -> StyleSummary:
    summary = StyleSummary(style=name, clips=len(records))
    summary.sra = _mean(records, "style_correct")
    summary.cra = _mean(records, "content_correct")
    held = [r for r in records if not r["evaluators_trained_on"]]
    summary.trained_on, summary.held_out = len(records) - len(held), len(held)
    summary.sra_held_out = _mean(held, "style_correct")
    summary.cra_held_out = _mean(held, "content_correct")
    for name_ in (
        "foot_skating",
        "foot_skating_source",
        "contact_agreement",
        "mpjpe",
        "method_style_score",
        "method_content_score",
    ):
        setattr(summary, name_, _mean(records, name_))
    if feats.shape[1] and len(feats) >= 2:
        summary.diversity = diversity(feats, n_pairs=min(300, len(feats)), seed=seed)
    if real is not None and len(real) >= 2:
        summary.diversity_real = diversity(real, n_pairs=min(300, len(real)), seed=seed)
    if real is not None and feats.shape[1]:
        summary.fmd = _fmd(feats, real, name, notes)
    return summary


def _fmd(feats: np.ndarray, real: np.ndarray, style: str, notes: list[str]) -> float | None:
    """FMD when both sets have more clips than feature dimensions (else the covariances are singular)."""
    width = feats.shape[1]
    if min(len(feats), len(real)) <= width:
        notes.append(
            f"style {style}: {len(feats)} stylized / {len(real)} real clips for {width}-dim features: "
            f"too few for FMD (needs more than {width} of each)"
        )
        return None
    try:
        with warnings.catch_warnings():  # near-singular products are handled (or refused) by frechet_distance
            warnings.simplefilter("ignore", LinAlgWarning)
            return frechet_distance(feats, real)
    except MotionDataError as err:
        notes.append(f"style {style}: FMD not computed ({err})")
        return None


def _explain_gaps(
    records: list[dict], summaries: list[StyleSummary], classifiers: Classifiers | None, notes: list[str]
) -> None:
    """Say why a figure is empty where the reason is per style or per clip (unknown label, no ground truth)."""
    if classifiers is not None and classifiers.style is not None:
        unknown = sorted({s.style for s in summaries} - set(classifiers.style_labels))
        if unknown:
            notes.append(
                f"styles {unknown} are not among the style classifier's labels {classifiers.style_labels}: "
                "no SRA for them"
            )
    if classifiers is not None and classifiers.content is not None:
        missing = sum(r["content"] not in classifiers.content_labels for r in records)
        if missing:
            notes.append(f"{missing} clips have no content label the content classifier knows: left out of CRA")
    if all(r["mpjpe"] is None for r in records):
        notes.append(
            "no paired ground truth (the corpus is not synthetic, or its styles are not the animator's): no MPJPE"
        )


def scores_table(evaluation: Evaluation) -> pa.Table:
    return pa.Table.from_pylist(evaluation.scores, schema=SCORES_SCHEMA)


def write_scores(evaluation: Evaluation, path: Path | None = None) -> Path:
    """``scores.parquet`` in the run folder (atomically), one row per output_id."""
    target = path or evaluation.run_dir / SCORES_FILE
    with atomic_path(target) as tmp:
        pq.write_table(scores_table(evaluation), tmp, compression="zstd")
    return target


# ---- looking at single clips (``motionaug preview``) ---------------------------------------------
# User-given ids are matched against ids the corpus or the shards list; they never become paths
# themselves, and a file name is only made from an id that passed ``check_id``.


def find_corpus_clip(corpus: Path, clip_id: str) -> MotionClip:
    """The clip ``clip_id`` of a corpus (a caption-span id ``<parent>_<start>_<end>`` too); a clip the corpus
    rejects is an error with the reject's reason."""
    clips, rejects = Corpus(corpus).load([clip_id])
    if clips:
        return clips[0]
    found = [r for r in rejects if Path(r.source.split(":")[0]).is_file() and ".." not in r.source]
    if found:  # the clip is there but unusable: say why (a file never opened from an unchecked id)
        raise MotionDataError(found[0].source, found[0].reason)
    raise MotionDataError(str(corpus), f"no clip with id {clip_id!r}")


def find_stylized(run_dir: Path, source_id: str, style: str, shards: list[Path] | None = None) -> dict:
    """The shard row of ``source_id`` stylized as ``style``, from ``shards`` (default: the run's, verified)."""
    run = RunDir(run_dir)
    styles = run.styles()
    if style not in styles:
        raise MotionDataError("--style", f"run has no style {style!r}; its styles are {styles}")
    verified = verified_shards(run, complete=False, style=style) if shards is None else shards
    for file in (f for f in verified if f.parent.name == f"style={style}"):
        table = pq.read_table(file, filters=[("source_id", "=", source_id)])
        if table.num_rows:
            return table.slice(0, 1).to_pylist()[0]
    raise MotionDataError(
        str(run_dir), f"no stylized clip of {source_id!r} in style {style!r} (not transferred yet, or rejected)"
    )


def _first_text(captions: Sequence[dict]) -> str | None:
    return captions[0]["text"] if captions else None


def preview_transfer(run_dir: Path, clip_id: str, style: str, out: Path | None = None, **options: Any) -> Path:
    """GIF/MP4 of the content clip beside its stylized version, original and revised captions as titles.

    Default ``out``: ``<run>/previews/<output_id>.gif``. ``options`` go to ``render_panels_gif``.
    """
    from motionaug.augment.render.previews import preview_pair

    row = find_stylized(run_dir, clip_id, style)
    content = find_corpus_clip(Path(RunDir(run_dir).config()["corpus"]["path"]), clip_id)
    name = check_id(row["output_id"], f"output id in {run_dir}")
    target = out if out is not None else Path(run_dir) / "previews" / f"{name}.gif"
    target.parent.mkdir(parents=True, exist_ok=True)
    return preview_pair(
        content,
        row_motion(row),
        _first_text(row["original_captions"]),
        _first_text(row["captions"]),
        target,
        style=style,
        **options,
    )


def preview_corpus(corpus: Path, clip_id: str, out: Path | None = None, **options: Any) -> Path:
    """GIF/MP4 of one corpus clip; default ``out``: ``./previews/<clip id>.gif``."""
    from motionaug.augment.render.previews import preview_clip

    clip = find_corpus_clip(corpus, clip_id)
    target = out if out is not None else Path("previews") / f"{check_id(clip.id, str(corpus))}.gif"
    target.parent.mkdir(parents=True, exist_ok=True)
    return preview_clip(clip, target, **options)


def preview_grid(run_dir: Path, n: int, out: Path | None = None, seed: int = 0, **options: Any) -> Path:
    """One PNG contact sheet of ``n`` random transfers across styles (seeded): content beside stylized."""
    from motionaug.augment.render.previews import CONTENT_COLOR, STYLIZED_COLOR, Panel, SheetRow, render_contact_sheet

    if n < 1:
        raise MotionDataError("--grid", f"needs at least 1 clip, got {n}")
    shards = verified_shards(RunDir(run_dir), complete=False)
    pairs = sorted(
        (r["source_id"], str(r["style"])) for r in iter_shard_rows(run_dir, ["source_id", "style"], files=shards)
    )
    if not pairs:
        raise MotionDataError(str(run_dir), "run has no stylized clips yet")
    chosen = [
        pairs[i] for i in sorted(np.random.default_rng(seed).choice(len(pairs), min(n, len(pairs)), replace=False))
    ]
    corpus = Path(RunDir(run_dir).config()["corpus"]["path"])
    rows = []
    for source_id, style in chosen:
        row = find_stylized(run_dir, source_id, style, shards)
        content = find_corpus_clip(corpus, source_id)
        panels = [
            Panel(features_to_joints(content.motion, T2M, source=f"clip {source_id}"), "content", CONTENT_COLOR),
            Panel(features_to_joints(row_motion(row), T2M, source=row["output_id"]), style, STYLIZED_COLOR),
        ]
        rows.append(SheetRow(f"{style} · {source_id}: {_first_text(row['captions']) or ''}", panels))
    target = out if out is not None else Path(run_dir) / "previews" / f"grid-{len(rows)}-seed{seed}.png"
    target.parent.mkdir(parents=True, exist_ok=True)
    return render_contact_sheet(rows, target, fps=float(np.float32(row["fps"])), **options)
