"""Captions rewritten for a stylized clip: old style words out, the new style in, tokens kept valid.

The seed paper's code revises HumanML3D captions by inserting the style word after each verb found in the lemma/POS
tokens; this module does that and two other phrasings (adjective on the subject noun, trailing phrase) so an
expanded corpus does not repeat one template. A caption is a list of words, each with the text before it and its
``lemma/POS`` token; only alphabetic words carry tokens, as in HumanML3D, so the tokens stay aligned with
``caption_words(text)``. Captions without usable tokens are tagged by a small rule-based lexicon instead of spaCy,
which is not a dependency.
"""

from __future__ import annotations

import random
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from functools import lru_cache
from typing import Protocol

from motionaug.augment.text.tokens import parse_token
from motionaug.schemas.captions import Caption
from motionaug.schemas.errors import MotionDataError


class StyleVocab(Protocol):
    """Anything naming a style like ``schemas.styles.StyleWords`` (the synthetic corpus's dataclass too)."""

    @property
    def adjective(self) -> str: ...
    @property
    def adverb(self) -> str | None: ...
    @property
    def phrases(self) -> tuple[str, ...]: ...


# ---- lexicon for captions without tokens ---------------------------------------------------------------------

_CLOSED: dict[str, str] = {
    **dict.fromkeys(
        "a an the this that these those his her its their my your our both each every another some".split(), "DET"
    ),
    **dict.fromkeys(
        "he she it they him them someone somebody something anyone everyone himself herself themselves itself".split(),
        "PRON",
    ),
    **dict.fromkeys(
        "with to in on at from into onto over under of by for like across along through toward towards behind above "
        "below near beside between against about after before up down without".split(),
        "ADP",
    ),
    **dict.fromkeys(
        "forward forwards backward backwards sideways around away back then again slowly quickly slightly straight "
        "ahead together out off here there also still very fast twice once".split(),
        "ADV",
    ),
    **dict.fromkeys("and or but".split(), "CCONJ"),
    **dict.fromkeys("while as if because".split(), "SCONJ"),
    **dict.fromkeys("is are was were be been being am has have had can will would should could".split(), "AUX"),
    **dict.fromkeys("not".split(), "PART"),
    **dict.fromkeys("one two three four five six seven eight nine ten".split(), "NUM"),
    **dict.fromkeys(
        "left right other several few small big large long short high low full half same quick slow".split(), "ADJ"
    ),
    **dict.fromkeys("elderly sad little young happy silly lively friendly ugly".split(), "ADJ"),  # -ly, yet not adverbs
    # the style adjectives of the embedded styles and of the Bandai labels (motionaug.augment.text.label_captions)
    **dict.fromkeys(
        "old proud angry tired exhausted depressed sneaky childlike childish cheerful gloomy timid feminine masculine "
        "youthful theatrical lumbering thuggish energetic active heavy light confident nervous strutting".split(),
        "ADJ",
    ),
}
_NOUNS = (
    "person man woman human figure guy lady boy girl child kid individual character body arm leg hand foot head "
    "knee hip shoulder elbow wrist finger toe chest torso waist step circle line way direction ground floor chair "
    "object ball box air spot place side time motion movement jump kick punch turn walk run squat dance wave lap "
    "square path stair manner fashion pride anger strut swagger thief tiptoe confidence actor musical giant thug "
    "street punk soldier robot zombie monkey"
).split()
_IRREGULAR_PLURALS = {"feet": "foot", "people": "people", "men": "man", "women": "woman", "children": "child"}
_VERBS = (
    "walk run jog jump hop skip kick punch wave turn step sit stand squat crouch bend lift raise lower throw catch "
    "dance spin climb crawl lean stretch swing move go stroll march sidestep shuffle stumble limp leap reach pick put "
    "place grab hold push pull clap bow kneel lie roll rotate shake nod look pace stomp tiptoe sneak strut swim box "
    "fight play perform take do get begin start continue stop return come bounce balance wobble sway rise fall drop "
    "slide twist touch hit swat swipe shrug rub wipe open close carry drink eat wash brush point salute gesture"
).split()
_IRREGULAR_VERBS: dict[str, tuple[str, ...]] = {
    "run": ("ran",),
    "sit": ("sat",),
    "stand": ("stood",),
    "go": ("went", "gone"),
    "swing": ("swung",),
    "throw": ("threw", "thrown"),
    "lie": ("lay", "lain", "lying"),
    "take": ("took", "taken"),
    "do": ("did", "done"),
    "get": ("got",),
    "begin": ("began", "begun"),
    "come": ("came",),
    "hold": ("held",),
    "catch": ("caught",),
    "leap": ("leapt",),
    "kneel": ("knelt",),
    "spin": ("spun",),
    "shake": ("shook", "shaken"),
    "bend": ("bent",),
    "rise": ("rose", "risen"),
    "fall": ("fell", "fallen"),
    "put": ("put",),
}
_DOUBLES_FINAL = frozenset(
    "run sit hop skip step jog spin swim stop begin get put grab clap nod strut drop rub swat".split()
)
# Subjects that take the style adjective: "a proud person walks".
SUBJECT_NOUNS = frozenset(
    "person man woman human figure guy lady boy girl child kid individual character people".split()
)
_OBJECT_START = frozenset({"DET", "PRON", "NOUN", "PROPN", "NUM", "ADJ"})  # an object follows: adverb before the verb
_WAY_NOUNS = ("way", "manner", "fashion")


