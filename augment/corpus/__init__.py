"""Corpora on disk: a HumanML3D folder or a Parquet corpus, opened by path through ``Corpus``."""

from motionaug.augment.corpus.clip import MotionClip
from motionaug.augment.corpus.corpus import Corpus, CorpusFormat, detect_format, split_of_ids
from motionaug.augment.corpus.humanml3d import HumanML3DReader, span_id, span_parent, write_humanml3d
from motionaug.augment.corpus.inspect import REJECTS_FILE, inspect_corpus
from motionaug.augment.corpus.parquet import ParquetCorpusWriter, clips_to_table, read_parquet_corpus, table_to_clips
from motionaug.augment.corpus.rejects import Reject, read_rejects, write_rejects

__all__ = [
    "REJECTS_FILE",
    "Corpus",
    "CorpusFormat",
    "HumanML3DReader",
    "MotionClip",
    "ParquetCorpusWriter",
    "Reject",
    "clips_to_table",
    "detect_format",
    "inspect_corpus",
    "read_parquet_corpus",
    "read_rejects",
    "span_id",
    "span_parent",
    "split_of_ids",
    "table_to_clips",
    "write_humanml3d",
    "write_rejects",
]
