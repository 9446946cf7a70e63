"""Everything a run can check before it claims its folder or starts Ray: one line and exit 2 when a check fails.

``preflight`` runs the config checks of ``pipeline.check_config`` (corpus, example files, the method and its
params), then what a run used to find out later, after its folder was claimed or while Ray waited: the split
files, the style examples themselves (found, long enough, described with the style's words), caption words a
HumanML3D caption line cannot hold, the resources each stage asks for against the machine the embedded Ray runs
on, the output folder, whether the corpus filters select any clip (``check_selection``), and whether a cluster
given by address answers at all (``probe_address``). A cluster's own
resources are checked once Ray has joined it (``ray_executor.RayBackend``), from the cluster's node list.
"""

from __future__ import annotations

import os
import socket
from pathlib import Path

from motionaug.augment.corpus import Corpus
from motionaug.augment.corpus.style_examples import load_style_examples
from motionaug.augment.methods.base import StyleTransferMethod
from motionaug.schemas.errors import MotionConfigError, MotionDataError
from motionaug.schemas.run_config import RunConfig
from motionaug.workflows.pipeline import (
    Resources,
    check_config,
    empty_selection,
    keep_clip,
    over_limit,
    stage_resources,
)

CAPTION_SEPARATORS = ("#", "\n", "\r")  # a HumanML3D caption line is ``text#tokens#start#end``


def preflight(config: RunConfig, local: bool | None = None) -> StyleTransferMethod:
    """Every check that needs no Ray and writes nothing; raises ``MotionConfigError`` (exit 2) naming the setting.

    ``local``: the run starts an embedded Ray on this machine (default: when ``compute.address`` is None), so its
    resource requests are checked against this machine; a cluster's are checked against its own nodes."""
    try:
        method = check_config(config)
    except MotionConfigError:
        raise
    except MotionDataError as err:
        raise MotionConfigError(err.source, err.reason) from None
    check_output(config.output)
    check_split_files(config)
    check_style_words(config)
    check_examples(config)
    if local if local is not None else config.compute.address is None:
        check_local_resources(config, method.trains)
    return method


def check_selection(config: RunConfig) -> None:
    """The corpus filters select at least one readable clip within the clip limit, found by reading the corpus
    until the first such clip (the whole corpus only when there is none): raises the plan stage's own
    ``MotionDataError`` (exit 1) before the run claims its folder. ``allow_empty`` runs skip it."""
    if config.allow_empty:
        return
    corpus = Corpus(config.corpus.path, split=config.corpus.split)
    readable = 0
    too_long = []
    for clip in corpus:
        readable += 1
        if (reject := over_limit(clip, config)) is not None:
            too_long.append(reject)
        elif keep_clip(clip, config):
            return
    raise empty_selection(config, readable - len(too_long), corpus.rejects + too_long)


def check_output(output: Path) -> None:
    """The run folder can be a folder: not a file, not under a file."""
    for path in (output, *output.parents):
        if path.exists():
            if not path.is_dir():
                where = "--out" if path == output else f"--out {output}"
                raise MotionConfigError(where, f"{path} is a file; a run needs a folder")
            return


def check_split_files(config: RunConfig) -> None:
    """``corpus.split`` and ``corpus.pool_split`` name split files the (HumanML3D) corpus has."""
    corpus = config.corpus.path
    if not corpus.is_dir() or not (corpus / "new_joint_vecs").is_dir():
        return
    for name in ("split", "pool_split"):
        split = getattr(config.corpus, name)
        if split is not None and not (corpus / f"{split}.txt").is_file():
            raise MotionConfigError(f"config corpus.{name}", f"{corpus / f'{split}.txt'} not found")


def check_style_words(config: RunConfig) -> None:
    """Style words and example descriptions become caption text: none may hold a caption line's separators."""
    for i, style in enumerate(config.styles):
        texts = {"words.adjective": style.words.adjective, "words.adverb": style.words.adverb or ""}
        texts |= {f"words.phrases[{k}]": phrase for k, phrase in enumerate(style.words.phrases)}
        texts |= {f"examples[{k}].description": ex.description for k, ex in enumerate(style.examples)}
        for where, text in texts.items():
            bad = next((c for c in CAPTION_SEPARATORS if c in text), None)
            if bad is not None:
                reason = f"{text!r} holds {bad!r}, which a HumanML3D caption line cannot (it separates its fields)"
                raise MotionConfigError(f"config styles[{i}].{where}", reason)


