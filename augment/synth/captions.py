"""Caption templates for synthetic clips, with HumanML3D lemma/UPOS tokens.

Three captions per clip, as HumanML3D has about three per motion. Neutral clips carry no style
word; styled clips name the style as an adjective (``a proud person walks``), an adverb
(``walks proudly``) or a phrase (``in a proud way``), so a text-conditioned model can learn both
content and style from the words. Tokens come from a closed lexicon: every word a template can
produce is listed with its lemma and universal POS tag, so tokens never need a tagger.
"""

from __future__ import annotations

import numpy as np

from motionaug.augment.synth.animator import ClipSpec
from motionaug.augment.synth.styles import STYLE_WORDS
from motionaug.schemas.captions import Caption
from motionaug.schemas.errors import MotionDataError

CAPTIONS_PER_CLIP = 3

# Verb phrases after the subject, third person singular. {side} is "left" or "right".
TEMPLATES: dict[str, tuple[str, ...]] = {
    "walk": (
        "walks forward",
        "walks straight ahead",
        "is walking forward",
        "takes several steps forward",
        "strolls forward",
        "walks ahead",
    ),
    "run": ("runs forward", "jogs forward", "is running forward", "runs straight ahead", "is jogging ahead"),
    "walk_backward": (
        "walks backwards",
        "takes steps backwards",
        "is walking backwards",
        "moves backwards",
        "walks backward",
    ),
    "walk_curve": (
        "walks in a curve to the {side}",
        "walks forward and turns {side}",
        "walks along a curved path",
        "is walking in a curve",
        "walks in a circle to the {side}",
    ),
    "sidestep": (
        "sidesteps to the {side}",
        "steps sideways to the {side}",
        "walks sideways to the {side}",
        "shuffles sideways",
        "moves sideways to the {side}",
    ),
    "turn": (
        "turns around",
        "turns around to the {side}",
        "turns on the spot",
        "turns to the {side}",
        "steps in place and turns around",
    ),
    "jump": ("jumps forward", "leaps forward", "jumps forward with both feet", "does a long jump"),
    "jump_in_place": ("jumps up and down", "jumps in place", "hops on the spot", "jumps straight up"),
    "kick": (
        "kicks with the {side} leg",
        "kicks forward with the {side} foot",
        "does a kick with the {side} leg",
        "kicks the air",
        "kicks forward",
    ),
    "punch": ("punches forward", "throws punches", "punches with both hands", "is boxing", "throws a few punches"),
    "wave": (
        "waves with the {side} hand",
        "raises the {side} hand and waves",
        "waves hello",
        "waves the {side} arm",
        "is waving",
    ),
    "raise_hands": (
        "raises both hands",
        "raises both arms above the head",
        "lifts both hands up",
        "puts both hands in the air",
        "raises both arms",
    ),
    "squat": (
        "squats down",
        "does a squat",
        "squats and stands up",
        "bends the knees and squats",
        "squats down and stands back up",
    ),
}

SUBJECTS = ("a person", "a man", "someone", "the person", "a woman")
ADJ_NOUNS = ("person", "man", "woman")

