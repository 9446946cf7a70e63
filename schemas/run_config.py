"""The run configuration of ``motionaug run``: one YAML/JSON file, validated before any work starts.

Everything is ``extra="forbid"`` so a typo is an error naming the field. Relative paths resolve against
the config file's folder. The run id is a hash of what determines the rows (corpus path and a fingerprint of
its files, styles, method, fan-out, seed, unit and batch sizes), not of where or on what they are computed, so
re-running the same config on the same corpus resumes the same run, and a corpus rewritten in place is a new one.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, field_validator, model_validator

from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.styles import StyleSpec

RUN_CONFIG_VERSION = 1
RESOLVED_CONFIG_FILE = "config.resolved.json"
CORPUS_CONTENT_DIRS = ("new_joint_vecs", "texts")
"""Sub-folders of a corpus whose files are clips (HumanML3D's motion and caption folders, MOTION_DIR and TEXT_DIR
of ``augment/corpus/humanml3d.py``); other sub-folders (renders, joints, a run folder put there) are not content."""


def corpus_stat_fingerprint(path: Path) -> str:
    """A digest of (name, size, modification time) of the corpus's files: a Parquet file, or a folder's top-level
    files (split lists, labels, Mean/Std, Parquet parts) and those of ``CORPUS_CONTENT_DIRS``.

    Cheap (one ``stat`` per file, no reads) and changed by any rewrite of the corpus, even to the same bytes.
    Hidden files and ``*.tmp`` are left out: they are a writer's temporaries, not the corpus.
    """
    path = Path(path)
    if path.is_file():
        stat = path.stat()
        entries = [f"{path.name}\0{stat.st_size}\0{stat.st_mtime_ns}"]
    elif path.is_dir():
        entries = _file_entries(path, "")
        for sub in CORPUS_CONTENT_DIRS:
            if (path / sub).is_dir():
                entries += _file_entries(path / sub, f"{sub}/")
    else:
        return "absent"
    return hashlib.sha256("\n".join(sorted(entries)).encode()).hexdigest()


def _file_entries(folder: Path, prefix: str) -> list[str]:
    entries = []
    with os.scandir(folder) as listing:
        for entry in listing:
            if entry.name.startswith(".") or entry.name.endswith(".tmp") or not entry.is_file():
                continue
            stat = entry.stat()
            entries.append(f"{prefix}{entry.name}\0{stat.st_size}\0{stat.st_mtime_ns}")
    return entries


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class CorpusFilters(_Strict):
    """Which clips of the corpus are stylized (all of them when empty)."""

    contents: list[str] | None = Field(default=None, description="Keep clips whose content label is listed.")
    source_styles: list[str] | None = Field(
        default=None,
        description="Keep clips whose style label is listed (e.g. [neutral] to stylize only neutral clips).",
    )
    caption_regex: str | None = Field(default=None, description="Keep clips with a caption matching this regex.")
    min_frames: int | None = Field(default=None, ge=1)
    max_frames: int | None = Field(default=None, ge=1)

    @field_validator("caption_regex")
    @classmethod
    def _compiles(cls, value: str | None) -> str | None:
        if value is not None:
            try:
                re.compile(value)
            except re.error as err:
                raise ValueError(f"not a valid regular expression ({err})") from None
        return value

    @model_validator(mode="after")
    def _ordered(self) -> CorpusFilters:
        if self.min_frames and self.max_frames and self.min_frames > self.max_frames:
            raise ValueError(f"min_frames {self.min_frames} > max_frames {self.max_frames}")
        return self


DEFAULT_CLIP_FRAMES = 200
"""HumanML3D's convention: clips under 10 s at 20 fps (its reference loader keeps 40 <= T < 200)."""
CLIP_FRAMES_CEILING = 20_000  # ``augment.corpus.humanml3d.MAX_CLIP_FRAMES``: no clip is read past it


