"""Style-transfer methods by name, imported only when asked for (a method may pull in torch models).

Everything else about a method is declared on its class (``motionaug.augment.methods.base``).
"""

from __future__ import annotations

import importlib
from collections.abc import Sequence
from types import MappingProxyType
from typing import Any

from motionaug.augment.methods.base import StyleTransferMethod
from motionaug.augment.methods.hooks import import_hook_modules
from motionaug.schemas.errors import MotionDataError

METHODS = MappingProxyType(
    {
        "stats": "motionaug.augment.methods.stats_baseline:StatsBaselineMethod",
        "onthefly": "motionaug.augment.methods.onthefly:OnTheFlyMethod",
        "erd": "motionaug.augment.methods.erd.method:ErdMethod",
        "umsd": "motionaug.augment.methods.umsd.method:UmsdMethod",
    }
)


def known_methods() -> list[str]:
    return sorted(METHODS)


def method_class(name: str) -> type[StyleTransferMethod]:
    """The class registered under ``name``; a clear error when unknown."""
    if name not in METHODS:
        raise MotionDataError("config method.name", f"unknown method {name!r}; known: {known_methods()}")
    module_name, class_name = METHODS[name].split(":")
    return vars(importlib.import_module(module_name))[class_name]


def validate_method_params(name: str, params: dict[str, Any], hook_modules: Sequence[str] = ()) -> dict[str, Any]:
    """The method's params, validated and normalised (one line naming ``method.params`` when bad); the hooks they
    name are looked up after ``hook_modules`` (a run config's ``hooks.modules``) are imported."""
    import_hook_modules(hook_modules)
    return method_class(name).parse_params(params).model_dump(mode="json")


def create_method(name: str, params: dict[str, Any], hook_modules: Sequence[str] = ()) -> StyleTransferMethod:
    """An instance configured with validated params, after importing the modules that register its hooks."""
    import_hook_modules(hook_modules)
    return method_class(name)(params)
