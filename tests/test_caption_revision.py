"""Caption revision: style words in, old style words out, HumanML3D tokens kept valid and aligned."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from motionaug.augment.synth.styles import STYLE_WORDS
from motionaug.augment.text.caption_revision import (
    caption_words,
    has_style_words,
    neutral_description,
    neutralise_caption,
    require_style_word,
    revise_caption,
    revised_captions,
    style_word_in,
    variant_kinds,
)
from motionaug.augment.text.tokens import parse_caption_line, parse_token
from motionaug.schemas.captions import Caption
from motionaug.schemas.errors import MotionDataError
from motionaug.schemas.styles import StyleWords

LINES = [
    "a man kicks something with his left leg.#a/DET man/NOUN kick/VERB something/PRON with/ADP his/DET left/ADJ leg/NOUN#0.0#0.0",  # noqa: E501 (a real caption line)
    "a person walks forward and then turns around.#a/DET person/NOUN walk/VERB forward/ADV and/CCONJ then/ADV turn/VERB around/ADV#0.0#0.0",  # noqa: E501 (a real caption line)
    "the person is jumping up and down#the/DET person/NOUN is/AUX jump/VERB up/ADP and/CCONJ down/ADP#0.0#0.0",
    "someone sadly walks in a circle.#someone/PRON sadly/ADV walk/VERB in/ADP a/DET circle/NOUN#0.0#0.0",
]
CAPTIONS = [parse_caption_line(line, f"texts/line{i}") for i, line in enumerate(LINES)]
WORDS = STYLE_WORDS  # the built-in styles' words, neutralised before a style goes in
STYLES = {
    name: StyleWords(adjective=w.adjective, adverb=w.adverb, phrases=w.phrases) for name, w in STYLE_WORDS.items()
}
PROUD, OLD, ANGRY = STYLES["proud"], STYLES["old"], STYLES["angry"]
LEMMA_POS = {"NOUN", "VERB"}  # HumanML3D lemmatises only these; other tokens carry the word itself


def assert_valid_and_aligned(caption: Caption) -> None:
    """Every token parses, one token per counted word, and non-lemmatised tokens spell their word."""
    words = caption_words(caption.text)
    assert len(caption.tokens) == len(words), (caption.text, caption.tokens)
    for word, item in zip(words, caption.tokens, strict=True):
        lemma, pos = parse_token(item, "test")
        if pos not in LEMMA_POS:
            assert lemma == word, (caption.text, item)
        else:
            assert word.startswith(lemma[:2]) or lemma == "be", (caption.text, item)


def all_variants(style: StyleWords) -> list[str | int]:
    return list(range(len(variant_kinds(style))))


@pytest.mark.parametrize(
    ("index", "variant", "expected", "token_slice"),
    [
        (1, "adverb", "a person walks proudly forward and then turns proudly around.", ["walk/VERB", "proudly/ADV"]),
        (0, "adverb", "a man proudly kicks something with his left leg.", ["proudly/ADV", "kick/VERB"]),
        (2, "adverb", "the person is jumping proudly up and down", ["jump/VERB", "proudly/ADV"]),
        (0, "adjective", "a proud man kicks something with his left leg.", ["a/DET", "proud/ADJ", "man/NOUN"]),
        (
            1,
            "phrase",
            "a person walks forward and then turns around in a proud way.",
            ["in/ADP", "a/DET", "proud/ADJ", "way/NOUN"],
        ),
        (3, "adverb", "someone walks proudly in a circle.", ["walk/VERB", "proudly/ADV"]),
        (3, "phrase:1", "someone walks in a circle with pride.", ["with/ADP", "pride/NOUN"]),
    ],
)
def test_reference_lines(index: int, variant: str, expected: str, token_slice: list[str]) -> None:
    revised = revise_caption(CAPTIONS[index], PROUD, variant, vocab=WORDS)
    assert revised.text == expected
    assert any(revised.tokens[i : i + len(token_slice)] == token_slice for i in range(len(revised.tokens)))
    assert_valid_and_aligned(revised)
    assert (revised.start, revised.end) == (CAPTIONS[index].start, CAPTIONS[index].end)


def test_adjective_fixes_the_article_and_styles_without_adverb_use_phrases() -> None:
    assert revise_caption(CAPTIONS[1], ANGRY, "adjective", vocab=WORDS).text.startswith("an angry person walks")
    assert revise_caption(CAPTIONS[0], OLD, "adjective", vocab=WORDS).tokens[:3] == [
        "an/DET",
        "old/ADJ",
        "man/NOUN",
    ]
    for caption in CAPTIONS:
        revised = revise_caption(caption, OLD, "adverb", vocab=WORDS)  # no adverb for 'old': a phrase instead
        assert revised.text.rstrip(".").endswith("in an old way"), revised.text
    assert "adverb" not in variant_kinds(OLD)
    with pytest.raises(MotionDataError, match="unknown caption variant 'sideways'"):
        revise_caption(CAPTIONS[0], PROUD, "sideways", vocab=WORDS)


@pytest.mark.parametrize("style_name", sorted(STYLES))
def test_every_variant_valid_styled_distinct_and_idempotent(style_name: str) -> None:
    style = STYLES[style_name]
    for caption in CAPTIONS:
        texts = set()
        for variant in all_variants(style):
            revised = revise_caption(caption, style, variant, vocab=WORDS)
            assert_valid_and_aligned(revised)
            assert style_word_in(revised.text, style) is not None, revised.text
            assert "sadly" not in revised.text or style.adverb == "sadly"
            assert revise_caption(revised, style, variant, vocab=WORDS) == revised  # no doubled style words
            assert neutralise_caption(revised, vocab=WORDS) == neutralise_caption(caption, vocab=WORDS)
            texts.add(revised.text)
        # 'someone ...' has no person noun, so its adjective variant falls back to the adverb (or first phrase) one
        expected = len(all_variants(style)) - (caption is CAPTIONS[3])
        assert len(texts) == expected, texts


def test_restyling_replaces_the_previous_style() -> None:
    for variant in all_variants(PROUD):
        proud = revise_caption(CAPTIONS[1], PROUD, variant, vocab=WORDS)
        for angry_variant in all_variants(ANGRY):
            angry = revise_caption(proud, ANGRY, angry_variant, vocab=WORDS)
            assert style_word_in(angry.text, PROUD) is None, angry.text
            assert angry == revise_caption(CAPTIONS[1], ANGRY, angry_variant, vocab=WORDS)


def test_neutralise_and_has_style_words() -> None:
    sad = CAPTIONS[3]
    assert has_style_words(sad, vocab=WORDS) and has_style_words(sad.text, vocab=WORDS)
    neutral = neutralise_caption(sad, vocab=WORDS)
    assert neutral.text == "someone walks in a circle."
    assert neutral.tokens == ["someone/PRON", "walk/VERB", "in/ADP", "a/DET", "circle/NOUN"]
    assert not has_style_words(neutral, vocab=WORDS)
    assert not any(has_style_words(c, vocab=WORDS) for c in CAPTIONS[:3])
    both = Caption(text="An old man walks proudly and angrily, like a thief.")
    assert neutralise_caption(both, vocab=WORDS).text == "A man walks."
    assert_valid_and_aligned(neutralise_caption(both, vocab=WORDS))
    strut = Caption(text="a man is strutting", tokens=["a/DET", "man/NOUN", "is/AUX", "strut/VERB"])
    assert not has_style_words(strut, vocab=WORDS)  # the verb is content, not the 'strutting' adjective
    custom = {"bouncy": StyleWords(adjective="bouncy", adverb="bouncily")}
    assert neutralise_caption(Caption(text="a person hops bouncily"), custom).text == "a person hops"
    with pytest.raises(MotionDataError, match="no words left"):
        neutralise_caption(Caption(text="proudly."), vocab=WORDS)


def test_a_word_joining_two_styled_verbs_stays_and_revision_is_idempotent_there() -> None:
    # "and" between two style words goes with them only where it coordinates those words, not two verbs
    joined = Caption(text="walks angrily and angrily walks a")
    assert neutralise_caption(joined, vocab=WORDS).text == "walks and walks a"
    assert neutralise_caption(Caption(text="a person proudly and angrily walks"), vocab=WORDS).text == "a person walks"
    revised = revise_caption(Caption(text="walks and walks a"), ANGRY, 0, vocab=WORDS)
    assert revise_caption(revised, ANGRY, 0, vocab=WORDS) == revised


def test_captions_without_tokens_are_tagged_by_rule() -> None:
    plain = Caption(text="A man walks forward, then sits down.")
    revised = revise_caption(plain, PROUD, "adverb", vocab=WORDS)
    assert revised.text == "A man walks proudly forward, then sits proudly down."
    assert revised.tokens[:4] == ["a/DET", "man/NOUN", "walk/VERB", "proudly/ADV"]
    assert "sit/VERB" in revised.tokens
    assert_valid_and_aligned(revised)
    unknown = revise_caption(Caption(text="a person pirouettes twice"), PROUD, 0, vocab=WORDS)
    assert unknown.text == "a person pirouettes proudly twice" and "pirouette/VERB" in unknown.tokens
    no_verb = revise_caption(Caption(text="a person's t-pose, 90 degrees"), PROUD, "adverb", vocab=WORDS)
    assert no_verb.text == "a person's t-pose, 90 degrees in a proud way"
    assert no_verb.tokens[:3] == ["a/DET", "person/NOUN", "tpose/X"]
    assert_valid_and_aligned(no_verb)


def test_misaligned_or_bad_tokens() -> None:
    short = Caption(text="a person walks in a circle", tokens=["a/DET", "person/NOUN", "walk/VERB"])
    revised = revise_caption(short, PROUD, "adverb", vocab=WORDS)  # token field does not line up: re-tagged by rule
    assert revised.text == "a person walks proudly in a circle"
    assert_valid_and_aligned(revised)
    with pytest.raises(MotionDataError, match="unknown POS tag"):
        revise_caption(Caption(text="a man walks", tokens=["a/DET", "man/NOUNS", "walk/VERB"]), PROUD, vocab=WORDS)
    with pytest.raises(MotionDataError, match="not plain words"):
        revise_caption(CAPTIONS[0], StyleWords(adjective="proud/ADJ"), vocab=WORDS)


def test_revised_captions_deterministic_and_distinct() -> None:
    first = revised_captions(CAPTIONS[:3], PROUD, n_variants=3, seed=4, vocab=WORDS)
    assert first == revised_captions(CAPTIONS[:3], PROUD, n_variants=3, seed=4, vocab=WORDS)
    assert len(first) == 3 and len({c.text for c in first}) == 3
    kinds = {
        ("adj" if "proud " in c.text and "proud way" not in c.text else "adv" if "proudly" in c.text else "phrase")
        for c in first
    }
    assert kinds == {"adj", "adv", "phrase"}  # the three phrasings cycle over the clip's captions
    more = revised_captions(CAPTIONS[:2], OLD, n_variants=6, seed=0, vocab=WORDS)
    assert len(more) == 6 and len({c.text for c in more}) == 6
    for caption in more:
        assert_valid_and_aligned(caption)
    assert {revised_captions(CAPTIONS[:3], PROUD, seed=s, vocab=WORDS)[0].text for s in range(8)} != {first[0].text}
    assert revised_captions([], PROUD, vocab=WORDS) == []
    with pytest.raises(MotionDataError, match="n_variants"):
        revised_captions(CAPTIONS, PROUD, n_variants=0, vocab=WORDS)


def test_descriptions() -> None:
    assert style_word_in("a person walks proudly", PROUD) == "proudly"
    assert style_word_in("A man walks like an old person.", OLD) == "like an old person"
    assert style_word_in("a person walks", PROUD) is None
    assert style_word_in("an unproud walk", PROUD) is None  # whole words only
    with pytest.raises(MotionDataError, match="names none of the style's words"):
        require_style_word("a person walks", PROUD, "styles/proud.json")
    assert neutral_description("a person walks proudly", vocab=WORDS) == "a person walks"
    assert neutral_description("An old man walks like an old man.", vocab=WORDS) == "A man walks."
    assert neutral_description("the walk is angry", vocab=WORDS) == "the walk is neutral"
    with pytest.raises(MotionDataError, match="nothing left"):
        neutral_description("proudly", vocab=WORDS)


WORD_POOL = [
    ("a", "a/DET"),
    ("the", "the/DET"),
    ("person", "person/NOUN"),
    ("man", "man/NOUN"),
    ("figure", "figure/NOUN"),
    ("walks", "walk/VERB"),
    ("runs", "run/VERB"),
    ("turning", "turn/VERB"),
    ("kicks", "kick/VERB"),
    ("is", "is/AUX"),
    ("forward", "forward/ADV"),
    ("then", "then/ADV"),
    ("and", "and/CCONJ"),
    ("in", "in/ADP"),
    ("circle", "circle/NOUN"),
    ("left", "left/ADJ"),
    ("hands", "hand/NOUN"),
    ("someone", "someone/PRON"),
    ("sadly", "sadly/ADV"),
    ("proudly", "proudly/ADV"),
    ("twice", "twice/ADV"),
    ("up", "up/ADP"),
]
GLUE = st.sampled_from([" ", " ", " ", ", ", " , ", ". "])


@settings(max_examples=80, deadline=None)
@given(
    items=st.lists(st.sampled_from(WORD_POOL), min_size=1, max_size=10),
    glue=st.lists(GLUE, min_size=10, max_size=10),
    end=st.sampled_from(["", ".", " ."]),
    style_name=st.sampled_from(sorted(STYLES)),
    variant=st.integers(0, 5),
    with_tokens=st.booleans(),
)
def test_revision_keeps_tokens_aligned_property(
    items: list[tuple[str, str]], glue: list[str], end: str, style_name: str, variant: int, with_tokens: bool
) -> None:
    text = "".join(word + (glue[i] if i < len(items) - 1 else end) for i, (word, _) in enumerate(items))
    caption = Caption(text=text, tokens=[tok for _, tok in items] if with_tokens else [])
    style = STYLES[style_name]
    if all(word in ("sadly", "proudly") for word, _ in items):
        with pytest.raises(MotionDataError):
            revise_caption(caption, style, variant, vocab=WORDS)
        return
    revised = revise_caption(caption, style, variant, vocab=WORDS)
    assert_valid_and_aligned(revised)
    assert style_word_in(revised.text, style) is not None
    assert revise_caption(revised, style, variant, vocab=WORDS) == revised
    others = [w for name, w in STYLES.items() if name != style_name]
    for other in others:
        for form in (other.adverb, *other.phrases):
            if form and form not in (style.adverb, *style.phrases):
                assert f" {form} " not in f" {revised.text.rstrip('.')} ", (form, revised.text)


def test_label_captions_revised_into_every_bandai_style_are_fully_tagged() -> None:
    """No word of a revised Bandai caption is left untagged (X): style phrases get their real parts of speech."""
    from motionaug.augment.text.label_captions import CONTENT_PHRASES, label_captions, label_style_words

    untagged = {}
    for words in label_style_words().values():
        for content in CONTENT_PHRASES:
            for seed in range(4):
                for revised in revised_captions(
                    label_captions(content, "normal", n=3, seed="x"), words, 3, seed, vocab=WORDS
                ):
                    untagged.update({t: revised.text for t in revised.tokens if t.endswith("/X")})
    assert not untagged
