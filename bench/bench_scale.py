"""A HumanML3D-size run through ``motionaug run`` (stats method, embedded local Ray): what the driver costs.

For each corpus size it writes a corpus in the HumanML3D layout (three captions per clip, as HumanML3D's
14,616 motions carry 44,970), runs ``motionaug run`` on it with ten styles in a child process, and reports:
planning seconds, the driver's peak resident memory (``ru_maxrss`` of the process that runs the command),
per-task overhead (fan-out wall time x CPUs minus the in-task seconds the markers record, per task), shard
count and sizes, and the transfer workers' peak memory. Driver memory that stays flat from 1,000 to 15,000
clips shows the corpus is streamed, not held by the driver.

Rendering is ~55 clips/s here (bench/RESULTS.md, section 3), so ``--base-clips`` clips are rendered once and
the larger corpora are copies of them under new ids (file copies, not links: the run reads every byte).

    .venv/bin/python bench/bench_scale.py --work WORK --clips 1000,5000,15000

Results go to stdout as JSON (and ``--out FILE``).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import yaml

REPO = Path(__file__).resolve().parents[1]
# Ten styles: the synthetic corpus's seven, and three more learnt from other example clips of three of them.
STYLE_EXAMPLES = {
    "proud": "proud",
    "depressed": "depressed",
    "old": "old",
    "childlike": "childlike",
    "angry": "angry",
    "strutting": "strutting",
    "sneaky": "sneaky",
    "elderly": "old",
    "furious": "angry",
    "sad": "depressed",
}
# Runs ``motionaug run`` and records the process's own peak RSS at exit (the driver of the embedded Ray).
DRIVER = """
import atexit, json, resource, sys
from pathlib import Path
record = Path(sys.argv[1])
sys.argv = ["motionaug", *sys.argv[2:]]
def _peak():
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    record.write_text(json.dumps({"driver_peak_rss_mb": rss}))
atexit.register(_peak)
from motionaug.workflows.cli import app
app()
"""


def render_base(folder: Path, clips: int) -> Path:
    from motionaug.augment.synth import generate_corpus

    if not (folder / "all.txt").is_file():
        generate_corpus(folder, clips, seed=0)
    return folder


def replicate(base: Path, out: Path, clips: int) -> Path:
    """A corpus of ``clips`` clips: clip ``i`` is a copy of base clip ``i % len(base)`` under id ``i`` (6 digits)."""
    if (out / "all.txt").is_file():
        return out
    base_ids = (base / "all.txt").read_text(encoding="utf-8").split()
    labels = {}
    for line in (base / "labels.jsonl").read_text(encoding="utf-8").splitlines():
        record = json.loads(line)
        labels[record["id"]] = record
    split_of = {i: name for name in ("train", "val", "test") for i in (base / f"{name}.txt").read_text().split()}
    tmp = out.with_name(out.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    (tmp / "new_joint_vecs").mkdir(parents=True)
    (tmp / "texts").mkdir()
    splits: dict[str, list[str]] = {"train": [], "val": [], "test": []}
    with open(tmp / "labels.jsonl", "w", encoding="utf-8") as handle:
        for i in range(clips):
            source, new = base_ids[i % len(base_ids)], f"{i:06d}"
            shutil.copyfile(base / "new_joint_vecs" / f"{source}.npy", tmp / "new_joint_vecs" / f"{new}.npy")
            shutil.copyfile(base / "texts" / f"{source}.txt", tmp / "texts" / f"{new}.txt")
            splits[split_of[source]].append(new)
            handle.write(json.dumps({**labels[source], "id": new}, sort_keys=True) + "\n")
    for name, ids in splits.items():
        (tmp / f"{name}.txt").write_text("".join(f"{i}\n" for i in ids), encoding="utf-8")
    (tmp / "all.txt").write_text("".join(f"{i:06d}\n" for i in range(clips)), encoding="utf-8")
    for name in ("Mean.npy", "Std.npy"):
        shutil.copyfile(base / name, tmp / name)
    tmp.rename(out)
    return out


def style_specs(base: Path) -> list[dict[str, Any]]:
    """Ten styles, each learnt from one walking clip of the base corpus in its synthetic style."""
    walking: dict[str, list[str]] = {}
    for line in (base / "labels.jsonl").read_text(encoding="utf-8").splitlines():
        record = json.loads(line)
        if record["content"] == "walk":
            walking.setdefault(record["style"], []).append(record["id"])
    used: dict[str, int] = {}
    specs = []
    for name, source_style in STYLE_EXAMPLES.items():
        n = used.get(source_style, 0)
        used[source_style] = n + 1
        clip = walking[source_style][n]
        specs.append(
            {
                "name": name,
                "words": {"adjective": name, "phrases": [f"in a {name} way"]},
                "examples": [{"source": clip, "description": f"a person walks in a {name} way"}],
            }
        )
    return specs


def write_config(path: Path, corpus: Path, out: Path, styles: list[dict[str, Any]], num_cpus: int) -> Path:
    data = {
        "version": 1,
        "corpus": {"path": str(corpus)},
        "styles": styles,
        "method": {"name": "stats"},
        "fan_out": {"per_clip": "all", "seed": 0},
        "compute": {"num_cpus": num_cpus, "batch_size": 32, "unit_size": 256},
        "output": str(out),
        "seed": 0,
    }
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return path


def rss_parts(pid: int) -> dict[str, int]:
    """kB of the process's resident memory by kind (anonymous heap, mapped files, shared memory)."""
    parts = {}
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith(("RssAnon", "RssFile", "RssShmem")):
                key, value = line.split(":")
                parts[key] = int(value.split()[0])
    except OSError:
        pass
    return parts


