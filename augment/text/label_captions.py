"""Captions a person would write for a (content, style) label pair, in HumanML3D's caption format.

Labelled motion capture (Bandai Namco datasets 1 and 2) has only ``content`` and ``style`` labels; the on-the-fly
paper (Hu et al., sec. 4.2) annotates Bandai-2 "with a simple text description based on the content and style
labels". This module writes several such captions per clip, with HumanML3D's ``lemma/POS`` tokens, from a phrase
table per content (``CONTENT_PHRASES``) and a word table per style (``LABEL_STYLES``: adjective, adverb, trailing
phrase, the paper's comma form). The neutral style is left out of the text, as HumanML3D describes neutral motion
and the on-the-fly method builds neutral prompts by removing style words (paper sec. 3.2). Tokens line up one per
word with ``caption_revision.caption_words``, and ``neutralising_vocab()`` lets the revision remove these words.
"""

from __future__ import annotations

import random
import re
from collections.abc import Mapping
from dataclasses import dataclass

from motionaug.augment.text.caption_revision import StyleVocab, caption_words
from motionaug.schemas.captions import Caption
from motionaug.schemas.styles import StyleWords

_WORD = re.compile(r"[A-Za-z]+(?:-[A-Za-z]+)*")
_DOUBLES_FINAL = frozenset("run jog put swim spin hit step nod sit get stop skip hop".split())
NEUTRAL_STYLES = frozenset({"normal", "neutral", "natural", "none"})


def article(next_word: str) -> str:
    """'a' or 'an' by the sound of the next word's first letter (good enough for these tables)."""
    return "an" if next_word[:1].lower() in "aeiou" else "a"


def ing_form(lemma: str) -> str:
    """'walk' -> 'walking', 'run' -> 'running', 'wave' -> 'waving', 'lie' -> 'lying'."""
    if lemma in _DOUBLES_FINAL:
        return lemma + lemma[-1] + "ing"
    if lemma.endswith("ie"):
        return lemma[:-2] + "ying"
    if lemma.endswith("e") and not lemma.endswith(("ee", "ye", "oe")):
        return lemma[:-1] + "ing"
    return lemma + "ing"


@dataclass(frozen=True)
class Phrase:
    """Words of a caption piece with one ``lemma/POS`` token per word; punctuation lives in ``text`` only."""

    text: str
    tokens: tuple[str, ...]

    def __post_init__(self) -> None:
        words = _WORD.findall(self.text)
        if len(words) != len(self.tokens) or len(caption_words(self.text)) != len(self.tokens):
            raise ValueError(f"phrase {self.text!r} has {len(words)} words but {len(self.tokens)} tokens")

    def progressive(self) -> Phrase:
        """Every verb in its -ing form: 'walks and turns right' -> 'walking and turning right'."""
        tokens = iter(self.tokens)

        def swap(match: re.Match[str]) -> str:
            lemma, _, pos = next(tokens).rpartition("/")
            return ing_form(lemma) if pos == "VERB" else match.group(0)

        return Phrase(_WORD.sub(swap, self.text), self.tokens)


def phrase(text: str, tokens: str) -> Phrase:
    return Phrase(text, tuple(tokens.split()))


def _join(*parts: Phrase) -> Caption:
    text = " ".join(p.text for p in parts if p.text)
    text = re.sub(r"\s+([,.])", r"\1", text).strip()
    return Caption(text=text.rstrip(",") + ".", tokens=[t for p in parts for t in p.tokens])


# ---- contents ---------------------------------------------------------------------------------------------------

_WALK = (
    phrase("walks forward", "walk/VERB forward/ADV"),
    phrase("walks straight ahead", "walk/VERB straight/ADV ahead/ADV"),
    phrase("walks", "walk/VERB"),
)
_RUN = (
    phrase("runs forward", "run/VERB forward/ADV"),
    phrase("runs", "run/VERB"),
    phrase("runs straight ahead", "run/VERB straight/ADV ahead/ADV"),
)


def _turn(side: str) -> tuple[Phrase, ...]:
    return (
        phrase(f"walks and turns {side}", f"walk/VERB and/CCONJ turn/VERB {side}/ADV"),
        phrase(
            f"walks forward and turns to the {side}",
            f"walk/VERB forward/ADV and/CCONJ turn/VERB to/ADP the/DET {side}/NOUN",
        ),
        phrase(f"walks, then turns {side}", f"walk/VERB then/ADV turn/VERB {side}/ADV"),
    )


