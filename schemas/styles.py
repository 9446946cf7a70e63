"""Style examples as users give them: which clip shows the style, how captions name it."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, field_validator


class StyleWords(BaseModel):
    """How captions name a style: ``a proud person``, ``walks proudly``, ``in a proud way``.

    ``adverb`` is None where English has no natural one (``old``); ``phrases`` are complete trailing
    phrases (``like an old person``). Used to revise captions and to spot style words to neutralise.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    adjective: str = Field(min_length=1)
    adverb: str | None = None
    phrases: tuple[str, ...] = ()

    def forms(self) -> list[str]:
        """Every surface form, longest first (so phrases are matched before single words)."""
        forms = [*self.phrases, self.adverb or "", self.adjective]
        return sorted({f for f in forms if f}, key=lambda f: (-len(f), f))


class StyleExample(BaseModel):
    """One example of a style: a corpus clip id, a features ``.npy`` or a ``.bvh`` file, and its description."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    source: str = Field(min_length=1, description="Corpus clip id, or a path to a .npy (T, 263) or .bvh file.")
    description: str = Field(min_length=1, description="e.g. 'a person walks proudly'.")
    joint_map: str | None = Field(default=None, description="Joint map file for a .bvh of a non-built-in skeleton.")
    reference: str | None = Field(
        default=None,
        min_length=1,
        description="Corpus clip id of this example's motion performed plainly (a plain wave for a styled wave): "
        "the output shapers' reference for it; else the plain pool clip whose root moves most like it.",
    )


class StyleSpec(BaseModel):
    """A named style with one or more examples (paper section 7.1) and its caption words."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    version: int = 1
    name: str = Field(pattern=r"^[a-z][a-z0-9_-]{0,63}$", description="Safe as a folder name: style=<name>/.")
    words: StyleWords
    examples: list[StyleExample] = Field(min_length=1)

    @field_validator("examples")
    @classmethod
    def _distinct(cls, examples: list[StyleExample]) -> list[StyleExample]:
        sources = [e.source for e in examples]
        if len(set(sources)) != len(sources):
            raise ValueError("the same example source is listed twice")
        return examples
