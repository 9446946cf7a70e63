"""The moment rule with the example's and the reference's statistics taken over each clip and its mirror image:
does a one-take example's left-right lean carry a content change?

- output shaper ``moments_symmetric`` (``floor`` as ``moments``): the product's moment rule, the example and the
  reference each replaced by the clip followed by its left-right mirror (``features.mirror_features``).

Why: a style's posture is mostly the same on both sides, but one take leans or carries one arm its own way, and the
rule sets that lean on every clip (synthetic LSO val: walks come out reading as turns or curves). Control:
``--row shapers``.
"""

from __future__ import annotations

import numpy as np

from motionaug.augment.methods.hooks import ShapeContext, output_shapers
from motionaug.augment.methods.shapers import Moments
from motionaug.augment.motion.features import mirror_features


def with_mirror(motion: np.ndarray) -> np.ndarray:
    """The clip's frames followed by its mirror image's."""
    motion = np.asarray(motion, np.float32)
    return np.concatenate([motion, mirror_features(motion)])


@output_shapers.register("moments_symmetric")
class MomentsSymmetric(Moments):
    """The moment rule on mirror-pooled example and reference statistics (module doc)."""

    def __call__(self, output: np.ndarray, context: ShapeContext) -> np.ndarray:
        if context.reference is None:
            raise ValueError("moments_symmetric needs the example's reference")
        pooled = ShapeContext(
            content=context.content,
            example=with_mirror(context.example),
            reference=with_mirror(context.reference),
            fps=context.fps,
        )
        return super().__call__(output, pooled)
