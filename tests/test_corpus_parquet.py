"""The Parquet corpus: round trips, readable as-is by pyarrow/pandas/duckdb, atomic files; format detection."""

from __future__ import annotations

import shutil
from pathlib import Path

import duckdb
import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from motionaug.augment.corpus import (
    Corpus,
    ParquetCorpusWriter,
    clips_to_table,
    detect_format,
    inspect_corpus,
    read_parquet_corpus,
    table_to_clips,
    write_humanml3d,
)
from motionaug.augment.corpus.clip import MotionClip
from motionaug.schemas.captions import Caption
from motionaug.schemas.corpus import CORPUS_SCHEMA_VERSION, corpus_schema
from motionaug.schemas.errors import MotionDataError

WIDTH = 263


def make_clips(n: int, width: int = WIDTH) -> list[MotionClip]:
    rng = np.random.default_rng(7)
    clips = []
    for i in range(n):
        captions = [
            Caption(text=f"a person walks {i} steps.", tokens=["a/DET", "person/NOUN", "walk/VERB"]),
            Caption(text="then turns.", tokens=["turn/VERB"], start=0.1, end=1.3),
        ]
        clips.append(
            MotionClip(
                id=f"clip{i:03d}",
                motion=rng.standard_normal((10 + i, width)).astype(np.float32),
                captions=captions[: 1 + i % 2],
                fps=20.0 if i % 3 else 12.5,
                content=["walk", "run"][i % 2],
                style=None if i % 4 == 0 else "proud",
                source=f"bandai/{i}.bvh",
                meta={"split": "train"} if i % 2 else {"parent": "x", "note": "ä"},
            )
        )
    return clips


def assert_same(a: list[MotionClip], b: list[MotionClip]) -> None:
    assert [c.id for c in a] == [c.id for c in b]
    for x, y in zip(a, b):
        assert np.array_equal(x.motion, y.motion) and y.motion.dtype == np.float32
        assert (x.captions, x.fps, x.content, x.style, x.source, x.meta) == (
            y.captions,
            y.fps,
            y.content,
            y.style,
            y.source,
            y.meta,
        )


def test_table_round_trip_keeps_every_field() -> None:
    clips = make_clips(6)
    table = clips_to_table(clips)
    assert table.schema.equals(corpus_schema(), check_metadata=True)
    assert table.column("n_frames").to_pylist() == [10, 11, 12, 13, 14, 15]
    back = table_to_clips(table)
    assert_same(clips, back)
    assert back[1].captions[1].start == 0.1  # float32 storage still reads back as the decimal written
    back[0].motion[0, 0] = 1.0  # clips own writable arrays, not views of Arrow buffers


def test_files_and_row_groups_stream(tmp_path: Path) -> None:
    clips = make_clips(10)
    with ParquetCorpusWriter(tmp_path / "corpus", rows_per_file=4, row_group_size=3) as writer:
        writer.write_all(clips)
    assert [f.name for f in writer.files] == ["part-00000.parquet", "part-00001.parquet", "part-00002.parquet"]
    metas = [pq.ParquetFile(f).metadata for f in writer.files]
    assert [m.num_rows for m in metas] == [4, 4, 2]
    assert [[m.row_group(i).num_rows for i in range(m.num_row_groups)] for m in metas] == [[3, 1], [3, 1], [2]]
    assert_same(clips, list(read_parquet_corpus(tmp_path / "corpus", batch_size=2)))
    assert not list((tmp_path / "corpus").glob(".*"))  # no temporary files left


def test_readable_as_is_by_pyarrow_pandas_duckdb(tmp_path: Path) -> None:
    clips = make_clips(5)
    path = tmp_path / "corpus.parquet"
    with ParquetCorpusWriter(path) as writer:
        writer.write_all(clips)
    table = pq.read_table(path)
    assert table.schema.metadata[b"motionaug.schema_version"] == str(CORPUS_SCHEMA_VERSION).encode()
    assert table.schema.metadata[b"motionaug.feature_dim"] == b"263"
    frame = pd.read_parquet(path)
    assert list(frame["id"]) == [c.id for c in clips]
    row = frame.iloc[3]
    assert np.array_equal(
        np.asarray(row["motion"], np.float32).reshape(row["n_frames"], row["n_feats"]), clips[3].motion
    )
    rows = duckdb.sql(
        f"select id, n_frames, len(captions), captions[1].text, style from '{path}' order by id"
    ).fetchall()
    assert rows[1] == ("clip001", 11, 2, "a person walks 1 steps.", "proud")
    assert rows[0][4] is None
    [(first_value,)] = duckdb.sql(f"select motion[264] from '{path}' where id = 'clip002'").fetchall()
    assert first_value == pytest.approx(float(clips[2].motion[1, 0]))  # duckdb decodes the motion encoding too
    [(total,)] = duckdb.sql(f"select sum(len(motion)) from '{tmp_path}/*.parquet'").fetchall()
    assert total == sum(c.motion.size for c in clips)


