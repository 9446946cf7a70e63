"""``motionaug evaluate`` on a tiny real run: report files, numbers recomputed directly, export by score.

The run is 16 synthetic clips x 2 styles of the ``stats`` method, made by calling the stages in this
process (no Ray); the base models are two tiny classifiers trained for a few epochs (their accuracy is
irrelevant here: the test checks that the report's numbers are the ones the metrics give).
"""

from __future__ import annotations

import base64
import re
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import torch
from fixtures.evaluation.tiny_run import add_loss_curve, build_base_models, build_run, make_corpus
from typer.testing import CliRunner

from motionaug.augment.corpus import Corpus
from motionaug.augment.eval.evaluation import evaluate_run, load_classifiers, paired_ground_truth
from motionaug.augment.eval.report import format_value
from motionaug.augment.metrics import (
    diversity,
    foot_contact_accuracy,
    foot_contacts_from_joints,
    foot_skating_ratio,
    frechet_distance,
    mpjpe,
    recognition_accuracy,
)
from motionaug.augment.motion.batch import pad_batch
from motionaug.augment.motion.features import features_to_joints
from motionaug.augment.outputs.run_dir import SCORES_FILE, RunDir
from motionaug.augment.outputs.shards import iter_shard_rows, row_motion
from motionaug.schemas.skeleton import T2M
from motionaug.workflows.cli import app

STYLE_NAMES = ["proud", "old"]
CURVE = [{"step": i, "l_rec": 1.0 / (i + 1), "l_s": 0.3 / (i + 1), "total": 1.3 / (i + 1)} for i in range(20)]


