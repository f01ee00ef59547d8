"""Durations as users write them in YAML: `2s`, `500 ms`, `1.5min`, or a number of seconds.

One small module so charts, topologies, activities and scenarios parse time the same
way without importing each other.
"""

from __future__ import annotations

import re
from typing import Any

_DURATION = re.compile(r"^\s*([0-9]+(?:\.[0-9]*)?)\s*(ms|s|min|h)?\s*$")
_UNIT = {"ms": 1e-3, "s": 1.0, "min": 60.0, "h": 3600.0, None: 1.0}


def parse_duration(value: Any) -> float:
    """Seconds from a number or a string like '2s', '500 ms', '1.5min'; ValueError otherwise."""
    if isinstance(value, bool):
        raise ValueError(f"not a duration: {value!r}")
    if isinstance(value, (int, float)):
        return float(value)
    match = _DURATION.match(str(value))
    if not match:
        raise ValueError(f"not a duration: {value!r} (write e.g. '2s', '500ms', '1.5min')")
    return float(match.group(1)) * _UNIT[match.group(2)]