def _verb_forms(lemma: str) -> set[str]:
    """Third person, -ing and -ed forms by the usual spelling rules, plus known irregular forms."""
    stem = lemma + lemma[-1] if lemma in _DOUBLES_FINAL else lemma
    if re.search(r"(s|sh|ch|x|z|o)$", lemma):
        third = lemma + "es"
    elif re.search(r"[^aeiou]y$", lemma):
        third = lemma[:-1] + "ies"
    else:
        third = lemma + "s"
    if lemma.endswith("ie"):
        ing, ed = lemma[:-2] + "ying", lemma + "d"
    elif lemma.endswith("e") and not lemma.endswith("ee"):
        ing, ed = lemma[:-1] + "ing", lemma + "d"
    else:
        ing, ed = stem + "ing", stem + "ed"
    return {lemma, third, ing, ed, *_IRREGULAR_VERBS.get(lemma, ())}


def _noun_forms(lemma: str) -> set[str]:
    plural = lemma + "es" if re.search(r"(s|sh|ch|x|z)$", lemma) else lemma + "s"
    return {lemma, plural}


_VERB_LEMMA: dict[str, str] = {form: lemma for lemma in _VERBS for form in _verb_forms(lemma)}
_NOUN_LEMMA: dict[str, str] = {form: lemma for lemma in _NOUNS for form in _noun_forms(lemma)} | _IRREGULAR_PLURALS

# ---- words of a caption ---------------------------------------------------------------------------------------

_CHUNK = re.compile(r"([A-Za-z0-9]+(?:-[A-Za-z0-9]+)*)('[A-Za-z]+)?")
_STYLE_WORD = re.compile(r"[A-Za-z]+(?:-[A-Za-z]+)*")


@dataclass(frozen=True)
class _Word:
    pre: str  # the text between the previous word and this one
    text: str  # surface form
    token: str | None = None  # 'lemma/POS' for counted words

    @property
    def key(self) -> str:
        """The word as HumanML3D's tokenizer sees it: lowercase, hyphens dropped."""
        return self.text.lower().replace("-", "")

    @property
    def counted(self) -> bool:
        return self.key.isalpha()

    @property
    def pos(self) -> str:
        return self.token.rpartition("/")[2] if self.token else ""

    @property
    def lemma(self) -> str:
        return self.token.rpartition("/")[0] if self.token else self.key


