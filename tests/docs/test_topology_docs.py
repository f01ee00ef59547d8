"""Spec: docs/topologies.md names every finding the topology checker can report."""

import re

from tests.conftest import REPO


def test_every_topology_finding_code_is_documented():
    source = (REPO / "framework" / "topology" / "loader.py").read_text()
    codes = set(re.findall(r'\.error\(\s*"([a-z-]+)"', source))
    docs = (REPO / "docs" / "topologies.md").read_text()
    missing = sorted(c for c in codes if f"`{c}`" not in docs)
    assert len(codes) > 12 and not missing, missing