class CorpusConfig(_Strict):
    path: Path
    format: Literal["auto", "humanml3d", "parquet"] = "auto"
    max_clip_frames: int | None = Field(
        default=None,
        ge=1,
        le=CLIP_FRAMES_CEILING,
        description=f"Longer clips are rejects (with their length as the reason); default {DEFAULT_CLIP_FRAMES}.",
    )
    split: str | None = Field(default=None, description="HumanML3D split file to read (default: all.txt).")
    filters: CorpusFilters = Field(default_factory=CorpusFilters)
    pool_split: str | None = Field(
        default=None,
        description="Split file the method's content pool (the clips its prepare learns from, e.g. on-the-fly's "
        "L_s) is drawn from, through the same filters; default: the run's own clips. A benchmark that scores "
        "held-out clips sets it to the train split, so that no method trains on a scored clip.",
    )


class MethodConfig(_Strict):
    name: str = Field(default="stats", min_length=1)
    params: dict[str, Any] = Field(default_factory=dict, description="Checked by the method's validate_params.")
    shapers: list[str | dict[str, Any]] = Field(
        default_factory=list,
        description="Output shapers (registered by name, augment.methods.hooks) applied in order to every output of "
        "any method, e.g. [moments]; a shaper is a post-process, not part of the method.",
    )


class FanOutConfig(_Strict):
    """``per_clip="all"``: every clip in every style; an int k: k styles per clip, drawn with ``seed``."""

    per_clip: Literal["all"] | int = "all"
    seed: int = 0

    @field_validator("per_clip")
    @classmethod
    def _positive(cls, value: Literal["all"] | int) -> Literal["all"] | int:
        if value != "all" and value < 1:
            raise ValueError(f"must be 'all' or >= 1, got {value}")
        return value


class BaseModelsConfig(_Strict):
    """Where the method's once-per-run models are and what they train on; how they train is the method's own
    setting (``method.params.train``). A ``path`` that holds trained models is used as it is (e.g. an imported MDM
    checkpoint); otherwise they are trained there, and reused on later runs while corpus and settings match."""

    path: Path | None = Field(default=None, description="The trained models; None: <run>/base_models.")
    corpus: Path | None = Field(
        default=None, description="Labelled corpus the method trains on (its train split); None: the run's corpus."
    )
    pretrain_if_missing: bool = True
    size: Literal["tiny", "small", "paper"] = Field("small", description="The size of the method's networks.")

    @model_validator(mode="before")
    @classmethod
    def _moved(cls, data: Any) -> Any:
        """Pre-training settings moved to the method's params: one line saying where, not a bare 'extra field'."""
        if isinstance(data, dict):
            for name in MOVED_TO_METHOD:
                if name in data:
                    where = "method.params.train" if name == "pretrain" else f"method.params.train.{name}"
                    raise ValueError(f"{name} moved: the method's training settings are {where} now")
        return data

    def resolved(self, absolute: Any) -> BaseModelsConfig:
        """Every path made absolute with ``absolute``."""
        return self.model_copy(update={"path": absolute(self.path), "corpus": absolute(self.corpus)})


MOVED_TO_METHOD = ("pretrain", "from_mdm", "clip_weights", "mdm_stats")


class ComputeConfig(_Strict):
    """Where and how wide: ``address`` None starts an embedded local Ray with ``num_cpus``."""

    address: str | None = None
    num_cpus: int | None = Field(default=None, ge=1)
    finetune_cpus: float = Field(default=1.0, gt=0)
    finetune_gpus: float = Field(default=0.0, ge=0)
    transfer_cpus: float = Field(default=1.0, gt=0)
    transfer_gpus: float = Field(default=0.0, ge=0)
    batch_size: int = Field(default=32, gt=0)
    unit_size: int = Field(default=256, ge=1)
    max_retries: int = Field(default=3, ge=0)
    include_dashboard: bool = False
    connect_timeout_s: float = Field(
        default=30.0, gt=0, description="Seconds to reach a cluster given by address before giving up."
    )
    unschedulable_timeout_s: float = Field(
        default=45.0,
        ge=0,
        description="Seconds a stage may wait for a node with the resources its tasks ask for (an autoscaler may "
        "add one); then the run stops naming the setting. An embedded Ray has no autoscaler: it stops at once.",
    )


