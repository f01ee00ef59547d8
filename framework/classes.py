"""The component classes a topology names, found by their `package.module:Class`
path; a clear error when one cannot be.

Apart from the container so that checking a topology (which imports its classes to
read their ports) does not depend on the process that hosts them.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Iterable
from pathlib import Path

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
        raise ClassPathError(f"{path!r} is not a Component class")
    return cls