@dataclass(frozen=True)
class _Doc:
    words: tuple[_Word, ...]
    tail: str  # text after the last word ("." or "")

    def counted(self) -> list[int]:
        return [i for i, w in enumerate(self.words) if w.counted]

    def render(self) -> str:
        text = "".join(w.pre + w.text for w in self.words) + self.tail
        text = re.sub(r"\s+", " ", text).strip()
        text = re.sub(r" ([,.;:!?])", r"\1", text)
        text = re.sub(r"[,;:]+(?=[,.;:!?]|$)", "", text)  # a comma left before '.' by a removal
        return re.sub(r"^[,;:.!?]+ ?", "", text)  # or at the start ("Proudly, a man ...")

    def tokens(self) -> list[str]:
        return [w.token for w in self.words if w.counted and w.token]


def _split(text: str) -> _Doc:
    """Words with the text before each; clitics ("'s", "n't") and numbers are kept but not counted."""
    words: list[_Word] = []
    pos = 0
    for match in _CHUNK.finditer(text):
        core, clitic = match.group(1), match.group(2) or ""
        if clitic.lower() == "'t" and len(core) > 1 and core.lower().endswith("n"):
            core, clitic = core[:-1], core[-1] + clitic  # "don't" -> "do" + "n't", as spaCy splits it
        words.append(_Word(text[pos : match.start()], core))
        if clitic:
            words.append(_Word("", clitic))
        pos = match.end()
    return _Doc(tuple(words), text[pos:])


def caption_words(text: str) -> list[str]:
    """The words a HumanML3D token field lists for ``text``, one per token (lowercase, no hyphens)."""
    return [w.key for w in _split(text).words if w.counted]


def _third_person_lemma(word: str) -> str:
    """'pirouettes' -> 'pirouette', 'punches' -> 'punch', 'goes' -> 'go' (unknown verbs after a subject)."""
    return word[:-2] if re.search(r"(sh|ch|ss|x|z|o)es$", word) else word[:-1]


def _tag(word: str, prev_pos: str, next_word: str) -> str:
    """``lemma/POS`` for one lowercase word from the lexicon and its neighbours; unknown words are X."""
    is_verb, is_noun = word in _VERB_LEMMA, word in _NOUN_LEMMA
    if is_verb and is_noun:  # "a kick" / "kicks", "on tiptoe" / "tiptoes": a noun after a determiner or preposition
        is_noun = prev_pos in ("DET", "ADJ", "NUM", "ADP")
        is_verb = not is_noun
    if is_noun:
        return f"{_NOUN_LEMMA[word]}/NOUN"
    if is_verb:
        return f"{_VERB_LEMMA[word]}/VERB"
    if word == "to" and next_word in _VERB_LEMMA:
        return "to/PART"
    if word in _CLOSED:
        return f"{word}/{_CLOSED[word]}"
    if word.endswith("ly") and len(word) > 4:
        return f"{word}/ADV"
    if prev_pos in ("NOUN", "PRON", "PROPN") and re.fullmatch(r"[a-z]{3,}[^s]s", word):  # "a person pirouettes"
        return f"{_third_person_lemma(word)}/VERB"
    if prev_pos == "AUX" and word.endswith("ing") and len(word) > 5:
        return f"{word[:-3]}/VERB"
    if prev_pos in ("DET", "ADJ"):  # inside a noun phrase: a modifier before its noun, else the noun itself
        return f"{word}/ADJ" if next_word in _NOUN_LEMMA else f"{word}/NOUN"
    return f"{word}/X"


def _tagged(words: Sequence[_Word]) -> list[_Word]:
    """Every counted word tagged by rule (captions without usable tokens)."""
    keys = [w.key if w.counted else "" for w in words]
    out: list[_Word] = []
    prev_pos = ""
    for i, word in enumerate(words):
        if not word.counted:
            out.append(replace(word, token=None))
            continue
        following = next((k for k in keys[i + 1 :] if k), "")
        token = _tag(word.key, prev_pos, following)
        out.append(replace(word, token=token))
        prev_pos = token.rpartition("/")[2]
    return out


def _parse(caption: Caption, source: str) -> _Doc:
    """The caption's words with tokens: its own when they line up one-to-one, else tagged by rule."""
    doc = _split(caption.text)
    for item in caption.tokens:
        parse_token(item, source)
    counted = doc.counted()
    if caption.tokens and len(caption.tokens) == len(counted):
        words = list(doc.words)
        for i, token in zip(counted, caption.tokens, strict=True):
            words[i] = replace(words[i], token=token)
        return _Doc(tuple(words), doc.tail)
    return _Doc(tuple(_tagged(doc.words)), doc.tail)


