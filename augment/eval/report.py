"""The evaluation of a run as ``report.md`` and a self-contained ``report.html`` (plots embedded as PNG).

Plots are drawn with matplotlib's object API on an Agg canvas (never pyplot), so writing a report
leaves matplotlib's global state alone and needs no display. The markdown links the same PNGs,
written to ``report_plots/`` beside it; the HTML embeds them (base64) so it can be mailed as one file.
How to read the report: docs/report.md.
"""

from __future__ import annotations

import base64
import html
import io
import re
import shlex
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from motionaug.augment.eval.evaluation import PAPER_REFERENCE, Evaluation, column
from motionaug.augment.io import atomic_path, atomic_write_text

REPORT_MD = "report.md"
REPORT_HTML = "report.html"
VIEWER_HTML = "viewer.html"  # augment.render.viewer writes it beside the report
PLOTS_DIR = "report_plots"
N_WORST = 5

# (attribute, header, kind): kind picks the number format
SUMMARY_COLUMNS = [
    ("clips", "clips", "int"),
    ("sra", "SRA", "pct"),
    ("cra", "CRA", "pct"),
    ("trained_on", "clips the evaluators trained on", "int"),
    ("sra_held_out", "SRA held out", "pct"),
    ("cra_held_out", "CRA held out", "pct"),
    ("fmd", "FMD", "num"),
    ("diversity", "diversity", "num"),
    ("diversity_real", "diversity (real)", "num"),
    ("foot_skating", "foot skating", "pct"),
    ("foot_skating_source", "foot skating (content)", "pct"),
    ("contact_agreement", "contact agreement", "pct"),
    ("mpjpe", "MPJPE (m)", "m"),
    ("method_style_score", "method style score", "num"),
    ("method_content_score", "method content score", "num"),
]

# per-clip score -> (label, True when higher is better): what the distributions and worst lists show
CLIP_SCORES = {
    "style_prob": ("style classifier p(target style)", True),
    "content_prob": ("content classifier p(content)", True),
    "method_style_score": ("method style score", True),
    "method_content_score": ("method content score", True),
    "foot_skating": ("foot skating ratio", False),
    "contact_agreement": ("foot-contact agreement with content", True),
    "mpjpe": ("MPJPE to paired ground truth (m)", False),
}


def format_value(kind: str, value: float | int | None) -> str:
    """How the report prints a number: percentages with 2 decimals, metres with 3, others with 3 significant."""
    if value is None or (isinstance(value, float) and not np.isfinite(value)):
        return "–"
    if kind == "int":
        return str(int(value))
    if kind == "pct":
        return f"{100 * value:.2f}%"
    if kind == "m":
        return f"{value:.3f}"
    return f"{value:.4g}"


@dataclass
class Plot:
    name: str
    title: str
    png: bytes


@dataclass
class WorstClip:
    output_id: str
    style: str
    value: float
    command: str


# ---- plots -----------------------------------------------------------------------------------------


def _png(figure: Figure) -> bytes:
    canvas = FigureCanvasAgg(figure)
    buffer = io.BytesIO()
    canvas.print_png(buffer)
    return buffer.getvalue()


def score_distributions(evaluation: Evaluation) -> Plot | None:
    """One histogram per per-clip score that has values, styles overlaid."""
    shown = [name for name in CLIP_SCORES if np.isfinite(column(evaluation.scores, name)).any()]
    if not shown:
        return None
    cols = min(3, len(shown))
    rows = (len(shown) + cols - 1) // cols
    figure = Figure(figsize=(4.2 * cols, 3.0 * rows), dpi=100, layout="constrained")
    styles = sorted({r["style"] for r in evaluation.scores})
    for i, name in enumerate(shown):
        ax = figure.add_subplot(rows, cols, i + 1)
        values = column(evaluation.scores, name)
        finite = values[np.isfinite(values)]
        bins = np.linspace(finite.min(), finite.max() + 1e-9, 16)
        for style in styles:
            mine = column([r for r in evaluation.scores if r["style"] == style], name)
            ax.hist(mine[np.isfinite(mine)], bins=bins, alpha=0.55, label=style)
        ax.set_title(CLIP_SCORES[name][0], fontsize=9)
        ax.set_ylabel("clips", fontsize=8)
        ax.tick_params(labelsize=7)
    figure.axes[0].legend(fontsize=7)
    return Plot("scores", "Per-clip score distributions", _png(figure))


