"""A corpus's identity: one hash over the files training reads, so trained models can say what they saw."""

from __future__ import annotations

import hashlib
from pathlib import Path

from motionaug.schemas.errors import MotionDataError


def corpus_fingerprint(corpus_dir: str | Path) -> str:
    """Hash over every file pretraining reads (motions, captions, splits, labels, Mean/Std): content hashes.

    Content rather than mtimes, so a copied corpus matches and a rewritten one with the same sizes does not.
    """
    root = Path(corpus_dir)
    if not root.is_dir():
        raise MotionDataError(str(root), "corpus folder does not exist")
    digest = hashlib.sha256()
    patterns = ("*.txt", "*.npy", "labels.jsonl", "new_joint_vecs/*.npy", "texts/*.txt")
    files = sorted({p for pattern in patterns for p in root.glob(pattern) if p.is_file()})
    if not any(p.parent.name == "new_joint_vecs" for p in files):
        raise MotionDataError(str(root), "not a HumanML3D folder: no new_joint_vecs/*.npy")
    for path in files:
        digest.update(path.relative_to(root).as_posix().encode() + b"\0")
        digest.update(hashlib.sha256(path.read_bytes()).digest())
    return digest.hexdigest()[:32]
