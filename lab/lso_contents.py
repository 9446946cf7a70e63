"""Which contents a leave-style-out row wins and loses: a unit's readings per (content, style), k = 1 by default.

    .venv/bin/python lab/lso_contents.py bench/lso/synthetic-fold1-shapers+dx9-posture-val.json [more units] [--k 3]

For each committed unit (``bench/bench_lso.py run``) it prints, per content of the scored clips and per held-out
style, how many transfers each judge reads as the style (``j1``, ``j2``) and how many keep their content (``c1``,
``c2``), over every draw, then the contents the content judges read instead. Why: the gathered table averages over
contents, and a step that loses one content (a walk read as a turn) looks like a small loss everywhere.
"""

from __future__ import annotations

import argparse
import json
from collections import Counter, defaultdict
from pathlib import Path

READS = (("style", "j1"), ("style_clip", "j2"), ("content", "c1"), ("content_pose", "c2"))


def table(unit_file: Path, k: int) -> tuple[dict[tuple[str, str], list[int]], Counter[tuple[str, str, str]]]:
    """(style, content) -> [j1, j2, c1, c2, n] counts, and (content, read as, judge) -> count of the misreads."""
    counts: dict[tuple[str, str], list[int]] = defaultdict(lambda: [0] * (len(READS) + 1))
    misread: Counter[tuple[str, str, str]] = Counter()
    for unit in json.loads(unit_file.read_text(encoding="utf-8"))["units"]:
        if unit["k"] != k:
            continue
        style = unit["style"]
        for i, content in enumerate(unit["truth_content"]):
            row = counts[(style, content)]
            for n, (judge, name) in enumerate(READS):
                read = unit["read"][judge][i]
                row[n] += read == (style if name.startswith("j") else content)
                if name.startswith("c") and read != content:
                    misread[(content, read, name)] += 1
            row[-1] += 1
    return counts, misread


def show(unit_file: Path, k: int) -> None:
    counts, misread = table(unit_file, k)
    styles = sorted({s for s, _ in counts})
    contents = sorted({c for _, c in counts})
    total = [sum(v[n] for v in counts.values()) for n in range(len(READS) + 1)]
    means = ", ".join(f"{name} {100 * total[n] / total[-1]:.1f}%" for n, (_, name) in enumerate(READS))
    print(f"{unit_file.name} (k = {k}): {means}; cells j1/j2 c1/c2 of n")
    print(f"{'':16}" + "".join(f"{s[:16]:>20}" for s in styles))
    for content in contents:
        cells = "".join("{:>6}/{:<3}{:>4}/{:<3}/{:<3}".format(*counts[(s, content)]) for s in styles)
        print(f"{content[:16]:16}{cells}")
    print("misread: " + ", ".join(f"{c} as {r} ({j}) {n}" for (c, r, j), n in misread.most_common(8)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("units", type=Path, nargs="+")
    parser.add_argument("--k", type=int, default=1)
    args = parser.parse_args()
    for unit_file in args.units:
        show(unit_file, args.k)


if __name__ == "__main__":
    main()
