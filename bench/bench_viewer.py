"""The 3D viewer on a 10,000-clip run: disk, time to the first drawn frame, clip-list latency and JS heap, measured
in headless Chromium (the system's ``chromium`` through playwright, from ``file://``).

The data: ``--bases`` synthetic clips (``corpus synth``), each used as ``--reuse`` source clips under new ids, each
source with ``--styles`` stylized versions (the source's motion retimed by a style-specific factor, as a slow or fast
style would be), written with the viewer's own encoders and chunking: 10,000 stylized clips and 2,500 content clips
by default. Page timings are medians of ``--repeats`` fresh pages.

    .venv/bin/python bench/bench_viewer.py --work WORK
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import time
from pathlib import Path

import numpy as np

from motionaug.augment.corpus import Corpus
from motionaug.augment.motion.features import features_to_joints
from motionaug.augment.render.viewer import (
    CLIPS_PER_CHUNK,
    LIMB_AGREEMENT,
    ChunkWriter,
    ViewerEntry,
    contact_digits,
    encode_joints,
    limb_agreement,
    limb_tracks,
    make_index,
    start_folder,
    write_index,
)
from motionaug.augment.synth import generate_corpus
from motionaug.schemas.skeleton import T2M

STYLE_SPEED = {"proud": 1.0, "old": 0.8, "depressed": 0.7, "childlike": 1.25}


def retimed(features: np.ndarray, factor: float) -> np.ndarray:
    """The clip played ``factor`` times as fast (linear resampling of every feature)."""
    n = max(3, int(round(len(features) / factor)))
    src, dst = np.linspace(0, 1, len(features)), np.linspace(0, 1, n)
    return np.stack([np.interp(dst, src, features[:, k]) for k in range(features.shape[1])], axis=1)


def record(features: np.ndarray, captions: list[str]) -> dict:
    joints = features_to_joints(features)
    return {**encode_joints(joints), "fps": 20.0, "contacts": contact_digits(joints, T2M), "captions": captions}


def build(work: Path, bases: int, reuse: int, styles: list[str]) -> dict:
    corpus = work / "corpus"
    if not corpus.exists():
        generate_corpus(corpus, bases, seed=0)
    started = time.perf_counter()
    out = work / "viewer-run"
    chunks = ChunkWriter(start_folder(out) / "chunks", CLIPS_PER_CHUNK)
    entries: list[ViewerEntry] = []
    source_chunks: dict[str, int] = {}
    rng = np.random.default_rng(0)
    for clip in Corpus(corpus):
        texts = [c.text for c in clip.captions]
        styled = {s: retimed(clip.motion, STYLE_SPEED[s]) for s in styles}
        content_rec = record(clip.motion, texts)
        style_recs = {s: record(m, [f"{t} ({s})" for t in texts]) for s, m in styled.items()}
        agreement = {s: limb_agreement(limb_tracks(clip.motion), limb_tracks(m)) for s, m in styled.items()}
        for copy in range(reuse):
            source = f"{clip.id}-{copy}"
            source_chunks[source] = chunks.add(f"src:{source}", content_rec)
            for s in styles:
                entry = ViewerEntry(f"{source}__{s}", source, s, clip.content or "", style_recs[s]["n"], "", texts[0])
                entry.caption = style_recs[s]["captions"][0]
                score = agreement[s]
                entry.scores = {LIMB_AGREEMENT: None if score is None else score - 0.2 * rng.random()}
                entry.chunk = chunks.add(entry.id, {**style_recs[s], "before": texts})
                entries.append(entry)
    chunks.flush()
    index = make_index("run", "bench", entries, {LIMB_AGREEMENT: ("limb agreement", True)}, LIMB_AGREEMENT, T2M)
    index["source_chunks"] = source_chunks
    summary = write_index(out, index, "bench: 10,000-clip viewer", chunks)
    return {
        "page": summary.page,
        "clips": summary.clips,
        "sources": len(source_chunks),
        "chunks": summary.chunks,
        "bytes": summary.bytes,
        "index_bytes": (out / "viewer" / "index.js").stat().st_size,
        "build_seconds": time.perf_counter() - started,
    }


def measure(page_path: Path, chromium: str, repeats: int) -> dict:
    from playwright.sync_api import sync_playwright

    first, selects, searches, heaps, before_gc = [], [], [], [], []
    with sync_playwright() as manager:
        browser = manager.chromium.launch(executable_path=chromium)
        for _ in range(repeats):
            page = browser.new_page(viewport={"width": 1280, "height": 800})
            page.goto(page_path.resolve().as_uri())
            page.wait_for_function("window.motionViewer && motionViewer.firstFrameMs !== null", timeout=60_000)
            first.append(page.evaluate("motionViewer.firstFrameMs"))  # ms since navigation start
            ids = page.evaluate("motionViewer.index.clips.id")
            picks = [ids[i] for i in np.random.default_rng(len(first)).choice(len(ids), 20, replace=False)]
            for clip_id in picks:  # a clip from a chunk not loaded yet: script tag, decode, first draw
                t = page.evaluate(
                    """id => new Promise(done => { const t0 = performance.now();
                       motionViewer.select(id, () => done(performance.now() - t0)); })""",
                    clip_id,
                )
                selects.append(t)
            t = page.evaluate(
                """() => new Promise(done => { const s = document.getElementById('search'), t0 = performance.now();
                   s.value = 'old'; s.dispatchEvent(new Event('input'));
                   const wait = () => document.getElementById('count').textContent.startsWith('10000 of')
                     ? requestAnimationFrame(wait) : done(performance.now() - t0 - 120); wait(); })"""
            )
            searches.append(t)  # filtering and re-sorting the list, less the input's 120 ms debounce
            cdp = page.context.new_cdp_session(page)
            before_gc.append(cdp.send("Runtime.getHeapUsage")["usedSize"] / 2**20)
            cdp.send("HeapProfiler.collectGarbage")
            heaps.append(cdp.send("Runtime.getHeapUsage")["usedSize"] / 2**20)
            page.close()
        browser.close()
    return {
        "first_frame_ms": statistics.median(first),
        "first_frame_ms_all": first,
        "select_ms_median": statistics.median(selects),
        "select_ms_p90": float(np.percentile(selects, 90)),
        "search_ms_median": statistics.median(searches),
        "js_heap_mb_max": max(heaps),
        "js_heap_mb_before_gc_max": max(before_gc),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--bases", type=int, default=250)
    parser.add_argument("--reuse", type=int, default=10)
    parser.add_argument("--styles", default="proud,old,depressed,childlike")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--chromium", default=os.environ.get("MOTIONAUG_CHROMIUM") or shutil.which("chromium"))
    args = parser.parse_args()
    if not args.chromium:
        raise SystemExit("no chromium on PATH (make browser, or --chromium PATH)")
    built = build(args.work, args.bases, args.reuse, args.styles.split(","))
    measured = measure(built["page"], args.chromium, args.repeats)
    result = {**built, **measured, "page": str(built["page"]), "load_average": os.getloadavg()}
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