def _to_caption(doc: _Doc, original: Caption, source: str) -> Caption:
    text = doc.render()
    if not caption_words(text):
        raise MotionDataError(source, f"no words left in caption {original.text!r} after revision")
    tokens = doc.tokens()
    for item in tokens:
        parse_token(item, source)
    return Caption(text=text, tokens=tokens, start=original.start, end=original.end)


# ---- editing words --------------------------------------------------------------------------------------------


def _article(next_word: str, like: str) -> str:
    """'a' or 'an' for the word that follows, in the case of the article it replaces."""
    article = "an" if next_word[:1].lower() in "aeiou" else "a"
    return article.capitalize() if like[:1].isupper() else article


def _fix_article(words: list[_Word], i: int) -> None:
    """Make the a/an at ``i`` agree with the word after it (after an insertion or removal)."""
    if not 0 <= i < len(words) - 1 or words[i].key not in ("a", "an"):
        return
    new = _article(words[i + 1].text, words[i].text)
    words[i] = replace(words[i], text=new, token=f"{new.lower()}/{words[i].pos or 'DET'}")


def _remove(doc: _Doc, indices: Iterable[int]) -> _Doc:
    """Drop words, keeping any punctuation that stood before them; fix a/an before each gap."""
    words, tail = list(doc.words), doc.tail
    for i in sorted(set(indices), reverse=True):
        punct = words[i].pre if words[i].pre.strip() else ""
        del words[i]
        if i < len(words):
            words[i] = replace(words[i], pre=punct + words[i].pre if punct else words[i].pre)
        else:
            tail = punct + tail
        _fix_article(words, i - 1)
    return _Doc(tuple(words), tail)


def _new_words(phrase: str, style: StyleVocab) -> list[_Word]:
    """Words of a style phrase with tokens: the style's own adjective/adverb tagged as such, others by rule."""
    words = _tagged(_split(phrase).words)
    adjective, adverb = _keys(style.adjective), _keys(style.adverb or "")
    out = []
    for w in words:
        if w.key in adverb:
            w = replace(w, token=f"{w.key}/ADV")
        elif w.key in adjective:
            w = replace(w, token=f"{w.key}/ADJ")
        out.append(replace(w, text=w.text.lower(), pre=" "))
    return out


def _insert(doc: _Doc, at: int, new: Sequence[_Word], before_word: bool = False) -> _Doc:
    """Insert words at index ``at`` (``len`` appends before the tail).

    ``before_word``: the words lead into ``doc.words[at]`` ("proudly kicks"), so they take over the text
    before it; otherwise they close what precedes ("walks proudly, then"), so that text stays put.
    """
    words = list(doc.words)
    if at < len(words) and before_word:
        first_pre, words[at] = words[at].pre, replace(words[at], pre=" ")
        new = [replace(new[0], pre=first_pre), *new[1:]]
    words[at:at] = new
    return _Doc(tuple(words), doc.tail)


# ---- style forms --------------------------------------------------------------------------------------------


def _keys(phrase: str) -> tuple[str, ...]:
    return tuple(w.key for w in _split(phrase).words if w.counted)


def _check_style(style: StyleVocab) -> None:
    """Style words are inserted into captions, so each must be plain words that a token field can carry."""
    for form in (style.adjective, style.adverb or "", *style.phrases):
        if form and not all(_STYLE_WORD.fullmatch(part) for part in form.split()):
            raise MotionDataError(
                f"style {style.adjective!r}", f"style word {form!r} is not plain words (letters, hyphens)"
            )


def _way_phrase(adjective: str) -> str:
    return f"in {_article(adjective, 'a')} {adjective} way"


@dataclass(frozen=True)
class _Form:
    keys: tuple[str, ...]
    attributive: bool = False  # an adjective: only removed before a person noun