def run_driver(config: Path, record: Path, log: Path, extra: list[str]) -> tuple[float, dict[str, float]]:
    """``motionaug run CONFIG`` in a child process: its wall seconds, and its peak resident memory by kind in MB
    (sampled every 0.2 s; the exact peak, ``ru_maxrss``, lands in ``record``)."""
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0", "COLUMNS": "120"}
    command = [sys.executable, "-c", DRIVER, str(record), "run", str(config), *extra]
    start = time.perf_counter()
    peaks: dict[str, float] = {}
    with open(log, "w", encoding="utf-8") as handle:
        child = subprocess.Popen(command, stdout=handle, stderr=subprocess.STDOUT, env=env, cwd=REPO)
        while child.poll() is None:
            for key, kb in rss_parts(child.pid).items():
                peaks[key] = max(peaks.get(key, 0.0), kb / 1024)
            time.sleep(0.2)
    if child.returncode != 0:
        raise SystemExit(f"motionaug run failed ({child.returncode}); see {log}")
    return time.perf_counter() - start, {k: round(v, 1) for k, v in peaks.items()}


def measure(work: Path, base: Path, clips: int, num_cpus: int) -> dict[str, Any]:
    corpus = replicate(base, work / f"corpus-{clips}", clips)
    out = work / f"run-{clips}"
    shutil.rmtree(out, ignore_errors=True)
    config = write_config(work / f"run-{clips}.yaml", corpus, out, style_specs(base), num_cpus)
    record = work / f"driver-{clips}.json"
    load_before = os.getloadavg()[0]
    wall, parts = run_driver(config, record, work / f"run-{clips}.log", [])
    manifest = json.loads((out / "manifest.json").read_text(encoding="utf-8"))
    stages = manifest["stages"]
    shards = manifest["shards"]
    sizes = sorted((out / s["path"]).stat().st_size for s in shards)
    in_task = sum(s["seconds"] for s in shards) + sum(a["seconds"] for a in manifest["artifacts"].values())
    fan_out_wall = max(stages["prepare"]["seconds"], stages["transfer"]["seconds"])
    tasks = len(shards) + len(manifest["artifacts"])
    captions = sum(len((corpus / "texts" / f"{i:06d}.txt").read_text().splitlines()) for i in range(clips))
    return {
        "clips": clips,
        "captions": captions,
        "styles": len(manifest["artifacts"]),
        "rows": manifest["rows"],
        "command_seconds": round(wall, 1),
        "plan_seconds": round(stages["plan"]["seconds"], 2),
        "plan_bytes": (out / "plan.json").stat().st_size,
        "driver_peak_rss_mb": round(json.loads(record.read_text())["driver_peak_rss_mb"], 1),
        "driver_peak_mb_by_kind": parts,
        "transfer_worker_peak_rss_mb": round(max(s["peak_rss_mb"] for s in shards), 1),
        "fan_out_seconds": round(fan_out_wall, 1),
        "tasks": tasks,
        "overhead_per_task_s": round((fan_out_wall * num_cpus - in_task) / tasks, 3),
        "transfer_task_mean_s": round(sum(s["seconds"] for s in shards) / len(shards), 2),
        "shards": len(shards),
        "shard_mb_min_median_max": [round(x / 1e6, 2) for x in (sizes[0], sizes[len(sizes) // 2], sizes[-1])],
        "shards_mb_total": round(sum(sizes) / 1e6, 1),
        "shard_bytes_per_row": round(sum(sizes) / max(manifest["rows"], 1)),
        "clips_per_second": round(manifest["rows"] / stages["transfer"]["seconds"], 1),
        "load_average_before": round(load_before, 2),
        "load_average_after": round(os.getloadavg()[0], 2),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True, help="Scratch folder (corpora and runs; kept).")
    parser.add_argument("--clips", default="1000,5000,15000", help="Corpus sizes, comma-separated.")
    parser.add_argument("--base-clips", type=int, default=1000, help="Clips rendered; larger corpora copy them.")
    parser.add_argument("--num-cpus", type=int, default=2)
    parser.add_argument("--out", type=Path, default=None, help="Also write the JSON here.")
    args = parser.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    base = render_base(args.work / "base", args.base_clips)
    results = []
    for clips in (int(c) for c in args.clips.split(",")):
        results.append(measure(args.work, base, clips, args.num_cpus))
        print(json.dumps(results[-1]), flush=True)
    if args.out:
        args.out.write_text(json.dumps(results, indent=1), encoding="utf-8")


if __name__ == "__main__":
    main()
