"""Style-transfer methods by name, imported only when asked for (a method may pull in torch models).

A method class may define ``validate_params(params) -> dict`` (a classmethod) so a bad parameter is a
config error before the run starts, and ``needs_base_models`` (default True: the safe assumption).
"""

from __future__ import annotations

import importlib
from types import MappingProxyType
from typing import Any

from schemas.errors import MotionDataError
from augment.methods.base import StyleTransferMethod

METHODS = MappingProxyType(
    {
        "stats": "augment.methods.stats_baseline:StatsBaselineMethod",
        "onthefly": "augment.methods.onthefly:OnTheFlyMethod",
    }
)


def known_methods() -> list[str]:
    return sorted(METHODS)


def method_class(name: str) -> type[StyleTransferMethod]:
    """The class registered under ``name``; a clear error when unknown or not installed yet."""
    if name not in METHODS:
        raise MotionDataError("config method.name", f"unknown method {name!r}; known: {known_methods()}")
    module_name, class_name = METHODS[name].split(":")
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as err:
        if err.name != module_name:
            raise
        raise MotionDataError("config method.name", f"method {name!r} is not available in this installation") from None
    return getattr(module, class_name)


def validate_method_params(name: str, params: dict[str, Any]) -> dict[str, Any]:
    """The method's own check of its params (normalised), or a one-line error naming method.params."""
    cls = method_class(name)
    hook = getattr(cls, "validate_params", None)
    if hook is None:
        return dict(params)
    try:
        return dict(hook(dict(params)))
    except MotionDataError as err:
        raise MotionDataError("config method.params", f"{name}: {err.reason}") from None
    except (TypeError, ValueError) as err:
        raise MotionDataError("config method.params", f"{name}: {str(err).splitlines()[0]}") from None


def create_method(name: str, params: dict[str, Any]) -> StyleTransferMethod:
    """An instance configured with validated params (``from_params`` if the class has it, else ``cls(**params)``)."""
    cls = method_class(name)
    checked = validate_method_params(name, params)
    factory = getattr(cls, "from_params", None)
    return factory(checked) if factory is not None else cls(**checked)


def needs_base_models(name: str) -> bool:
    return bool(getattr(method_class(name), "needs_base_models", True))