def test_rewrite_drops_stale_parts_and_abort_publishes_nothing(tmp_path: Path) -> None:
    out = tmp_path / "corpus"
    with ParquetCorpusWriter(out, rows_per_file=2) as writer:
        writer.write_all(make_clips(6))
    with ParquetCorpusWriter(out, rows_per_file=2) as writer:
        writer.write_all(make_clips(3))
    assert sorted(p.name for p in out.iterdir()) == ["part-00000.parquet", "part-00001.parquet"]
    assert len(list(read_parquet_corpus(out))) == 3
    with pytest.raises(RuntimeError):
        with ParquetCorpusWriter(tmp_path / "failed.parquet", row_group_size=2) as writer:
            writer.write_all(make_clips(3))  # one row group is already in the temporary file
            raise RuntimeError("crash")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["corpus"]


def test_empty_corpus_is_a_readable_file(tmp_path: Path) -> None:
    with ParquetCorpusWriter(tmp_path / "empty.parquet", feature_dim=251, skeleton="kit"):
        pass
    assert list(read_parquet_corpus(tmp_path / "empty.parquet")) == []
    info = inspect_corpus(tmp_path / "empty.parquet")
    assert (info.clips, info.skeleton, info.feature_dim) == (0, "kit", 251)


def test_bad_input_is_refused(tmp_path: Path) -> None:
    with pytest.raises(MotionDataError, match="clip 'clip000': feature width 250, expected 263"):
        with ParquetCorpusWriter(tmp_path / "narrow.parquet") as writer:
            writer.write_all(make_clips(1, width=250))
    clip = make_clips(1)[0]
    clip.motion[3, 3] = np.nan
    with pytest.raises(MotionDataError, match="NaN/Inf values from frame 3"):
        clips_to_table([clip])
    plain = tmp_path / "plain.parquet"
    pq.write_table(pa.table({"id": ["a"]}), plain)
    with pytest.raises(MotionDataError, match="plain.parquet: not a motionaug corpus"):
        list(read_parquet_corpus(plain))
    table = clips_to_table(make_clips(2))
    newer = table.replace_schema_metadata({**table.schema.metadata, b"motionaug.schema_version": b"99"})
    pq.write_table(newer, tmp_path / "newer.parquet")
    with pytest.raises(MotionDataError, match="version 99 is newer"):
        list(read_parquet_corpus(tmp_path / "newer.parquet"))
    wrong = table.set_column(2, table.schema.field("n_frames"), pa.array([10, 99], pa.int32()))
    with pytest.raises(MotionDataError, match=r"row 1 \(clip001\): motion has 2893 values, n_frames\*n_feats is 26037"):
        table_to_clips(wrong, source="wrong.parquet")


def test_open_and_inspect_detect_each_format(tmp_path: Path) -> None:
    clips = make_clips(5)
    write_humanml3d(clips[2::2], tmp_path / "h3d")  # the 20 fps clips with whole-clip captions only
    with ParquetCorpusWriter(tmp_path / "pq", rows_per_file=2) as writer:
        writer.write_all(clips)
    assert detect_format(tmp_path / "h3d") == "humanml3d"
    assert detect_format(tmp_path / "pq") == detect_format(tmp_path / "pq" / "part-00000.parquet") == "parquet"
    with pytest.raises(MotionDataError, match="not a corpus"):
        detect_format(tmp_path)
    reader = Corpus(tmp_path / "pq")
    assert_same(clips, list(reader))
    assert reader.rejects == []
    assert [c.id for c in Corpus(tmp_path / "h3d")] == ["clip002", "clip004"]
    info = inspect_corpus(tmp_path / "pq")
    assert (info.format, info.clips, info.frames, info.captions) == ("parquet", 5, 60, 7)
    assert info.contents == {"run": 2, "walk": 3} and info.styles == {"proud": 3} and info.splits == {"train": 2}
    assert info.hours == pytest.approx((10 / 12.5 + 11 / 20 + 12 / 20 + 13 / 12.5 + 14 / 20) / 3600)
    (tmp_path / "h3d" / "new_joint_vecs" / "clip004.npy").write_bytes(b"broken")
    shutil.copy(tmp_path / "h3d" / "all.txt", tmp_path / "h3d" / "train.txt")
    info = inspect_corpus(tmp_path / "h3d")
    assert (info.format, info.clips, info.frames, info.rejects, info.splits) == (
        "humanml3d",
        1,
        12,
        1,
        {"train": 2, "all": 2},
    )
