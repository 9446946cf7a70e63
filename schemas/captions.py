"""Caption records as HumanML3D writes them: ``caption#lemma/POS tokens#start#end``."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class Caption(BaseModel):
    """One caption line. ``start``/``end`` in seconds; 0.0/0.0 means the whole clip."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    text: str = Field(min_length=1)
    tokens: list[str] = Field(default_factory=list, description="'word/POS' items, e.g. 'walk/VERB'.")
    start: float = 0.0
    end: float = 0.0

    @property
    def whole_clip(self) -> bool:
        return self.start == 0.0 and self.end == 0.0
