"""Estimators by task and name, so a config selects them: create("detector", "hog", {"scale": 0.5}).

A factory is a class or function called with the estimator's options as keyword arguments; one that also takes
a `shared` keyword receives a dict shared by every estimator of one pipeline (e.g. one MediaPipe graph serving
the detector, the segmenter and the 2D pose estimator).
"""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable

from m3c.perception.interfaces import INTERFACES, TASKS, Estimator

_FACTORIES: dict[str, dict[str, Callable]] = {task: {} for task in TASKS}
# Modules whose import registers the built-in estimators; none imports an optional package at import time.
_BUILTIN_MODULES = ("m3c.perception.mediapipe_pose", "m3c.perception.hog", "m3c.perception.body",
                    "m3c.perception.contacts", "m3c.perception.simple", "m3c.perception.networks")
_builtins_loaded = False


def _load_builtins() -> None:
    global _builtins_loaded
    if not _builtins_loaded:
        _builtins_loaded = True
        for module in _BUILTIN_MODULES:
            importlib.import_module(module)


def register(task: str, name: str):
    """Decorator: registers a factory for `task` under `name`."""
    if task not in TASKS:
        raise ValueError(f"unknown task {task!r}; tasks are {', '.join(TASKS)}")

    def decorator(factory: Callable) -> Callable:
        if name in _FACTORIES[task] and _FACTORIES[task][name] is not factory:
            raise ValueError(f"a {task} estimator named {name!r} is already registered")
        _FACTORIES[task][name] = factory
        return factory

    return decorator


def available(task: str) -> tuple[str, ...]:
    """Names registered for a task, sorted."""
    if task not in TASKS:
        raise ValueError(f"unknown task {task!r}; tasks are {', '.join(TASKS)}")
    _load_builtins()
    return tuple(sorted(_FACTORIES[task]))


def create(task: str, name: str, options: dict | None = None, shared: dict | None = None,
           defaults: dict | None = None) -> Estimator:
    """A new estimator for `task` named `name`, built with `options`; `defaults` (settings of the whole run, such
    as the patches' padding) go to an estimator that takes them, unless `options` set them."""
    names = available(task)
    if name not in _FACTORIES[task]:
        raise ValueError(f"no {task} estimator named {name!r}; available: {', '.join(names)}")
    factory = _FACTORIES[task][name]
    kwargs = dict(options or {})
    try:
        parameters = inspect.signature(factory).parameters
    except (TypeError, ValueError):
        parameters = {}
    takes_any = any(p.kind is inspect.Parameter.VAR_KEYWORD for p in parameters.values())
    if parameters and not takes_any:
        unknown = sorted(set(kwargs) - set(parameters) - {"shared"})
        if unknown or "shared" in kwargs:
            allowed = [p for p in parameters if p != "shared"]
            raise ValueError(f"unknown option(s) {', '.join(unknown or ['shared'])} for the {task} estimator "
                             f"{name!r}; it takes: {', '.join(allowed) or 'no options'}")
    for key, value in (defaults or {}).items():
        if key not in kwargs and key in parameters:  # named: a **options factory may pass it on to a config
            kwargs[key] = value
    if "shared" in parameters:
        kwargs["shared"] = shared if shared is not None else {}
    estimator = factory(**kwargs)
    interface = INTERFACES[task]
    if not isinstance(estimator, interface):
        raise TypeError(f"the {task} estimator {name!r} must implement {interface.__name__}")
    estimator.name = name
    return estimator