def _wave_one(side: str) -> tuple[Phrase, ...]:
    return (
        phrase(f"waves the {side} hand", f"wave/VERB the/DET {side}/ADJ hand/NOUN"),
        phrase(f"waves with their {side} hand", f"wave/VERB with/ADP their/DET {side}/ADJ hand/NOUN"),
        phrase(f"raises the {side} hand and waves", f"raise/VERB the/DET {side}/ADJ hand/NOUN and/CCONJ wave/VERB"),
    )


def _raise_one(side: str) -> tuple[Phrase, ...]:
    return (
        phrase(f"raises the {side} hand", f"raise/VERB the/DET {side}/ADJ hand/NOUN"),
        phrase(f"raises their {side} hand up", f"raise/VERB their/DET {side}/ADJ hand/NOUN up/ADP"),
        phrase(
            f"puts the {side} hand up in the air",
            f"put/VERB the/DET {side}/ADJ hand/NOUN up/ADP in/ADP the/DET air/NOUN",
        ),
    )


def _walk_side(side: str) -> tuple[Phrase, ...]:
    return (
        phrase(f"walks to the {side}", f"walk/VERB to/ADP the/DET {side}/NOUN"),
        phrase(f"walks toward the {side}", f"walk/VERB toward/ADP the/DET {side}/NOUN"),
        phrase(f"moves to the {side}", f"move/VERB to/ADP the/DET {side}/NOUN"),
    )


_DANCE = phrase("dances", "dance/VERB")

CONTENT_PHRASES: dict[str, tuple[Phrase, ...]] = {
    # Bandai-Namco-Research-Motiondataset-2
    "walk": _WALK,
    "walk-turn-left": _turn("left"),
    "walk-turn-right": _turn("right"),
    "run": _RUN,
    "wave-both-hands": (
        phrase("waves both hands", "wave/VERB both/DET hand/NOUN"),
        phrase("waves with both hands", "wave/VERB with/ADP both/DET hand/NOUN"),
        phrase("raises both hands and waves", "raise/VERB both/DET hand/NOUN and/CCONJ wave/VERB"),
    ),
    "wave-left-hand": _wave_one("left"),
    "wave-right-hand": _wave_one("right"),
    "raise-up-both-hands": (
        phrase("raises both hands", "raise/VERB both/DET hand/NOUN"),
        phrase("raises both hands up", "raise/VERB both/DET hand/NOUN up/ADP"),
        phrase("puts both hands up in the air", "put/VERB both/DET hand/NOUN up/ADP in/ADP the/DET air/NOUN"),
    ),
    "raise-up-left-hand": _raise_one("left"),
    "raise-up-right-hand": _raise_one("right"),
    # Bandai-Namco-Research-Motiondataset-1 (walk and run as above)
    "dash": (
        phrase("sprints forward", "sprint/VERB forward/ADV"),
        phrase("dashes forward", "dash/VERB forward/ADV"),
        phrase("runs forward very fast", "run/VERB forward/ADV very/ADV fast/ADV"),
    ),
    "walk-back": (
        phrase("walks backward", "walk/VERB backward/ADV"),
        phrase("walks backwards", "walk/VERB backwards/ADV"),
        phrase("takes a few steps backward", "take/VERB a/DET few/ADJ step/NOUN backward/ADV"),
    ),
    "walk-left": _walk_side("left"),
    "walk-right": _walk_side("right"),
    "bow": (
        phrase("bows", "bow/VERB"),
        phrase("bows forward", "bow/VERB forward/ADV"),
        phrase("bends forward in a bow", "bend/VERB forward/ADV in/ADP a/DET bow/NOUN"),
    ),
    "bye": (
        phrase("waves goodbye", "wave/VERB goodbye/NOUN"),
        phrase("waves goodbye with one hand", "wave/VERB goodbye/NOUN with/ADP one/NUM hand/NOUN"),
        phrase("says goodbye with a wave", "say/VERB goodbye/NOUN with/ADP a/DET wave/NOUN"),
    ),
    "byebye": (
        phrase("waves a hand from side to side", "wave/VERB a/DET hand/NOUN from/ADP side/NOUN to/ADP side/NOUN"),
        phrase("waves goodbye again and again", "wave/VERB goodbye/NOUN again/ADV and/CCONJ again/ADV"),
        phrase("waves bye-bye", "wave/VERB byebye/NOUN"),
    ),
    "guide": (
        phrase("shows someone the way", "show/VERB someone/PRON the/DET way/NOUN"),
        phrase("points the way with an open hand", "point/VERB the/DET way/NOUN with/ADP an/DET open/ADJ hand/NOUN"),
        phrase("guides someone with a hand gesture", "guide/VERB someone/PRON with/ADP a/DET hand/NOUN gesture/NOUN"),
    ),
    "respond": (
        phrase("responds to someone", "respond/VERB to/ADP someone/PRON"),
        phrase("responds to someone with a gesture", "respond/VERB to/ADP someone/PRON with/ADP a/DET gesture/NOUN"),
        phrase("answers someone with a gesture", "answer/VERB someone/PRON with/ADP a/DET gesture/NOUN"),
    ),
    "call": (
        phrase("calls someone over", "call/VERB someone/PRON over/ADP"),
        phrase("beckons someone over", "beckon/VERB someone/PRON over/ADP"),
        phrase("waves someone over", "wave/VERB someone/PRON over/ADP"),
    ),
    "punch": (
        phrase("punches", "punch/VERB"),
        phrase("punches forward", "punch/VERB forward/ADV"),
        phrase("throws a punch", "throw/VERB a/DET punch/NOUN"),
    ),
    "kick": (
        phrase("kicks", "kick/VERB"),
        phrase("kicks forward", "kick/VERB forward/ADV"),
        phrase("kicks with one leg", "kick/VERB with/ADP one/NUM leg/NOUN"),
    ),
    "slash": (
        phrase("slashes", "slash/VERB"),
        phrase("slashes downward", "slash/VERB downward/ADV"),
        phrase("makes a slashing motion", "make/VERB a/DET slashing/ADJ motion/NOUN"),
    ),
    "dance-long": (
        _DANCE,
        phrase("dances for a while", "dance/VERB for/ADP a/DET while/NOUN"),
        phrase("performs a dance", "perform/VERB a/DET dance/NOUN"),
    ),
    "dance-short": (
        _DANCE,
        phrase("dances briefly", "dance/VERB briefly/ADV"),
        phrase("does a short dance", "do/VERB a/DET short/ADJ dance/NOUN"),
    ),
}