def _forms(vocab: Iterable[StyleVocab]) -> tuple[_Form, ...]:
    """Every phrase, adverb, 'in a(n) ADJ way/manner/fashion' and adjective; longest first.

    Memoised on the words themselves: transfer revises thousands of captions with one vocabulary.
    """
    return _forms_of(tuple((style.adjective, style.adverb, tuple(style.phrases)) for style in vocab))


@lru_cache(maxsize=64)
def _forms_of(vocab: tuple[tuple[str, str | None, tuple[str, ...]], ...]) -> tuple[_Form, ...]:
    forms: set[_Form] = set()
    for adjective_text, adverb, phrases in vocab:
        for text in (*phrases, adverb or ""):
            if _keys(text):
                forms.add(_Form(_keys(text)))
        adjective = _keys(adjective_text)
        for noun in _WAY_NOUNS:
            for article in ("a", "an"):
                forms.add(_Form(("in", article, *adjective, noun)))
        forms.add(_Form(adjective, attributive=True))
    return tuple(sorted(forms, key=lambda f: (-len(f.keys), f.keys)))


def _matches(doc: _Doc, forms: Sequence[_Form]) -> set[int]:
    """Word indices (into ``doc.words``) of style forms present; a coordinating word between two goes too."""
    counted = doc.counted()
    keys = [doc.words[i].key for i in counted]
    hit: set[int] = set()  # positions in ``counted``
    for form in forms:
        n = len(form.keys)
        for start in range(len(keys) - n + 1):
            span = range(start, start + n)
            if tuple(keys[start : start + n]) != form.keys or hit.intersection(span):
                continue
            if form.attributive and not _before_person(doc, counted, start + n - 1):
                continue
            hit.update(span)
    for j in range(1, len(counted) - 1):
        if (
            doc.words[counted[j]].pos == "CCONJ"
            and j - 1 in hit
            and j + 1 in hit
            and not _joins_verbs(doc, counted, hit, j)
        ):
            hit.add(j)  # "proudly and angrily" -> nothing left to coordinate
    return {counted[j] for j in hit}


def _joins_verbs(doc: _Doc, counted: list[int], hit: set[int], j: int) -> bool:
    """The coordinating word at counted position ``j`` joins two verb phrases, each with its own style form
    ("walks angrily and angrily walks"): a verb just before the forms on its left and just after those on its right."""
    start, end = j - 1, j + 1
    while start - 1 in hit:
        start -= 1
    while end + 1 in hit:
        end += 1
    before = doc.words[counted[start - 1]].pos if start > 0 else ""
    after = doc.words[counted[end + 1]].pos if end + 1 < len(counted) else ""
    return before == "VERB" and after == "VERB"


def _before_person(doc: _Doc, counted: list[int], j: int) -> bool:
    """The adjective at counted position ``j`` modifies a person noun (possibly through other adjectives)."""
    for k in counted[j + 1 :]:
        word = doc.words[k]
        if word.pos != "ADJ":
            return word.pos == "NOUN" and word.lemma.lower() in SUBJECT_NOUNS
    return False


def _vocab(vocab: Mapping[str, StyleVocab], *extra: StyleVocab) -> list[StyleVocab]:
    return [*vocab.values(), *extra]


def _neutral_doc(doc: _Doc, vocab: Sequence[StyleVocab]) -> _Doc:
    return _remove(doc, _matches(doc, _forms(vocab)))


def _as_caption(caption: Caption | str) -> Caption:
    return Caption(text=caption) if isinstance(caption, str) else caption


def neutralise_caption(caption: Caption, vocab: Mapping[str, StyleVocab]) -> Caption:
    """The caption without any known style's words ("a person walks sadly" -> "a person walks"), tokens kept valid."""
    source = f"caption {caption.text!r}"
    return _to_caption(_neutral_doc(_parse(caption, source), _vocab(vocab)), caption, source)


def has_style_words(caption: Caption | str, vocab: Mapping[str, StyleVocab]) -> bool:
    """Whether ``neutralise_caption`` would remove anything (predicate adjectives, "is angry", do not count)."""
    caption = _as_caption(caption)
    doc = _parse(caption, f"caption {caption.text!r}")
    return bool(_matches(doc, _forms(_vocab(vocab))))


