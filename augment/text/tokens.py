"""HumanML3D caption lines, ``caption#word/POS word/POS#start#end``, parsed and written strictly.

The token field feeds the reference evaluators' word vectorizer, which splits every item on '/' and
one-hot encodes the POS; a malformed item there crashes training, so it is an error here, at the file.
"""

from __future__ import annotations

import math
import re

from motionaug.schemas.captions import Caption
from motionaug.schemas.errors import MotionDataError

UPOS_TAGS = frozenset(
    "ADJ ADP ADV AUX CCONJ DET INTJ NOUN NUM PART PRON PROPN PUNCT SCONJ SYM VERB X".split()
)  # the universal POS tags spaCy assigns
TOLERATED_TAGS = frozenset({"SPACE", "EOL"})
POS_TAGS = UPOS_TAGS | TOLERATED_TAGS

_FIELD_SEP = "#"
_N_FIELDS = 4

# Closed-class words get their usual tag when captions arrive without tokens; the rest are X.
# Real lemma/POS needs a tagger (spaCy), which is not a dependency.
_CLOSED_CLASS = {
    **dict.fromkeys("a an the this that these those his her its their my your our".split(), "DET"),
    **dict.fromkeys("he she it they him them someone somebody something person's".split(), "PRON"),
    **dict.fromkeys(
        "with to in on at from into onto over under up down forward backward of by for around".split(), "ADP"
    ),
    **dict.fromkeys("and or but".split(), "CCONJ"),
    **dict.fromkeys("while then".split(), "SCONJ"),
    **dict.fromkeys("is are was were be being been".split(), "AUX"),
}
_WORD = re.compile(r"[a-z0-9]+(?:'[a-z]+)?")


def parse_token(item: str, source: str) -> tuple[str, str]:
    """Split one ``word/POS`` item; exactly one '/', a non-empty word, a known tag."""
    parts = item.split("/")
    if len(parts) != 2 or not parts[0]:
        raise MotionDataError(source, f"token {item!r} is not 'word/POS'")
    word, pos = parts
    if pos not in POS_TAGS:
        raise MotionDataError(source, f"token {item!r} has unknown POS tag {pos!r}")
    return word, pos


def parse_tokens(field: str, source: str) -> list[str]:
    """The space-separated token field; an empty field is no tokens."""
    items = field.split()
    for item in items:
        parse_token(item, source)
    return items


def format_tokens(tokens: list[str], source: str) -> str:
    """The token field for a line; refuses items that would not parse back."""
    for item in tokens:
        if item != item.strip() or " " in item or _FIELD_SEP in item:
            raise MotionDataError(source, f"token {item!r} contains whitespace or '#'")
        parse_token(item, source)
    return " ".join(tokens)


def default_tokens(text: str) -> list[str]:
    """Tokens for a caption that has none: lowercase words, closed-class words tagged, others X."""
    return [f"{word}/{_CLOSED_CLASS.get(word, 'X')}" for word in _WORD.findall(text.lower())]


def _parse_time(value: str, what: str, source: str) -> float:
    """Seconds; NaN means 'whole clip' as in the reference loader, so it reads as 0.0."""
    try:
        seconds = float(value)
    except ValueError:
        raise MotionDataError(source, f"{what} time {value!r} is not a number") from None
    if math.isnan(seconds):
        return 0.0
    if math.isinf(seconds) or seconds < 0:
        raise MotionDataError(source, f"{what} time {value!r} is not a finite non-negative number")
    return seconds


def parse_caption_line(line: str, source: str) -> Caption:
    """One line of a texts/<id>.txt file; ``source`` names the file and line in errors."""
    fields = line.rstrip("\r\n").split(_FIELD_SEP)
    if len(fields) != _N_FIELDS:
        raise MotionDataError(source, f"expected {_N_FIELDS} '#'-separated fields, found {len(fields)}")
    text, token_field, start, end = fields
    if not text.strip():
        raise MotionDataError(source, "empty caption text")
    return Caption(
        text=text.strip(),
        tokens=parse_tokens(token_field, source),
        start=_parse_time(start, "start", source),
        end=_parse_time(end, "end", source),
    )


def format_caption_line(caption: Caption, source: str) -> str:
    """The line (without newline) that ``parse_caption_line`` reads back to ``caption``."""
    text = caption.text.strip()
    if _FIELD_SEP in text or "\n" in text or "\r" in text:
        raise MotionDataError(source, f"caption {text[:40]!r} contains '#' or a line break")
    tokens = caption.tokens or default_tokens(text)
    for what, seconds in (("start", caption.start), ("end", caption.end)):
        if not math.isfinite(seconds) or seconds < 0:
            raise MotionDataError(source, f"caption {what} time {seconds} is not a finite non-negative number")
    return _FIELD_SEP.join([text, format_tokens(tokens, source), repr(float(caption.start)), repr(float(caption.end))])