# ---- styles -----------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LabelStyle:
    """Words for one style label; ``words`` gives them to caption revision as a ``StyleVocab``."""

    adjective: str
    adverb: str | None = None
    phrases: tuple[Phrase, ...] = ()
    depictive: str | None = None  # "a person is running, exhausted." (the paper's form), where it reads well

    def __post_init__(self) -> None:
        for word in (self.adjective, self.adverb or "x", self.depictive or "x"):
            if not re.fullmatch(r"[a-z]+(?: [a-z]+)*", word):
                raise ValueError(f"style word {word!r} must be lowercase words separated by single spaces")

    @property
    def words(self) -> StyleWords:
        return StyleWords(adjective=self.adjective, adverb=self.adverb, phrases=tuple(p.text for p in self.phrases))

    def way(self) -> Phrase:
        a = article(self.adjective)
        return phrase(f"in {a} {self.adjective} way", f"in/ADP {a}/DET {_tags(self.adjective, 'ADJ')} way/NOUN")


_MODIFIERS = {"not": "PART", "very": "ADV", "quite": "ADV", "rather": "ADV", "slightly": "ADV", "too": "ADV"}


def _tags(words: str, pos: str) -> str:
    """``pos`` for each word; degree words and 'not' before the head keep their own tag ('not/PART sure/ADJ')."""
    items = words.split()
    return " ".join(f"{w}/{_MODIFIERS.get(w, pos) if i < len(items) - 1 else pos}" for i, w in enumerate(items))


_ACTIVE = LabelStyle(
    "active", "energetically", (phrase("in a lively manner", "in/ADP a/DET lively/ADJ manner/NOUN"),), "energetic"
)
_MASCULINE = LabelStyle("masculine", None, (phrase("in a masculine manner", "in/ADP a/DET masculine/ADJ manner/NOUN"),))
_FEMININE = LabelStyle("feminine", None, (phrase("in a feminine manner", "in/ADP a/DET feminine/ADJ manner/NOUN"),))

