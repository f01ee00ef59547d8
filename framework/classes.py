"""The component classes a topology names, found by their `package.module:Class`
path; a clear error when one cannot be.

Apart from the container so that checking a topology (which imports its classes to
read their ports) does not depend on the process that hosts them.
"""

from __future__ import annotations

import difflib
import importlib
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from framework.component import Component
from framework.errors import FwError


class ClassPathError(FwError):
    """A component class path that does not name an importable Component class."""


def add_import_paths(paths: Iterable[str | Path]) -> None:
    """Let `load_class` find modules in these folders too (a topology's own folder and
    its `import_paths:`), after the ones Python already searches: an integrator's
    components next to their topology need no PYTHONPATH."""
    for path in paths:
        folder = str(Path(path).resolve())
        if folder not in sys.path:
            sys.path.append(folder)


def load_class(path: str) -> type[Component]:
    """`package.module:Class` -> the class; a `ClassPathError` saying why otherwise."""
    module_name, _, class_name = path.partition(":")
    if not class_name:
        raise ClassPathError(f"class path {path!r} must look like 'package.module:Class'")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise ClassPathError(f"cannot import {module_name!r}: {exc}") from None
    cls = getattr(module, class_name, None)
    if not (isinstance(cls, type) and issubclass(cls, Component)):
        raise ClassPathError(f"{path!r} is not a Component class{_nearest(module, class_name)}")
    return cls


def load_function(path: str) -> Any:
    """`package.module:function` -> the function (a hook a topology names: the links a
    recording draws a robot with); a `ClassPathError` saying why otherwise."""
    module_name, _, name = path.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise ClassPathError(f"cannot import {module_name!r}: {exc}") from None
    function = getattr(module, name, None)
    if not callable(function):
        raise ClassPathError(f"{path!r} is not a function of {module_name!r}")
    return function


def _nearest(module: Any, name: str) -> str:
    """'; did you mean ...?' for the module's Component class nearest `name` (case
    aside: NDITracker finds NdiTracker), or its Component classes, or ''."""
    classes = sorted(
        attr
        for attr, value in vars(module).items()
        if isinstance(value, type)
        and issubclass(value, Component)
        and value.__module__ == module.__name__
    )
    if not classes:
        return f"; {module.__name__} defines no Component class"
    lowered = {attr.lower(): attr for attr in classes}
    close = difflib.get_close_matches(name.lower(), list(lowered), n=1, cutoff=0.6)
    if close:
        return f"; did you mean '{module.__name__}:{lowered[close[0]]}'?"
    return f"; {module.__name__} defines {', '.join(classes)}"