class HooksConfig(_Strict):
    """Modules outside the package that register hooks (``augment.methods.hooks``) the method params name."""

    modules: list[str] = Field(
        default_factory=list,
        description="Importable module names (e.g. lab.umsd_hooks), imported by the driver and every Ray worker "
        "before the method is built; a module must import from the run's working directory or be installed.",
    )


class RunConfig(_Strict):
    version: Literal[1] = RUN_CONFIG_VERSION
    corpus: CorpusConfig
    styles: list[StyleSpec] = Field(min_length=1)
    method: MethodConfig = Field(default_factory=MethodConfig)
    hooks: HooksConfig = Field(default_factory=HooksConfig)
    fan_out: FanOutConfig = Field(default_factory=FanOutConfig)
    base_models: BaseModelsConfig = Field(default_factory=BaseModelsConfig)
    evaluators: Path | None = Field(
        default=None,
        description="The judges `motionaug evaluate` scores the run with: an evaluators folder (`motionaug pretrain "
        "--evaluators-only`), kept apart from any method's trained models; None: those of base_models.path.",
    )
    compute: ComputeConfig = Field(default_factory=ComputeConfig)
    output: Path = Path("runs/run")
    seed: int = 0
    allow_empty: bool = Field(
        default=False, description="Accept a run that selects or writes 0 clips (else that is an error)."
    )
    _fingerprint: tuple[str, str] | None = PrivateAttr(default=None)  # (resolved corpus path, its fingerprint)

    @field_validator("styles")
    @classmethod
    def _unique_names(cls, styles: list[StyleSpec]) -> list[StyleSpec]:
        names = [s.name for s in styles]
        dupes = sorted({n for n in names if names.count(n) > 1})
        if dupes:
            raise ValueError(f"style names must be unique; repeated: {dupes}")
        return styles

    @model_validator(mode="after")
    def _fan_out_fits(self) -> RunConfig:
        k = self.fan_out.per_clip
        if k != "all" and k > len(self.styles):
            raise ValueError(f"fan_out.per_clip {k} > number of styles {len(self.styles)}")
        return self

    def clip_frames(self) -> int:
        """The most frames a clip of this run may have (``corpus.max_clip_frames`` or the convention)."""
        return self.corpus.max_clip_frames or DEFAULT_CLIP_FRAMES

    def corpus_fingerprint(self) -> str:
        """``corpus_stat_fingerprint`` of the corpus, computed once per config object (it travels with it to tasks)."""
        path = str(Path(self.corpus.path).resolve())
        if self._fingerprint is None or self._fingerprint[0] != path:
            self._fingerprint = (path, corpus_stat_fingerprint(Path(path)))
        return self._fingerprint[1]

    def run_id(self) -> str:
        """Deterministic id of what the run produces (not where it is written or how it is computed)."""
        keep = self.model_dump(mode="json", include={"version", "corpus", "styles", "method", "fan_out", "seed"})
        keep["batching"] = [self.compute.unit_size, self.compute.batch_size]  # seeds are drawn per unit and batch
        keep["corpus"]["path"] = str(Path(keep["corpus"]["path"]).resolve())
        if not keep["method"]["shapers"]:
            del keep["method"]["shapers"]  # the default: run ids of configs without shapers stay as they were
        if keep["corpus"]["max_clip_frames"] is None:
            del keep["corpus"]["max_clip_frames"]  # the default: run ids of configs that never set it stay as they were
        keep["corpus"]["content"] = self.corpus_fingerprint()
        if self.hooks.modules:  # what registers the hooks the method names
            keep["hooks"] = list(self.hooks.modules)
        digest = hashlib.sha256(json.dumps(keep, sort_keys=True).encode()).hexdigest()
        return f"run-{digest[:12]}"