LABEL_STYLES: dict[str, LabelStyle] = {
    # Bandai-Namco-Research-Motiondataset-2 (and 1: active, feminine)
    "active": _ACTIVE,
    "elderly": LabelStyle(
        "elderly",
        None,
        (
            phrase("like an elderly person", "like/ADP an/DET elderly/ADJ person/NOUN"),
            phrase("like an old person", "like/ADP an/DET old/ADJ person/NOUN"),
        ),
    ),
    "exhausted": LabelStyle(
        "exhausted",
        "wearily",
        (phrase("like an exhausted person", "like/ADP an/DET exhausted/ADJ person/NOUN"),),
        "exhausted",
    ),
    "feminine": _FEMININE,
    "masculine": _MASCULINE,
    "youthful": LabelStyle(
        "youthful", "youthfully", (phrase("like a young person", "like/ADP a/DET young/ADJ person/NOUN"),)
    ),
    # Bandai-Namco-Research-Motiondataset-1
    "happy": LabelStyle(
        "happy", "happily", (phrase("in a cheerful way", "in/ADP a/DET cheerful/ADJ way/NOUN"),), "happy"
    ),
    "sad": LabelStyle("sad", "sadly", (phrase("in a gloomy way", "in/ADP a/DET gloomy/ADJ way/NOUN"),), "sad"),
    "angry": LabelStyle("angry", "angrily", (phrase("with anger", "with/ADP anger/NOUN"),), "angry"),
    "proud": LabelStyle("proud", "proudly", (phrase("with pride", "with/ADP pride/NOUN"),), "proud"),
    "not-confident": LabelStyle("timid", "timidly", (phrase("without confidence", "without/ADP confidence/NOUN"),)),
    "masculinity": _MASCULINE,
    "childish": LabelStyle("childish", "childishly", (phrase("like a child", "like/ADP a/DET child/NOUN"),)),
    "old": LabelStyle("old", None, (phrase("like an old person", "like/ADP an/DET old/ADJ person/NOUN"),)),
    "tired": LabelStyle(
        "tired", "wearily", (phrase("like a tired person", "like/ADP a/DET tired/ADJ person/NOUN"),), "tired"
    ),
    "musical": LabelStyle(
        "theatrical",
        "theatrically",
        (phrase("like an actor in a musical", "like/ADP an/DET actor/NOUN in/ADP a/DET musical/NOUN"),),
    ),
    "giant": LabelStyle("lumbering", "heavily", (phrase("like a giant", "like/ADP a/DET giant/NOUN"),)),
    "chimpira": LabelStyle(
        "thuggish",
        None,
        (
            phrase("like a thug", "like/ADP a/DET thug/NOUN"),
            phrase("like a street punk", "like/ADP a/DET street/NOUN punk/NOUN"),
        ),
    ),
}
_STYLE_ALIASES = {"children": "childish", "childlike": "childish", "notconfident": "not-confident"}

_SUBJECTS = (
    phrase("a person", "a/DET person/NOUN"),
    phrase("someone", "someone/PRON"),
    phrase("the person", "the/DET person/NOUN"),
)
_IS = phrase("is", "is/AUX")
_COMMA = Phrase(",", ())


def label_key(label: str | None) -> str:
    """A label as the tables spell it: lowercase, words joined by '-' ('Walk_Turn Left' -> 'walk-turn-left')."""
    return re.sub(r"[\s_]+", "-", (label or "").strip().lower())


def is_neutral(style: str | None) -> bool:
    """No style, or a neutral one (``normal``, ``neutral``, ``natural``): captions carry no style words."""
    return not style or label_key(style) in NEUTRAL_STYLES


def content_phrases(content: str) -> tuple[Phrase, ...]:
    """Third-person verb phrases for a content; an unknown one reads "performs a(n) <words> motion"."""
    key = label_key(content)
    if key in CONTENT_PHRASES:
        return CONTENT_PHRASES[key]
    words = [w.lower() for w in _WORD.findall(key.replace("-", " "))]
    if not words:
        return (phrase("moves", "move/VERB"),)
    a = article(words[0])
    return (
        phrase(
            f"performs {a} {' '.join(words)} motion",
            " ".join(["perform/VERB", f"{a}/DET", *(f"{w}/NOUN" for w in words), "motion/NOUN"]),
        ),
    )