def check_examples(config: RunConfig) -> None:
    """Every style example loads as the prepare stage will load it: found, long enough, its description naming
    the style, its named reference in the corpus. A clip id is looked up in the whole corpus (an example may come
    from another split)."""
    corpus = Corpus(config.corpus.path)
    for i, style in enumerate(config.styles):
        for j, example in enumerate(style.examples):
            if example.reference is not None and corpus.get(example.reference) is None:
                where = f"config styles[{i}].examples[{j}].reference"
                raise MotionConfigError(where, f"clip id {example.reference!r} is not in the corpus")
            if Path(example.source).suffix.lower() in (".npy", ".bvh"):
                continue
            if corpus.get(example.source) is None:
                where = f"config styles[{i}].examples[{j}].source"
                reason = f"clip id {example.source!r} is not in the corpus (nor a .npy/.bvh file)"
                raise MotionConfigError(where, reason)
        try:
            load_style_examples(style, corpus.get)
        except MotionDataError as err:
            raise MotionConfigError(f"config styles[{i}]", str(err)) from None


def machine_resources() -> dict[str, float]:
    """CPUs this process may use and GPUs torch sees: what an embedded Ray on this machine can offer."""
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        cpus = os.cpu_count() or 1
    import torch

    return {"CPU": float(cpus), "GPU": float(torch.cuda.device_count())}


def check_local_resources(config: RunConfig, trains: bool, machine: dict[str, float] | None = None) -> None:
    """``compute.num_cpus`` within the machine; every stage's request within what the embedded Ray will have."""
    machine = machine if machine is not None else machine_resources()
    cores = int(machine["CPU"])
    asked = config.compute.num_cpus
    if asked is not None and asked > cores:
        raise MotionConfigError("config compute.num_cpus", f"{asked} CPUs asked, but this machine has {cores}")
    offer = {"CPU": float(asked if asked is not None else cores), "GPU": machine["GPU"]}
    check_requests(config, trains, [offer], "the embedded Ray on this machine has", bool(asked))


def check_cluster_resources(config: RunConfig, trains: bool, nodes: list[dict[str, float]]) -> None:
    """Every stage's request within what one alive node of the cluster has (a submitted run's check, from the
    cluster's own node list; a cluster with an autoscaler is not checked, as it may add the node)."""
    check_requests(config, trains, nodes, "the cluster's nodes have", False)


def check_requests(config: RunConfig, trains: bool, nodes: list[dict[str, float]], whose: str, capped: bool) -> None:
    """One line naming the setting when a stage asks for more of a resource than any of ``nodes`` has."""
    for stage, request in stage_resources(config, trains).items():
        problem = unfit(request, nodes)
        if problem is not None:
            setting, amount, kind, most = problem
            has = "none" if most == 0 else f"{most:g}" + (" (compute.num_cpus)" if kind == "CPU" and capped else "")
            if most and len(nodes) > 1:
                has = f"at most {has} per node"
            asks = f"{stage} tasks ask for {amount:g} {kind}{plural(amount)} each"
            raise MotionConfigError(f"config {setting}", f"{asks}, but {whose} {has}")


def plural(amount: float) -> str:
    return "" if amount == 1 else "s"


def unfit(request: Resources, nodes: list[dict[str, float]]) -> tuple[str, float, str, float] | None:
    """(setting, amount asked, resource, the most any node has) when no node has what ``request`` asks for."""
    asks = (("CPU", request.cpus, request.cpu_setting), ("GPU", request.gpus, request.gpu_setting))
    for kind, amount, setting in asks:
        most = max((node.get(kind, 0.0) for node in nodes), default=0.0)
        if amount > 0 and amount > most:
            return setting, amount, kind, most
    return None


def probe_address(address: str, timeout_s: float) -> None:
    """Fail in ``timeout_s`` with one line when nothing listens at a cluster's ``HOST:PORT`` (``ray://`` too);
    ``auto`` and ``local`` are Ray's to resolve."""
    text = address.strip()
    where = f"--address {address}"
    if text in ("auto", "local"):
        return
    scheme, _, hostport = text.rpartition("://")
    if scheme and scheme.lower() != "ray":
        reason = "is a URL; a run joins a cluster by its GCS address HEAD:6379 (or ray://HEAD:10001)"
        if scheme.lower() in ("http", "https"):
            reason += "; the dashboard URL is for `motionaug submit`"
        raise MotionConfigError(where, reason)
    host, _, port = hostport.split("/", 1)[0].rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise MotionConfigError(where, "not HOST:PORT (the cluster's GCS address, e.g. HEAD:6379)")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s):
            pass
    except OSError as err:
        reason = f"no answer in {timeout_s:g} s" if isinstance(err, TimeoutError) else (err.strerror or str(err))
        reason = f"cannot reach the Ray cluster ({reason.lower()}; is it up and the port right?)"
        raise MotionDataError(where, reason) from None