def parse_override(item: str) -> tuple[list[str], Any]:
    """``a.b.c=value`` -> (["a", "b", "c"], value); the value is read as YAML (numbers, lists, null)."""
    if "=" not in item:
        raise ValueError(f"override {item!r} is not key.sub=value")
    key, raw = item.split("=", 1)
    parts = [p for p in key.strip().split(".") if p]
    if not parts:
        raise ValueError(f"override {item!r} has an empty key")
    if not raw.strip():
        return parts, ""
    try:
        return parts, yaml.safe_load(raw)
    except yaml.YAMLError as err:
        problem = getattr(err, "problem", None) or str(err).splitlines()[0]
        raise ValueError(f"override {item!r}: the value is not valid YAML ({problem})") from None


def apply_overrides(data: dict[str, Any], overrides: list[str]) -> dict[str, Any]:
    """Set each ``key.sub=value`` in a copy of ``data`` (intermediate tables are created)."""
    result = json.loads(json.dumps(data, default=str))
    for item in overrides:
        parts, value = parse_override(item)
        node = result
        for part in parts[:-1]:
            child = node.setdefault(part, {})
            if not isinstance(child, dict):
                raise ValueError(f"override {item!r}: {part} is not a table")
            node = child
        node[parts[-1]] = value
    return result


def read_config_file(path: Path) -> dict[str, Any]:
    """The raw mapping of a .yaml/.yml/.json config file; a syntax error names file:line:column."""
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise MotionDataError(str(path), f"cannot read the config ({err.__class__.__name__}: {err})") from None
    try:
        data = json.loads(text) if path.suffix == ".json" else yaml.safe_load(text)
    except json.JSONDecodeError as err:
        raise MotionDataError(f"{path}:{err.lineno}:{err.colno}", f"not valid JSON ({err.msg})") from None
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f"{path}:{mark.line + 1}:{mark.column + 1}" if mark is not None else str(path)
        problem = getattr(err, "problem", None) or str(err).splitlines()[0]
        raise MotionDataError(where, f"not valid YAML ({problem})") from None
    if not isinstance(data, dict):
        raise MotionDataError(str(path), "a run config must be a mapping at the top level")
    return data


def resolve_paths(config: RunConfig, base: Path) -> RunConfig:
    """Relative corpus, output, base-model, evaluator and example paths made absolute against ``base``."""

    def absolute(p: Path | None) -> Path | None:
        return None if p is None else (p if p.is_absolute() else (base / p)).resolve()

    styles = [
        style.model_copy(update={"examples": [_absolute_example(ex, base) for ex in style.examples]})
        for style in config.styles
    ]
    return config.model_copy(
        update={
            "corpus": config.corpus.model_copy(update={"path": absolute(config.corpus.path)}),
            "output": absolute(config.output),
            "base_models": config.base_models.resolved(absolute),
            "evaluators": absolute(config.evaluators),
            "styles": styles,
        }
    )


def _absolute_example(example: Any, base: Path) -> Any:
    source = Path(example.source)
    if source.suffix.lower() in (".npy", ".bvh") and not source.is_absolute():
        return example.model_copy(update={"source": str((base / source).resolve())})
    return example


def load_run_config(path: Path | None, overrides: list[str] | None = None, data: dict | None = None) -> RunConfig:
    """Read, override and validate a config; paths resolve against the file's folder (or the cwd)."""
    raw = read_config_file(path) if path is not None else dict(data or {})
    raw = apply_overrides(raw, overrides or [])
    base = path.resolve().parent if path is not None else Path.cwd()
    return resolve_paths(RunConfig.model_validate(raw), base)
