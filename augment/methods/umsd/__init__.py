"""UMSD (Qian et al., ACM MM 2025): one-stream motion style diffusion, trained once, zero-shot styles from examples.

Public API: ``UmsdTrainConfig`` and ``train_umsd`` (labelled clips -> model folder), ``load_umsd`` (folder ->
``UmsdModel``: network + normaliser), ``prepare_data`` / ``UmsdTrainer`` (the training loop's parts). The method
behind the workflow contract is ``motionaug.augment.methods.umsd.method.UmsdMethod``; the network lives in
``motionaug.models.umsd``.
"""

from motionaug.augment.methods.umsd.training import (
    UmsdBatch,
    UmsdData,
    UmsdModel,
    UmsdTrain,
    UmsdTrainArtifact,
    UmsdTrainConfig,
    UmsdTrainer,
    load_umsd,
    prepare_data,
    read_artifact,
    spec_key,
    train_umsd,
)

__all__ = [
    "UmsdBatch",
    "UmsdData",
    "UmsdModel",
    "UmsdTrainArtifact",
    "UmsdTrain",
    "UmsdTrainConfig",
    "UmsdTrainer",
    "load_umsd",
    "prepare_data",
    "read_artifact",
    "spec_key",
    "train_umsd",
]
