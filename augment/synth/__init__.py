"""Procedural style corpus: parametric contents x styles on the t2m skeleton, with captions.

The product's embedded default dataset: every clip is a ``ClipSpec`` that renders to joints, so the
same content can be rendered in any style (paired ground truth for style transfer).
"""

from motionaug.augment.synth.animator import ClipSpec, RenderedClip, render, sample_spec
from motionaug.augment.synth.captions import make_captions
from motionaug.augment.synth.contents import CONTENTS
from motionaug.augment.synth.corpus import CorpusSummary, generate_corpus, read_labels, restyled
from motionaug.augment.synth.styles import STYLE_WORDS, STYLES, StyleWords, style_params

__all__ = [
    "CONTENTS",
    "STYLES",
    "STYLE_WORDS",
    "ClipSpec",
    "CorpusSummary",
    "RenderedClip",
    "StyleWords",
    "generate_corpus",
    "make_captions",
    "read_labels",
    "render",
    "restyled",
    "sample_spec",
    "style_params",
]