def loss_plot(evaluation: Evaluation) -> Plot | None:
    """Fine-tuning loss per style (every named loss; ``total`` drawn bold)."""
    if not evaluation.loss_curves:
        return None
    figure = Figure(figsize=(6.5, 3.6), dpi=100, layout="constrained")
    ax = figure.add_subplot(1, 1, 1)
    for style, curve in sorted(evaluation.loss_curves.items()):
        keys = sorted({k for point in curve for k in point} - {"step", "seconds"})
        steps = np.array([p.get("step", i) for i, p in enumerate(curve)])
        for key in keys:
            values = np.array([p.get(key, np.nan) for p in curve])
            ax.plot(steps, values, label=f"{style}: {key}", linewidth=2.0 if key == "total" else 1.0)
    ax.set_xlabel("step")
    ax.set_ylabel("loss")
    if all(min((p.get("total", 1.0) for p in c), default=1.0) > 0 for c in evaluation.loss_curves.values()):
        ax.set_yscale("log")
    ax.legend(fontsize=7)
    ax.set_title("Fine-tuning loss per style", fontsize=10)
    return Plot("loss", "Fine-tuning loss curves", _png(figure))


def stage_plot(evaluation: Evaluation) -> Plot | None:
    if not evaluation.stages:
        return None
    names = list(evaluation.stages)
    seconds = [evaluation.stages[n]["seconds"] for n in names]
    figure = Figure(figsize=(6.0, 0.45 * len(names) + 1.0), dpi=100, layout="constrained")
    ax = figure.add_subplot(1, 1, 1)
    ax.barh(names[::-1], seconds[::-1], color="#4c72b0")
    ax.set_xlabel("seconds (wall clock)")
    ax.set_title("Time per stage", fontsize=10)
    return Plot("stages", "Time per stage", _png(figure))


# ---- content -----------------------------------------------------------------------------------------


def preview_command(run_dir: Path, source_id: str, style: str) -> str:
    return f"motionaug preview {shlex.quote(str(run_dir))} --clip {shlex.quote(source_id)} --style {shlex.quote(style)}"


def worst_clips(evaluation: Evaluation, name: str, n: int = N_WORST) -> list[WorstClip]:
    """The ``n`` clips scoring worst on one per-clip score (lowest when higher is better)."""
    higher_better = CLIP_SCORES[name][1]
    scored = [(r, r[name]) for r in evaluation.scores if r.get(name) is not None]
    scored.sort(key=lambda pair: (pair[1] if higher_better else -pair[1], pair[0]["output_id"]))
    return [
        WorstClip(r["output_id"], r["style"], float(v), preview_command(evaluation.run_dir, r["source_id"], r["style"]))
        for r, v in scored[:n]
    ]


def summary_rows(evaluation: Evaluation) -> list[list[str]]:
    """Table cells: one row per style, then ``all``, then the seed paper's published row."""
    rows = [
        [s.style, *[format_value(kind, getattr(s, attr)) for attr, _, kind in SUMMARY_COLUMNS]]
        for s in [*evaluation.styles, evaluation.overall]
    ]
    paper = {"sra": PAPER_REFERENCE["sra"], "cra": PAPER_REFERENCE["cra"]}
    rows.append(
        [
            f"{PAPER_REFERENCE['name']} (published)",
            *[format_value(kind, paper.get(attr)) for attr, _, kind in SUMMARY_COLUMNS],
        ]
    )
    return rows


def reference_note() -> str:
    return (
        f"The last row is the seed paper's published result ({PAPER_REFERENCE['name']}): SRA "
        f"{format_value('pct', PAPER_REFERENCE['sra'])}, CRA {format_value('pct', PAPER_REFERENCE['cra'])}; "
        "without the semantic-guidance loss L_s their SRA drops to "
        f"{format_value('pct', PAPER_REFERENCE['sra_without_ls'])}. "
        "Their classifiers were trained on the Xia dataset and differ from ours: compare trends, not absolute values."
    )


