"""fw's compiled kernel (components/domain/_fwkernel.c), or None where it was not built.

`pip install` builds it (the package's ext-modules); a checkout used without installing,
or a machine without a C compiler, runs the Python references instead: each function of
the kernel names the Python it replaces, which stays as the fallback and as what a spec
holds it to (tests/components/domain/test_kernel.py and the specs beside each caller).
"""

from __future__ import annotations

from types import ModuleType

_fwkernel: ModuleType | None
try:
    from components.domain import _fwkernel
except ImportError:  # not built: the Python references
    _fwkernel = None

COMPILED = _fwkernel is not None
"""True when the 1 kHz cycle's arithmetic runs in the compiled kernel."""