@pytest.fixture(scope="module")
def tiny(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    torch.set_num_threads(1)
    root = tmp_path_factory.mktemp("evaluation")
    corpus = make_corpus(root / "corpus")
    config = build_run(corpus, root / "run")
    add_loss_curve(config.output, "proud", CURVE)  # "old" has none: the report must cope
    base = build_base_models(corpus, root / "base")
    result = CliRunner().invoke(app, ["evaluate", str(config.output), "--base-models", str(base)])
    assert result.exit_code == 0, result.output
    return {"corpus": corpus, "run": config.output, "base": base}


def summary_table(markdown: str) -> dict[str, dict[str, str]]:
    """The report's summary table: row label -> header -> cell."""
    lines = markdown.split("## Summary", 1)[1].strip().splitlines()
    header = [c.strip() for c in lines[0].strip("|").split("|")]
    rows = {}
    for line in lines[2:]:
        if not line.startswith("|"):
            break
        cells = [c.strip() for c in line.strip("|").split("|")]
        rows[cells[0]] = dict(zip(header, cells))
    return rows


def scores_by_id(run: Path) -> dict[str, dict]:
    return {r["output_id"]: r for r in pq.read_table(run / SCORES_FILE).to_pylist()}


def test_report_has_every_metric_for_every_style(tiny) -> None:
    run = tiny["run"]
    table = summary_table((run / "report.md").read_text())
    for style in [*STYLE_NAMES, "all"]:
        row = table[style]
        for header in ("SRA", "CRA", "diversity", "foot skating", "contact agreement", "MPJPE (m)"):
            assert row[header] != "–", (style, header)
        assert row["clips"] == "16" if style != "all" else row["clips"] == "32"
    for style in STYLE_NAMES:
        assert table[style]["FMD"] != "–" and table[style]["diversity (real)"] != "–"
    paper = next(v for k, v in table.items() if "published" in k)
    assert paper["SRA"] == "70.77%" and paper["CRA"] == "83.72%"
    text = (run / "report.md").read_text()
    assert "28.01%" in text and "differ from ours" in text
    assert f"motionaug preview {run} --clip " in text and "--style " in text  # worst clips say how to look
    assert (run / "report_plots" / "scores.png").is_file() and (run / "report_plots" / "loss.png").is_file()


def test_html_is_self_contained_with_png_plots(tiny) -> None:
    page = (tiny["run"] / "report.html").read_text()
    images = re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', page)
    assert len(images) == 3  # score distributions, loss curves, stage times
    assert all(base64.b64decode(data)[:8] == b"\x89PNG\r\n\x1a\n" for data in images)
    assert "http://" not in page and "https://" not in page and "<script" not in page


def test_scores_parquet_matches_metrics_computed_directly(tiny) -> None:
    run, corpus = tiny["run"], tiny["corpus"]
    scores = scores_by_id(run)
    sources = {c.id: c for c in Corpus(corpus)}
    rows = list(iter_shard_rows(run))
    assert sorted(scores) == sorted(r["output_id"] for r in rows)
    for row in rows[:4]:
        got = scores[row["output_id"]]
        joints = features_to_joints(row_motion(row))
        assert got["foot_skating"] == pytest.approx(foot_skating_ratio(joints, T2M, 20.0), abs=1e-12)
        content = features_to_joints(sources[row["source_id"]].motion)
        n = min(len(joints), len(content))
        agree = foot_contact_accuracy(
            foot_contacts_from_joints(joints[:n], T2M), foot_contacts_from_joints(content[:n], T2M)
        )
        assert got["contact_agreement"] == pytest.approx(agree, abs=1e-12)
        truth = paired_ground_truth(sources[row["source_id"]].meta["spec"], row["style"])
        m = min(len(truth), len(joints))
        assert got["mpjpe"] == pytest.approx(mpjpe(joints[:m], truth[:m]), abs=1e-9)
        assert got["content_score"] == got["content_prob"]  # the stats method gives no content score of its own


def _style_rows(run: Path, style: str) -> list[dict]:
    return sorted((r for r in iter_shard_rows(run) if r["style"] == style), key=lambda r: r["output_id"])


@pytest.mark.filterwarnings("ignore::scipy.linalg.LinAlgWarning")  # 4-dim tiny features: near-singular
def test_report_numbers_equal_direct_sra_cra_fmd(tiny) -> None:
    run, corpus = tiny["run"], tiny["corpus"]
    table = summary_table((run / "report.md").read_text())
    classifiers = load_classifiers(tiny["base"])
    real = [c for c in Corpus(corpus) if c.style == "proud"]
    real_feats = classifiers.style.features(*pad_batch([features_to_joints(c.motion) for c in real])).numpy()
    rows = _style_rows(run, "proud")
    joints, mask = pad_batch([features_to_joints(row_motion(r)) for r in rows])
    with torch.no_grad():
        style_logits = classifiers.style(joints, mask)
        content_logits = classifiers.content(joints, mask)
        feats = classifiers.style.features(joints, mask).numpy()
    sra = recognition_accuracy(style_logits, torch.full((len(rows),), classifiers.style_labels.index("proud")))
    cra = recognition_accuracy(
        content_logits, torch.tensor([classifiers.content_labels.index(r["content"]) for r in rows])
    )
    assert table["proud"]["SRA"] == format_value("pct", sra)
    assert table["proud"]["CRA"] == format_value("pct", cra)
    assert table["proud"]["FMD"] == format_value("num", frechet_distance(feats, real_feats))
    assert table["proud"]["diversity"] == format_value("num", diversity(feats, n_pairs=len(feats), seed=0))
    skating = np.mean([foot_skating_ratio(features_to_joints(row_motion(r)), T2M, 20.0) for r in rows])
    assert table["proud"]["foot skating"] == format_value("pct", skating)


def test_evaluation_without_base_models_says_so_instead_of_inventing(tiny) -> None:
    evaluation = evaluate_run(tiny["run"])  # the stats run has no base models of its own
    assert all(s.sra is None and s.cra is None and s.fmd is None for s in evaluation.styles)
    assert any("no base models" in note for note in evaluation.notes)
    assert evaluation.overall.foot_skating is not None and evaluation.overall.mpjpe is not None
    assert set(evaluation.loss_curves) == {"proud"} and evaluation.loss_curves["proud"][3]["total"] == pytest.approx(
        1.3 / 4
    )
    manifest = RunDir(tiny["run"]).manifest()
    assert manifest.rows == 32
    assert evaluation.throughput == pytest.approx(32 / manifest.stages["transfer"].seconds)  # rows / transfer seconds
    assert list(evaluation.stages) == ["plan", "prepare", "transfer"]  # pipeline order, not the manifest's sorted keys


def test_the_configs_evaluators_judge_the_run_before_its_base_models(tiny, tmp_path: Path) -> None:
    """``evaluators`` in the run config: judges apart from the method's trained models (a protocol's shared ones)."""
    from motionaug.augment.eval.evaluation import _base_models_dir
    from motionaug.schemas.run_config import RunConfig, resolve_paths

    manifest = RunDir(tiny["run"]).manifest()
    judges = str(tiny["base"])
    assert _base_models_dir(tiny["run"], manifest, {"evaluators": judges}, None) == tiny["base"]
    assert _base_models_dir(tiny["run"], manifest, {"evaluators": judges}, tmp_path) == tmp_path  # --evaluators wins
    style = {"name": "proud", "words": {"adjective": "proud"}, "examples": [{"source": "1", "description": "x"}]}
    data = {"corpus": {"path": "c"}, "styles": [style], "evaluators": "j"}
    config = resolve_paths(RunConfig.model_validate(data), tmp_path)
    assert config.evaluators == (tmp_path / "j").resolve()
    result = CliRunner().invoke(app, ["evaluate", str(tiny["run"]), "--evaluators", judges])
    assert result.exit_code == 0, result.output


def test_export_min_content_score_filters_by_scores_parquet(tiny, tmp_path: Path) -> None:
    run = tiny["run"]
    scores = scores_by_id(run)
    train = [s for s in scores.values() if s["split"] == "train"]
    threshold = float(np.median([s["content_score"] for s in train]))
    kept = sorted(s["output_id"] for s in train if s["content_score"] >= threshold)
    assert 0 < len(kept) < len(train)
    out = tmp_path / "export"
    result = CliRunner().invoke(app, ["export", str(run), "--out", str(out), "--min-content-score", str(threshold)])
    assert result.exit_code == 0, result.output
    listed = (out / "train.txt").read_text().split()
    assert sorted(i for i in listed if "__" in i) == kept
    assert f"{len(train) - len(kept)} below the score" in " ".join(result.output.split())


def test_evaluate_refuses_an_unfinished_run_in_one_line(tmp_path: Path) -> None:
    result = CliRunner().invoke(app, ["evaluate", str(tmp_path)])
    assert result.exit_code == 1
    assert "run is not complete" in result.output and result.output.count("\n") == 1


def test_loss_curves_accept_numbers_or_records_and_skip_styles_without(tmp_path: Path) -> None:
    from motionaug.augment.eval.evaluation import loss_curves

    (tmp_path / "styles" / "a").mkdir(parents=True)
    (tmp_path / "styles" / "a" / "artifact.json").write_text('{"losses": [3.0, 2.0, 1.5]}')
    (tmp_path / "styles" / "b").mkdir()
    (tmp_path / "styles" / "b" / "artifact.json").write_text('{"method": "stats"}')
    curves = loss_curves(tmp_path, ["a", "b", "missing"])
    assert curves == {"a": [{"step": 0.0, "total": 3.0}, {"step": 1.0, "total": 2.0}, {"step": 2.0, "total": 1.5}]}


def test_clips_the_evaluators_trained_on_are_counted_and_held_out_figures_kept_apart(tiny) -> None:
    evaluation = evaluate_run(tiny["run"], base_models=tiny["base"])
    train_rows = [r for r in evaluation.scores if r["split"] == "train"]
    assert 0 < len(train_rows) < len(evaluation.scores)  # the fixture corpus has train and held-out clips
    assert evaluation.overall.trained_on == len(train_rows)
    assert evaluation.overall.held_out == len(evaluation.scores) - len(train_rows)
    held = [r for r in evaluation.scores if r["split"] != "train"]
    assert evaluation.overall.sra_held_out == pytest.approx(np.mean([r["style_correct"] for r in held]))
    assert any("optimistic" in note for note in evaluation.notes)
    table = summary_table((tiny["run"] / "report.md").read_text())
    assert table["all"]["clips the evaluators trained on"] == str(len(train_rows))


def test_a_run_whose_pool_is_its_scored_clips_is_marked_not_held_out(tiny) -> None:
    """The tiny run sets no pool split, so its method learnt from the clips it is scored on; the report says so."""
    evaluation = evaluate_run(tiny["run"], base_models=tiny["base"])
    assert any("pool is the scored clips" in leak for leak in evaluation.leaks)
    report = (tiny["run"] / "report.md").read_text(encoding="utf-8")
    assert "**held out**: NOT HELD OUT: corpus.pool_split is unset" in report