def _info_lines(evaluation: Evaluation) -> list[tuple[str, str]]:
    return [
        ("run", f"{evaluation.run_id} ({evaluation.run_dir})"),
        ("method", evaluation.method),
        ("stylized clips", str(evaluation.rows)),
        ("rejected", str(evaluation.rejects)),
        ("corpus", evaluation.corpus),
        ("FMD reference", evaluation.reference),
        ("base models", evaluation.base_models or "none (classifier metrics not measured)"),
        ("held out", "NOT HELD OUT: " + "; ".join(evaluation.leaks) if evaluation.leaks else "yes"),
    ]


def _timing_rows(evaluation: Evaluation) -> list[list[str]]:
    rows = [
        [name, f"{t['seconds']:.1f}", str(int(t["tasks"])), str(int(t["skipped"]))]
        for name, t in evaluation.stages.items()
    ]
    if evaluation.throughput is not None:
        rows.append(["throughput", f"{evaluation.throughput:.2f} stylized clips/s over the transfer stage", "", ""])
    return rows


# ---- markdown ------------------------------------------------------------------------------------


def _md_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    def cell(text: str) -> str:
        return text.replace("|", "\\|")

    lines = ["| " + " | ".join(cell(h) for h in header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(cell(c) for c in row) + " |" for row in rows]
    return lines + [""]


def render_markdown(evaluation: Evaluation, plots: dict[str, Plot]) -> str:
    lines = [f"# Evaluation of run {evaluation.run_id}", ""]
    lines += [f"- **{k}**: {v}" for k, v in _info_lines(evaluation)] + [""]
    lines += [f"[The 3D viewer]({VIEWER_HTML}): every stylized clip beside its content clip, worst first.", ""]
    lines += ["## Summary", ""]
    lines += _md_table(["style", *[h for _, h, _ in SUMMARY_COLUMNS]], summary_rows(evaluation))
    lines += [reference_note(), ""]
    if evaluation.notes:
        lines += ["### Not measured", ""] + [f"- {note}" for note in evaluation.notes] + [""]
    if "scores" in plots:
        lines += ["## Per-clip scores", "", f"![per-clip scores]({PLOTS_DIR}/scores.png)", ""]
    lines += ["## Worst clips", ""]
    for name, (label, higher_better) in CLIP_SCORES.items():
        worst = worst_clips(evaluation, name)
        if worst:
            lines += [f"### {label} ({'lowest' if higher_better else 'highest'})", ""]
            lines += _md_table(
                ["output id", "style", "value", "look at it"],
                [[w.output_id, w.style, f"{w.value:.4g}", f"`{w.command}`"] for w in worst],
            )
    lines += ["## Fine-tuning", ""]
    lines += (
        [f"![loss curves]({PLOTS_DIR}/loss.png)", ""]
        if "loss" in plots
        else ["No loss curves in the styles' artifact.json.", ""]
    )
    lines += ["## Time per stage", ""]
    lines += _md_table(["stage", "seconds", "tasks", "skipped"], _timing_rows(evaluation))
    if "stages" in plots:
        lines += [f"![time per stage]({PLOTS_DIR}/stages.png)", ""]
    lines += ["How to read this report: docs/report.md in the motionaug repository.", ""]
    return "\n".join(lines)


# ---- html ------------------------------------------------------------------------------------------


_CSS = """body{font-family:system-ui,sans-serif;margin:2em auto;max-width:1200px;color:#222}
table{border-collapse:collapse;margin:0.5em 0 1.2em;font-size:0.9em}td,th{border:1px solid #ccc;padding:3px 8px}
th{background:#f0f0f0}td.num{text-align:right}tr.paper td{color:#666;font-style:italic}tr.all td{font-weight:bold}
code{font-size:0.85em;background:#f6f6f6}img{max-width:100%}.note{color:#8a5a00}"""


_NUMBER = re.compile(r"[-+0-9.e%–]+( clips/s.*)?")


def _html_table(header: Sequence[str], rows: Sequence[Sequence[str]], row_classes: Sequence[str] = ()) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = []
    for i, row in enumerate(rows):
        klass = f' class="{row_classes[i]}"' if i < len(row_classes) and row_classes[i] else ""
        cells = "".join(
            f'<td class="num">{c}</td>' if j and _NUMBER.fullmatch(c) else f"<td>{c}</td>" for j, c in enumerate(row)
        )
        body.append(f"<tr{klass}>{cells}</tr>")
    return f"<table><tr>{head}</tr>{''.join(body)}</table>"


def _img(plot: Plot) -> str:
    data = base64.b64encode(plot.png).decode("ascii")
    return f'<img alt="{html.escape(plot.title)}" src="data:image/png;base64,{data}">'


def render_html(evaluation: Evaluation, plots: dict[str, Plot]) -> str:
    e = html.escape
    parts = [
        f"<!doctype html><html><head><meta charset='utf-8'><title>Evaluation of run {e(evaluation.run_id)}</title>",
        f"<style>{_CSS}</style></head><body>",
        f"<h1>Evaluation of run {e(evaluation.run_id)}</h1><ul>",
    ]
    parts += [f"<li><b>{e(k)}</b>: {e(v)}</li>" for k, v in _info_lines(evaluation)] + ["</ul>"]
    parts.append(
        f"<p><a href='{VIEWER_HTML}'>Open the 3D viewer</a>: every stylized clip beside its content clip, worst limb"
        f" agreement first (written by <code>motionaug evaluate</code> and <code>motionaug view</code>).</p>"
    )
    parts.append("<h2>Summary</h2>")
    rows = [[e(c) for c in row] for row in summary_rows(evaluation)]
    classes = [""] * len(evaluation.styles) + ["all", "paper"]
    parts += [
        _html_table(["style", *[h for _, h, _ in SUMMARY_COLUMNS]], rows, classes),
        f"<p>{e(reference_note())}</p>",
    ]
    if evaluation.notes:
        parts += ["<h3>Not measured</h3><ul>"] + [f"<li class='note'>{e(n)}</li>" for n in evaluation.notes] + ["</ul>"]
    if "scores" in plots:
        parts += ["<h2>Per-clip scores</h2>", _img(plots["scores"])]
    parts.append("<h2>Worst clips</h2>")
    for name, (label, higher_better) in CLIP_SCORES.items():
        worst = worst_clips(evaluation, name)
        if worst:
            parts.append(f"<h3>{e(label)} ({'lowest' if higher_better else 'highest'})</h3>")
            cells = [[e(w.output_id), e(w.style), f"{w.value:.4g}", f"<code>{e(w.command)}</code>"] for w in worst]
            parts.append(_html_table(["output id", "style", "value", "look at it"], cells))
    parts.append("<h2>Fine-tuning</h2>")
    parts.append(_img(plots["loss"]) if "loss" in plots else "<p>No loss curves in the styles' artifact.json.</p>")
    parts += [
        "<h2>Time per stage</h2>",
        _html_table(["stage", "seconds", "tasks", "skipped"], [[e(c) for c in r] for r in _timing_rows(evaluation)]),
    ]
    if "stages" in plots:
        parts.append(_img(plots["stages"]))
    parts.append("<p>How to read this report: docs/report.md in the motionaug repository.</p></body></html>")
    return "\n".join(parts)


# ---- writing -------------------------------------------------------------------------------------


def make_plots(evaluation: Evaluation) -> dict[str, Plot]:
    plots = [score_distributions(evaluation), loss_plot(evaluation), stage_plot(evaluation)]
    return {p.name: p for p in plots if p is not None}


def write_report(evaluation: Evaluation, out_dir: Path | None = None) -> tuple[Path, Path]:
    """``report.md`` (+ ``report_plots/*.png``) and ``report.html`` into the run folder; returns both paths."""
    folder = Path(out_dir) if out_dir is not None else evaluation.run_dir
    plots = make_plots(evaluation)
    for plot in plots.values():
        with atomic_path(folder / PLOTS_DIR / f"{plot.name}.png") as tmp:
            tmp.write_bytes(plot.png)
    md, page = folder / REPORT_MD, folder / REPORT_HTML
    atomic_write_text(md, render_markdown(evaluation, plots))
    atomic_write_text(page, render_html(evaluation, plots))
    return md, page