# ---- revision -----------------------------------------------------------------------------------------------


def _phrase_options(style: StyleVocab) -> list[str]:
    """Trailing phrases for the style: 'in a(n) ADJ way' first, then its own phrases."""
    options = [_way_phrase(style.adjective), *style.phrases]
    return list(dict.fromkeys(" ".join(p.split()) for p in options))


def variant_kinds(style: StyleVocab) -> list[str]:
    """The phrasings ``revise_caption`` can produce: 'adverb' (if any), 'adjective', 'phrase:0'..."""
    head = ["adverb"] if style.adverb else []
    return [*head, "adjective", *(f"phrase:{i}" for i in range(len(_phrase_options(style))))]


def _kind(style: StyleVocab, variant: int | str) -> str:
    kinds = variant_kinds(style)
    if isinstance(variant, int):
        return kinds[variant % len(kinds)]
    kind = "phrase:0" if variant == "phrase" else variant
    if kind not in kinds and kind != "adverb":  # 'adverb' of a style without one falls back to a phrase
        raise MotionDataError(f"style {style.adjective!r}", f"unknown caption variant {variant!r}; known: {kinds}")
    return kind


@dataclass(frozen=True)
class _Slot:
    at: int
    before_verb: bool


def _verb_slots(doc: _Doc) -> list[_Slot]:
    """Where the adverb goes for each verb group: after its last verb, or before it when an object follows."""
    slots = []
    for i, word in enumerate(doc.words):
        if word.pos != "VERB" or word.key == "left":  # HumanML3D tags "left" VERB now and then
            continue
        nxt = doc.words[i + 1] if i + 1 < len(doc.words) else None
        if nxt is None or nxt.pre.strip():  # last word, or punctuation follows ("walks, then ...")
            slots.append(_Slot(i + 1, before_verb=False))
        elif nxt.pos == "VERB" or (nxt.pos == "PART" and i + 2 < len(doc.words) and doc.words[i + 2].pos == "VERB"):
            continue  # "starts walking", "begins to walk": the adverb goes with the last verb
        else:
            object_next = not nxt.counted or nxt.pos in _OBJECT_START  # "kicks something", "turns 90 degrees"
            slots.append(_Slot(i, True) if object_next else _Slot(i + 1, False))
    return slots


def _subject_slot(doc: _Doc) -> int | None:
    """Index to insert an adjective at: before the subject person noun (and its adjectives), else None."""
    counted = doc.counted()
    for n, i in enumerate(counted):
        word = doc.words[i]
        if word.pos in ("VERB", "AUX"):
            return None
        if word.pos == "NOUN" and word.lemma.lower() in SUBJECT_NOUNS:
            while n > 0 and doc.words[counted[n - 1]].pos == "ADJ":
                n -= 1
            return counted[n]
    return None


def _with_adverb(doc: _Doc, style: StyleVocab) -> _Doc | None:
    slots = _verb_slots(doc)
    if not style.adverb or not slots:
        return None
    for slot in reversed(slots):
        doc = _insert(doc, slot.at, _new_words(style.adverb, style), before_word=slot.before_verb)
    return doc


def _with_adjective(doc: _Doc, style: StyleVocab) -> _Doc | None:
    slot = _subject_slot(doc)
    if slot is None:
        return None
    doc = _insert(doc, slot, _new_words(style.adjective, style), before_word=True)
    words = list(doc.words)
    _fix_article(words, slot - 1)
    return _Doc(tuple(words), doc.tail)


def _with_phrase(doc: _Doc, style: StyleVocab, index: int) -> _Doc:
    return _insert(doc, len(doc.words), _new_words(_phrase_options(style)[index], style))


