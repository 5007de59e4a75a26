"""The package's own source is Python 3.9 (its oldest supported version),
checked with the parser's feature_version since no 3.9 interpreter is at
hand in CI."""

from __future__ import annotations

import ast
from pathlib import Path

import lluav

PACKAGE = Path(__file__).resolve().parents[1] / "lluav"


def test_the_package_source_is_python_3_9():
    sources = sorted(PACKAGE.glob("*.py"))
    assert {p.name for p in sources} >= {"__init__.py", "_sync.py", "_async.py"}
    for path in sources:
        ast.parse(path.read_text(), filename=str(path), feature_version=(3, 9))


def test_the_installed_package_is_the_checked_out_source():
    installed = Path(lluav.__file__).parent
    for path in PACKAGE.glob("*.py"):
        assert (installed / path.name).read_text() == path.read_text(), path.name
