"""Style-ERD (Tao et al., CVPR 2022): online, frame-by-frame style transfer with a recurrent residual network.

Public API: ``train_erd`` (labelled clips -> model folder), ``load_erd`` (folder -> ``ErdNetwork``),
``transfer`` (whole clips, offline) and ``StreamingStylizer`` (one frame at a time, one frame of lag).
The network itself lives in ``motionaug.models.style_erd``.
"""

from motionaug.augment.methods.erd.stream import (
    FORWARD_CHANNELS,
    StreamingStylizer,
    finish_clip,
    project_rotations,
    rederive_forward,
    transfer,
)
from motionaug.augment.methods.erd.training import (
    ErdArtifact,
    ErdTrain,
    ErdTrainConfig,
    ErdTrainer,
    load_erd,
    prepare_data,
    read_artifact,
    train_erd,
)

__all__ = [
    "FORWARD_CHANNELS",
    "ErdArtifact",
    "ErdTrain",
    "ErdTrainConfig",
    "ErdTrainer",
    "StreamingStylizer",
    "finish_clip",
    "load_erd",
    "prepare_data",
    "project_rotations",
    "read_artifact",
    "rederive_forward",
    "train_erd",
    "transfer",
]
