"""Variants that plug in by name, the way diffusers plugs callbacks into a pipeline.

Three families, each a registry from a name to a factory called with the config's options: ``sampler_callbacks``
(``callback(step) -> x0`` on every sampling step's x0 prediction, ``SamplerStep``); ``output_shapers``
(``shaper(output, context) -> output`` on each transfer output (T, F), ``ShapeContext``; the run's, for any method:
``augment.methods.shaping``); ``loss_terms`` (``term(batch) -> loss``, added to a training step's loss times its
weight, ``LossBatch``). A config names a hook as ``name`` or ``{name: ..., option: ...}``. Hooks outside the package
register when their module is imported: a run config lists such modules (``hooks.modules``), which every Ray worker
imports before it builds the method. The product registers the hooks its shipped configs name.
"""

from __future__ import annotations

import importlib
import os
import sys
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Annotated, Any, ClassVar, Generic, TypeVar

import numpy as np
import torch
import yaml
from pydantic import AfterValidator

from motionaug.schemas.errors import MotionDataError

HookSpec = str | dict[str, Any]
"""A hook as a config names it: its registered name, or ``{name: NAME, **options}``."""

F = TypeVar("F", bound=type)


@dataclass(frozen=True)
class SamplerStep:
    """One sampling step: timestep ``t``, the x0 prediction (B, T, F) and the batch's valid frames (B, T)."""

    t: int
    x0: torch.Tensor
    x_t: torch.Tensor
    mask: torch.Tensor


@dataclass(frozen=True)
class ShapeContext:
    """What an output shaper may read beside the output: the content clip, the style example and the plain stand-in
    for the example's content (``reference``, None unless the shaper asked for one), all (T_i, F) in the output's
    feature space, and the frame rate; ``alike``: every (example, reference) of the style that moves as the content
    does (``shaping.alike_examples``), the picked one included, for a shaper that pools a style's k examples."""

    content: np.ndarray
    example: np.ndarray
    reference: np.ndarray | None
    fps: float
    alike: tuple[tuple[np.ndarray, np.ndarray | None], ...] = ()


@dataclass(frozen=True)
class LossBatch:
    """A training step's predicted and target global joint positions (B, T, J, 3), metres, and valid frames (B, T)."""

    predicted: torch.Tensor
    target: torch.Tensor
    mask: torch.Tensor
    fps: float


class SamplerCallback(ABC):
    """Called on every sampling step's x0 prediction; returns the x0 the step goes on with."""

    @abstractmethod
    def __call__(self, step: SamplerStep) -> torch.Tensor: ...


class OutputShaper(ABC):
    """Called on each transfer output (T, F); returns the shaped output, F wide (T frames unless it retimes)."""

    needs_reference: ClassVar[bool] = False
    """Whether it reads ``ShapeContext.reference`` (then ``prepare`` picks a stand-in for each example)."""

    @abstractmethod
    def __call__(self, output: np.ndarray, context: ShapeContext) -> np.ndarray: ...

    def context_after(self, context: ShapeContext) -> ShapeContext:
        """The context the steps after this one read: the same, unless this step plays the output at another clock
        (then the content and the reference on that clock, so every later step compares clips of one pace)."""
        return context


class LossTerm(ABC):
    """A training-loss term: ``weight`` times its value is added to every step's loss."""

    def __init__(self, weight: float = 1.0) -> None:
        self.weight = float(weight)

    @abstractmethod
    def __call__(self, batch: LossBatch) -> torch.Tensor: ...


