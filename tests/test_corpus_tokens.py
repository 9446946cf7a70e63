"""Caption lines and token fields: strict parsing, faithful formatting, atomic writes and rejects files."""

from __future__ import annotations

import os

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from motionaug.augment.corpus.rejects import Reject, read_rejects, write_rejects
from motionaug.augment.io import atomic_open, atomic_write_text
from motionaug.augment.text.tokens import (
    UPOS_TAGS,
    default_tokens,
    format_caption_line,
    parse_caption_line,
    parse_tokens,
)
from motionaug.schemas.captions import Caption
from motionaug.schemas.errors import MotionDataError

EXAMPLE = "a man kicks something with his left leg.#a/DET man/NOUN kick/VERB something/PRON with/ADP his/DET left/ADJ leg/NOUN#0.0#0.0"  # noqa: E501 (a real caption line)


def test_parse_reference_example() -> None:
    caption = parse_caption_line(EXAMPLE + "\n", "texts/000001.txt:1")
    assert caption.text == "a man kicks something with his left leg."
    assert caption.tokens[:3] == ["a/DET", "man/NOUN", "kick/VERB"] and len(caption.tokens) == 8
    assert caption.whole_clip


def test_nan_times_mean_whole_clip_and_spans_parse() -> None:
    assert parse_caption_line("a man hops.#a/DET man/NOUN hop/VERB#nan#nan", "f").whole_clip
    span = parse_caption_line("a man hops.#a/DET man/NOUN hop/VERB#1.5#3.25", "f")
    assert (span.start, span.end) == (1.5, 3.25) and not span.whole_clip


@pytest.mark.parametrize(
    ("line", "reason"),
    [
        ("a man walks.#a/DET man/NOUN walk/VERB#0.0", "found 3"),
        ("a man walks.#a/DET man/NOUN walk/VERB#0.0#0.0#1.0", "found 5"),
        ("a man walks.#a/DET man walk/VERB#0.0#0.0", "'man' is not 'word/POS'"),
        ("a man walks.#a/DET man/NOUNS walk/VERB#0.0#0.0", "unknown POS tag 'NOUNS'"),
        ("a man walks.#a/b/DET man/NOUN#0.0#0.0", "is not 'word/POS'"),
        ("a man walks.#/DET man/NOUN#0.0#0.0", "is not 'word/POS'"),
        ("a man walks.#a/DET#zero#0.0", "start time 'zero' is not a number"),
        ("a man walks.#a/DET#0.0#-1.0", "end time '-1.0'"),
        ("a man walks.#a/DET#inf#0.0", "start time 'inf'"),
        ("  #a/DET#0.0#0.0", "empty caption text"),
    ],
)
def test_malformed_lines_name_the_source(line: str, reason: str) -> None:
    with pytest.raises(MotionDataError, match="texts/000007.txt:4") as info:
        parse_caption_line(line, "texts/000007.txt:4")
    assert reason in info.value.reason


def test_empty_token_field_is_no_tokens_and_tolerated_tags_pass() -> None:
    assert parse_caption_line("a man walks.##0.0#0.0", "f").tokens == []
    assert parse_tokens("walk/VERB  end/EOL ./PUNCT", "f") == ["walk/VERB", "end/EOL", "./PUNCT"]
    with pytest.raises(MotionDataError, match="not 'word/POS'"):
        parse_tokens("walk/VERB /SPACE", "f")  # an empty word is never valid, whatever the tag


@settings(max_examples=60, deadline=None)
@given(
    text=st.text(st.characters(blacklist_characters="#\r\n", blacklist_categories=("Cs",)), min_size=1).filter(
        str.strip
    ),
    words=st.lists(st.from_regex(r"[a-z']{1,8}", fullmatch=True), max_size=6),
    tags=st.lists(st.sampled_from(sorted(UPOS_TAGS)), min_size=6, max_size=6),
    span=st.tuples(st.floats(0, 600, allow_nan=False), st.floats(0, 600, allow_nan=False)),
)
def test_format_then_parse_is_identity(text: str, words: list[str], tags: list[str], span: tuple[float, float]) -> None:
    caption = Caption(
        text=text.strip(), tokens=[f"{w}/{t}" for w, t in zip(words, tags)] or ["x/X"], start=span[0], end=span[1]
    )
    line = format_caption_line(caption, "clip")
    assert "\n" not in line
    assert parse_caption_line(line + "\n", "clip") == caption


def test_format_refuses_what_cannot_be_read_back() -> None:
    with pytest.raises(MotionDataError, match="contains '#'"):
        format_caption_line(Caption(text="walk #2", tokens=["walk/VERB"]), "clip 'a'")
    with pytest.raises(MotionDataError, match="not 'word/POS'"):
        format_caption_line(Caption(text="walk", tokens=["walk"]), "clip 'a'")


def test_default_tokens_are_valid_and_tag_closed_class_words() -> None:
    tokens = default_tokens("A man walks with his left leg, then stops.")
    assert tokens == ["a/DET", "man/X", "walks/X", "with/ADP", "his/DET", "left/X", "leg/X", "then/SCONJ", "stops/X"]
    line = format_caption_line(Caption(text="A man walks."), "clip")
    assert line == "A man walks.#a/DET man/X walks/X#0.0#0.0"


def test_atomic_write_keeps_old_file_on_error(tmp_path) -> None:
    target = tmp_path / "sub" / "a.txt"
    atomic_write_text(target, "old\n")
    with pytest.raises(RuntimeError):
        with atomic_open(target, "w") as handle:
            handle.write("half of the new")
            raise RuntimeError("crash mid-write")
    assert target.read_text() == "old\n"
    assert os.listdir(target.parent) == ["a.txt"]  # no temporary file left behind


def test_rejects_round_trip_as_json_lines(tmp_path) -> None:
    rejects = [
        Reject(id="000001", source="/d/new_joint_vecs/000001.npy", reason="feature width 250, expected 263"),
        Reject.from_error("../x", MotionDataError("all.txt:3", "unsafe id '../x'")),
    ]
    path = tmp_path / "rejects.jsonl"
    assert write_rejects(rejects, path) == 2
    assert len(path.read_text().splitlines()) == 2
    assert read_rejects(path) == rejects
    assert str(rejects[1]) == "all.txt:3: unsafe id '../x' (clip ../x)"