def label_style(style: str | None) -> LabelStyle | None:
    """The words for a style; None for the neutral style; an unknown one is named by its label as an adjective."""
    if is_neutral(style):
        return None
    key = label_key(style)
    key = _STYLE_ALIASES.get(key, key)
    if key in LABEL_STYLES:
        return LABEL_STYLES[key]
    words = [w.lower() for w in re.findall(r"[A-Za-z]+", key)]
    return LabelStyle(" ".join(words)) if words else None


def label_style_words() -> dict[str, StyleWords]:
    """Every style label's words as ``StyleWords``, the target ``style`` argument of ``revise_caption``."""
    return {name: style.words for name, style in LABEL_STYLES.items()}


def neutralising_vocab(base: Mapping[str, StyleVocab]) -> dict[str, StyleVocab]:
    """``base`` (the other style words a caller knows) plus every label style, with each comma form
    ("..., exhausted.") added as a phrase so that ``revise_caption``/``neutralise_caption`` remove it too."""
    vocab: dict[str, StyleVocab] = dict(base)
    for name, style in LABEL_STYLES.items():
        extra = (style.depictive,) if style.depictive else ()
        words = style.words
        vocab[f"label:{name}"] = StyleWords(
            adjective=words.adjective, adverb=words.adverb, phrases=(*words.phrases, *extra)
        )
    return vocab


# ---- captions ---------------------------------------------------------------------------------------------------


def _neutral_groups(verbs: tuple[Phrase, ...]) -> list[list[Caption]]:
    """One group per verb phrase: every subject, present and progressive."""
    return [[_join(s, v) for s in _SUBJECTS] + [_join(s, _IS, v.progressive()) for s in _SUBJECTS] for v in verbs]


def _styled_groups(verbs: tuple[Phrase, ...], style: LabelStyle) -> list[list[Caption]]:
    """One group per way of naming the style: adjective on the subject, adverb, each phrase, the comma form."""
    a = article(style.adjective)
    adjective = phrase(f"{a} {style.adjective} person", f"{a}/DET {_tags(style.adjective, 'ADJ')} person/NOUN")
    groups = [[_join(adjective, v) for v in verbs]]
    if style.adverb:
        adverb = phrase(style.adverb, _tags(style.adverb, "ADV"))
        groups.append([_join(s, v, adverb) for v in verbs for s in _SUBJECTS])
    for tail in (style.way(), *style.phrases):
        subjects = _SUBJECTS[1:2] if "person/NOUN" in tail.tokens else _SUBJECTS  # not "a person ... like a person"
        groups.append([_join(s, v, tail) for v in verbs for s in subjects])
    if style.depictive:
        state = phrase(style.depictive, _tags(style.depictive, "ADJ"))
        groups.append([_join(s, _IS, v.progressive(), _COMMA, state) for v in verbs for s in _SUBJECTS])
    return groups


def _groups(content: str, style: str | None) -> list[list[Caption]]:
    verbs = content_phrases(content)
    words = label_style(style)
    return _neutral_groups(verbs) if words is None else _styled_groups(verbs, words)


def all_label_captions(content: str, style: str | None) -> list[Caption]:
    """Every phrasing this module writes for the pair, in a fixed order."""
    captions = {c.text: c for group in _groups(content, style) for c in group}
    return list(captions.values())


def label_caption(content: str, style: str | None) -> Caption:
    """The plainest caption for the pair: 'a person walks forward.', 'an elderly person walks and turns right.'."""
    return _groups(content, style)[0][0]


def label_captions(content: str, style: str | None, n: int = 3, seed: int | str = 0) -> list[Caption]:
    """``n`` distinct captions for one clip (fewer only if the pair has fewer phrasings).

    Captions come round-robin from the groups (ways of naming the style, or verb phrases for neutral clips) starting
    at a seeded group, each group shuffled by the seed, so clips of one label pair get varied captions and the same
    (content, style, seed) always gives the same ones. Pass the clip id as ``seed``.
    """
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    rng = random.Random(f"{seed}|{label_key(content)}|{label_key(style)}")
    groups = [rng.sample(group, len(group)) for group in _groups(content, style)]
    start = rng.randrange(len(groups))
    groups = groups[start:] + groups[:start]
    out: list[Caption] = []
    seen: set[str] = set()
    while len(out) < n and any(groups):
        for group in groups:
            while group and group[-1].text in seen:
                group.pop()
            if group and len(out) < n:
                caption = group.pop()
                seen.add(caption.text)
                out.append(caption)
    return out
