"""Every docstring example in the package runs, and prints what it says (found by walking the package, so a new
example is tested without a test of its own)."""

from __future__ import annotations

import doctest
import importlib
import pkgutil

import pytest

import iiwa_ident


def _modules_with_examples() -> list[str]:
    names = []
    for info in pkgutil.walk_packages(iiwa_ident.__path__, "iiwa_ident."):
        spec = importlib.util.find_spec(info.name)
        if spec is not None and spec.origin and spec.origin.endswith(".py"):
            with open(spec.origin, encoding="utf-8") as fh:
                if ">>>" in fh.read():
                    names.append(info.name)
    return names


MODULES = _modules_with_examples()


def test_the_examples_are_found():
    assert {"iiwa_ident.ident._resid", "iiwa_ident.model._eq4", "iiwa_ident.diagnose._channels"} <= set(MODULES)


@pytest.mark.parametrize("name", MODULES)
def test_examples(name):
    result = doctest.testmod(importlib.import_module(name), optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0 and result.failed == 0, name