class Registry(Generic[F]):
    """Names to hook classes; ``create`` builds one hook from a config's ``HookSpec`` (options: its arguments)."""

    def __init__(self, family: str, builtins: str | None = None) -> None:
        self.family = family
        self._factories: dict[str, F] = {}
        self._builtins = builtins  # the product module registering this family's shipped hooks, imported when asked

    def _load_builtins(self) -> None:
        if self._builtins is not None:
            module, self._builtins = self._builtins, None
            importlib.import_module(module)

    def register(self, name: str) -> Callable[[F], F]:
        """Decorator: register a hook class under ``name``."""

        def add(factory: F) -> F:
            known = self._factories.get(name)
            if known is not None and known.__qualname__ != factory.__qualname__:
                raise ValueError(f"{self.family} {name!r} is registered already ({known.__module__})")
            self._factories[name] = factory
            return factory

        return add

    def names(self) -> list[str]:
        self._load_builtins()
        return sorted(self._factories)

    def check(self, specs: Iterable[HookSpec], where: str) -> None:
        """Config-time check that every named hook is registered (one line naming ``where`` otherwise)."""
        self._load_builtins()
        for spec in specs:
            name, _ = split_spec(spec)
            if name not in self._factories:
                raise MotionDataError(
                    where, f"unknown {self.family} {name!r}; known: {self.names()} (hooks.modules imports more)"
                )

    def checked(self, specs: list[HookSpec]) -> list[HookSpec]:
        """``specs`` when every name is registered, for a pydantic field validator (a ``ValueError`` otherwise)."""
        self._load_builtins()
        for spec in specs:
            name, _ = split_spec(spec)
            if name not in self._factories:
                raise ValueError(f"unknown {self.family} {name!r}; known: {self.names()} (hooks.modules imports more)")
        return specs

    def factory(self, name: str, where: str = "config") -> F:
        self.check([name], where)
        return self._factories[name]

    def create(self, spec: HookSpec, where: str = "config") -> Any:
        self.check([spec], where)
        name, options = split_spec(spec)
        try:
            return self._factories[name](**options)
        except (TypeError, ValueError) as err:
            raise MotionDataError(where, f"{self.family} {name!r}: {err}") from None

    def create_all(self, specs: Sequence[HookSpec], where: str = "config") -> list[Any]:
        return [self.create(spec, where) for spec in specs]


def split_spec(spec: HookSpec) -> tuple[str, dict[str, Any]]:
    """``"name"`` or ``{name: ..., **options}`` -> (name, options)."""
    if isinstance(spec, str):
        return spec, {}
    options = dict(spec)
    return str(options.pop("name", "")), options


def parse_hook_specs(text: str) -> list[HookSpec]:
    """Comma-separated ``NAME`` or ``NAME:KEY=VALUE:...`` (values read as YAML): hooks as a command line names them,
    e.g. ``coordination:shrink=0.0,moments``."""
    specs: list[HookSpec] = []
    for item in (t for t in text.split(",") if t):
        name, *options = item.split(":")
        specs.append(
            {"name": name, **{k: yaml.safe_load(v) for k, v in (o.split("=", 1) for o in options)}} if options else name
        )
    return specs


sampler_callbacks: Registry[type[SamplerCallback]] = Registry("sampler callback")
output_shapers: Registry[type[OutputShaper]] = Registry("output shaper", "motionaug.augment.methods.shapers")
loss_terms: Registry[type[LossTerm]] = Registry("loss term")


def _registered_terms(specs: tuple[HookSpec, ...]) -> tuple[HookSpec, ...]:
    return tuple(loss_terms.checked(list(specs)))


LossTerms = Annotated[tuple[HookSpec, ...], AfterValidator(_registered_terms)]
"""A params field of loss terms: each named one must be registered (a ``ValueError`` for pydantic otherwise)."""


def import_hook_modules(modules: Sequence[str]) -> None:
    """Import the modules that register hooks (a run config's ``hooks.modules``); one line when one is missing.

    The working directory is searched last, as Ray puts the driver's on its workers' path: a module beside the run
    (``lab.umsd_hooks`` from the repository root) imports the same way in the driver and in every worker.
    """
    if modules and os.getcwd() not in sys.path:
        sys.path.append(os.getcwd())
    for name in modules:
        try:
            importlib.import_module(name)
        except ImportError as err:
            raise MotionDataError("config hooks.modules", f"cannot import {name!r}: {err}") from None


def needs_reference(specs: Sequence[HookSpec]) -> bool:
    """Whether any named output shaper reads ``ShapeContext.reference`` (then ``prepare`` picks one per example)."""
    return any(output_shapers.factory(split_spec(spec)[0]).needs_reference for spec in specs)