def _styled(doc: _Doc, style: StyleVocab, kind: str) -> _Doc:
    """Apply one phrasing; an adjective without a subject falls back to the adverb, an adverb without a verb to a
    phrase."""
    if kind == "adjective":
        done = _with_adjective(doc, style)
        return done if done is not None else _styled(doc, style, "adverb")
    if kind == "adverb":
        done = _with_adverb(doc, style)
        return done if done is not None else _with_phrase(doc, style, 0)
    return _with_phrase(doc, style, int(kind.partition(":")[2]))


def revise_caption(
    caption: Caption, style: StyleVocab, variant: int | str = 0, *, vocab: Mapping[str, StyleVocab]
) -> Caption:
    """The caption in ``style``: known style words (``vocab`` plus ``style``) are
    removed first, then the style goes in as ``variant`` (an index into ``variant_kinds(style)`` or a kind name)."""
    _check_style(style)
    source = f"caption {caption.text!r}"
    doc = _neutral_doc(_parse(caption, source), _vocab(vocab, style))
    if not doc.counted():
        raise MotionDataError(source, "nothing but style words in the caption")
    return _to_caption(_styled(doc, style, _kind(style, variant)), caption, source)


def revised_captions(
    captions: list[Caption],
    style: StyleVocab,
    n_variants: int = 3,
    seed: int = 0,
    *,
    vocab: Mapping[str, StyleVocab],
) -> list[Caption]:
    """Distinct revised phrasings for one clip: one per caption (at least ``n_variants``, cycling the captions),
    the kinds cycling adverb / adjective / phrase from a seeded start, a later kind taken when one repeats a text."""
    if n_variants < 1:
        raise MotionDataError("revised_captions", f"n_variants must be >= 1, got {n_variants}")
    if not captions:
        return []
    rng = random.Random(seed)
    kinds = variant_kinds(style)
    families = [k for k in ("adverb", "adjective") if k in kinds] + ["phrase"]
    start = rng.randrange(len(families))
    out: list[Caption] = []
    seen: set[str] = set()
    for k in range(max(len(captions), n_variants)):
        family = families[(start + k) % len(families)]
        first = f"phrase:{rng.randrange(len(_phrase_options(style)))}" if family == "phrase" else family
        for kind in [first, *(x for x in kinds if x != first)]:
            revised = revise_caption(captions[k % len(captions)], style, kind, vocab=vocab)
            if revised.text not in seen:
                seen.add(revised.text)
                out.append(revised)
                break
    return out


# ---- descriptions of style examples --------------------------------------------------------------------------


def style_word_in(description: str, words: StyleVocab) -> str | None:
    """The first of the style's forms (longest first) that the description contains as whole words, else None."""
    keys = caption_words(description)
    forms = [*(_keys(p) for p in words.phrases), _keys(words.adverb or ""), _keys(words.adjective)]
    for form in sorted((f for f in forms if f), key=len, reverse=True):
        n = len(form)
        if any(tuple(keys[i : i + n]) == form for i in range(len(keys) - n + 1)):
            return " ".join(form)
    return None


def require_style_word(description: str, words: StyleVocab, source: str) -> str:
    """``style_word_in`` or a clear error: a description must name its style for the pair to mean anything."""
    found = style_word_in(description, words)
    if found is None:
        forms = [f for f in (words.adjective, words.adverb, *words.phrases) if f]
        raise MotionDataError(source, f"description {description!r} names none of the style's words {forms}")
    return found


def neutral_description(description: str, vocab: Mapping[str, StyleVocab]) -> str:
    """The description without style words ("a person walks proudly" -> "a person walks"); an adjective that
    cannot be dropped ("the walk is angry") becomes "neutral"."""
    source = f"description {description!r}"
    doc = _neutral_doc(_parse(Caption(text=description), source), _vocab(vocab))
    adjectives = {_keys(style.adjective) for style in _vocab(vocab)}
    words = list(doc.words)
    for i, word in enumerate(words):
        if (word.key,) in adjectives and word.pos not in ("VERB", "NOUN"):
            words[i] = replace(word, text="neutral", token="neutral/ADJ")
            _fix_article(words, i - 1)
    text = _Doc(tuple(words), doc.tail).render()
    if not caption_words(text):
        raise MotionDataError(source, "nothing left after removing the style words")
    return text
