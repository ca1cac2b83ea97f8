"""Classes pickled under the names official checkpoints use (Lightning's AttributeDict, yacs' CfgNode, ...),
without those packages: the module exists in sys.modules only while the file is written."""

from __future__ import annotations

import contextlib
import sys
import types


def named_class(qualified: str) -> type:
    """A class that pickles as `qualified` (module.Name): a dict subclass with instance attributes, as yacs'
    CfgNode is; a plain attribute holder for argparse's Namespace."""
    module_name, class_name = qualified.rsplit(".", 1)
    if class_name == "Namespace":
        def init_namespace(self, **kwargs):
            self.__dict__.update(kwargs)
        return type(class_name, (), {"__module__": module_name, "__init__": init_namespace})

    def init(self, *args, **kwargs):
        dict.__init__(self, *args, **kwargs)
        self.__dict__["__immutable__"] = False
    return type(class_name, (dict,), {"__module__": module_name, "__init__": init})


@contextlib.contextmanager
def importable(cls: type):
    """Makes cls importable under its module name (and the parent packages) for the duration; a module that
    exists (argparse) gets its own attribute back afterwards."""
    parts = cls.__module__.split(".")
    names = [".".join(parts[:i]) for i in range(1, len(parts) + 1)]
    saved = {name: sys.modules.get(name) for name in names}
    missing = object()
    module_before = saved[cls.__module__]
    attribute_before = getattr(module_before, cls.__name__, missing) if module_before is not None else missing
    try:
        for name in names:
            if saved[name] is None:
                sys.modules[name] = types.ModuleType(name)
        setattr(sys.modules[cls.__module__], cls.__name__, cls)
        yield cls
    finally:
        if module_before is not None:
            if attribute_before is missing:
                delattr(module_before, cls.__name__)
            else:
                setattr(module_before, cls.__name__, attribute_before)
        for name, module in saved.items():
            if module is None:
                sys.modules.pop(name, None)