# word -> (lemma, UPOS), as spaCy tags these words in captions like HumanML3D's
LEXICON: dict[str, tuple[str, str]] = {
    **{w: (w, "DET") for w in ("a", "an", "the", "both")},
    **{w: (w, "ADP") for w in ("in", "to", "along", "with", "like", "on", "above")},
    **{
        w: (w, "ADV")
        for w in (
            "forward",
            "straight",
            "ahead",
            "backwards",
            "backward",
            "sideways",
            "around",
            "up",
            "down",
            "back",
            "out",
            "proudly",
            "sadly",
            "playfully",
            "angrily",
            "confidently",
            "sneakily",
        )
    },
    **{
        w: (w, "ADJ")
        for w in (
            "left",
            "right",
            "curved",
            "several",
            "few",
            "long",
            "proud",
            "depressed",
            "sad",
            "old",
            "elderly",
            "childlike",
            "little",
            "angry",
            "sneaky",
            "strutting",
        )
    },
    **{
        w: (w, "NOUN")
        for w in (
            "person",
            "man",
            "woman",
            "way",
            "curve",
            "circle",
            "path",
            "kick",
            "squat",
            "leg",
            "foot",
            "hand",
            "arm",
            "head",
            "spot",
            "air",
            "place",
            "chest",
            "pride",
            "anger",
            "strut",
            "swagger",
            "child",
            "kid",
            "thief",
            "tiptoe",
            "step",
            "jump",
        )
    },
    "steps": ("step", "NOUN"),
    "feet": ("foot", "NOUN"),
    "hands": ("hand", "NOUN"),
    "arms": ("arm", "NOUN"),
    "punches": ("punch", "NOUN"),
    "knees": ("knee", "NOUN"),
    "someone": ("someone", "PRON"),
    "hello": ("hello", "INTJ"),
    "and": ("and", "CCONJ"),
    "is": ("be", "AUX"),
    "walks": ("walk", "VERB"),
    "walking": ("walk", "VERB"),
    "runs": ("run", "VERB"),
    "running": ("run", "VERB"),
    "jogs": ("jog", "VERB"),
    "jogging": ("jog", "VERB"),
    "takes": ("take", "VERB"),
    "strolls": ("stroll", "VERB"),
    "moves": ("move", "VERB"),
    "turns": ("turn", "VERB"),
    "sidesteps": ("sidestep", "VERB"),
    "shuffles": ("shuffle", "VERB"),
    "jumps": ("jump", "VERB"),
    "leaps": ("leap", "VERB"),
    "hops": ("hop", "VERB"),
    "kicks": ("kick", "VERB"),
    "does": ("do", "VERB"),
    "throws": ("throw", "VERB"),
    "boxing": ("box", "VERB"),
    "waves": ("wave", "VERB"),
    "waving": ("wave", "VERB"),
    "raises": ("raise", "VERB"),
    "lifts": ("lift", "VERB"),
    "puts": ("put", "VERB"),
    "squats": ("squat", "VERB"),
    "stands": ("stand", "VERB"),
    "bends": ("bend", "VERB"),
    "hanging": ("hang", "VERB"),
}
# "steps" is a noun after "takes"/"several" ("takes several steps") and a verb elsewhere ("steps sideways").
_NOUN_STEPS_AFTER = frozenset({"takes", "several"})


def tokenize(text: str) -> list[str]:
    """``lemma/UPOS`` tokens of a caption built from the lexicon; an unknown word is an error."""
    words = text.split()
    tokens = []
    for i, word in enumerate(words):
        entry = LEXICON.get(word)
        if word == "steps" and (i == 0 or words[i - 1] not in _NOUN_STEPS_AFTER):
            entry = ("step", "VERB")
        if entry is None:
            raise MotionDataError(f"caption {text!r}", f"word {word!r} is not in the synthetic caption lexicon")
        tokens.append(f"{entry[0]}/{entry[1]}")
    return tokens


def _article(word: str) -> str:
    return "an" if word[0] in "aeiou" else "a"


def _template_key(spec: ClipSpec) -> str:
    return "jump_in_place" if spec.content == "jump" and spec.travel == 0.0 else spec.content


def _styled(vp: str, subject: str, spec: ClipSpec, mode: str, rng: np.random.Generator) -> str:
    """Put the style's words into one caption: as adjective, adverb (before or after) or phrase."""
    words = STYLE_WORDS[spec.style]
    if mode == "adjective":
        noun = str(rng.choice(ADJ_NOUNS))
        return f"{_article(words.adjective)} {words.adjective} {noun} {vp}"
    if mode == "adverb" and words.adverb is not None:
        if rng.random() < 0.5 and not vp.startswith("is "):
            return f"{subject} {words.adverb} {vp}"
        return f"{subject} {vp} {words.adverb}"
    return f"{subject} {vp} {str(rng.choice(words.phrases))}"


def make_captions(spec: ClipSpec, n: int = CAPTIONS_PER_CLIP) -> list[Caption]:
    """``n`` distinct captions for a clip, drawn deterministically from its seed."""
    rng = np.random.default_rng([spec.seed, 7])
    templates = TEMPLATES[_template_key(spec)]
    picks = rng.choice(len(templates), size=min(n, len(templates)), replace=False)
    modes = ["adjective", "adverb", "phrase"]
    rng.shuffle(modes)
    captions = []
    for k, idx in enumerate(picks):
        vp = templates[int(idx)].format(side=spec.side)
        subject = str(rng.choice(SUBJECTS))
        text = f"{subject} {vp}" if spec.style == "neutral" else _styled(vp, subject, spec, modes[k % 3], rng)
        captions.append(Caption(text=text, tokens=tokenize(text)))
    return captions
