"""Ground truth stays out of identification code.

Only the dataset format module, the datasets package and modules under
``iiwa_ident/evaluation/`` may use ``read_truth`` or address the HDF5 group
``/truth``. The check parses each module and looks at code, not prose:

* names, attributes, imports and definitions called ``read_truth``, and string
  literals naming it (as in ``getattr(mod, "read_truth")``);
* string literals that are a path into the truth group: ``"/truth"``,
  ``"truth/..."``, f-string parts such as ``f"/truth/{k}"``;
* the bare literal ``"truth"`` where it acts as an HDF5 key: a subscript
  (``h5["truth"]``), a membership test (``"truth" in h5``) or the first
  argument of ``get``/``require_group``/``create_group``/``__getitem__``.

Docstrings, comments, ``truth=`` keywords and object attributes such as
``hasattr(robot, "truth")`` (a simulator handing truth to the writer) are fine.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "iiwa_ident"
ALLOWED_FILES = {"datasets/_format.py", "datasets/__init__.py"}
ALLOWED_DIRS = ("evaluation/",)

_TRUTH_PATH = re.compile(r"^(/truth(/|$)|truth/)")
_KEY_METHODS = {"get", "require_group", "create_group", "__getitem__"}
_READ_TRUTH = re.compile(r"\bread_truth\b")


def _docstring_ids(tree: ast.AST) -> set[int]:
    ids: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                if isinstance(body[0].value.value, str):
                    ids.add(id(body[0].value))
    return ids


def truth_violations(source: str) -> list[str]:
    """Return ``"line N: reason"`` for every use of ground truth in ``source``."""
    tree = ast.parse(source)
    docstrings = _docstring_ids(tree)
    found: list[str] = []
    # Bare "truth" literals in positions where they act as an HDF5 key.
    key_ids: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Subscript):
            key_ids.add(id(node.slice))
        elif isinstance(node, ast.Compare) and any(isinstance(op, (ast.In, ast.NotIn)) for op in node.ops):
            key_ids.add(id(node.left))
        elif (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Attribute)
            and node.func.attr in _KEY_METHODS
            and node.args
        ):
            key_ids.add(id(node.args[0]))

    def flag(node: ast.AST, reason: str) -> None:
        found.append(f"line {getattr(node, 'lineno', '?')}: {reason}")

    for node in ast.walk(tree):
        if isinstance(node, ast.Name) and node.id == "read_truth":
            flag(node, "uses name read_truth")
        elif isinstance(node, ast.Attribute) and node.attr == "read_truth":
            flag(node, "uses attribute read_truth")
        elif isinstance(node, ast.alias) and "read_truth" in (node.name, node.asname):
            flag(node, "imports read_truth")
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.name == "read_truth":
            flag(node, "defines read_truth")
        elif (
            isinstance(node, ast.Constant)
            and isinstance(node.value, str)
            and id(node) not in docstrings
        ):
            if _TRUTH_PATH.match(node.value) or (node.value == "truth" and id(node) in key_ids):
                flag(node, f"string {node.value!r} addresses the truth group")
            elif _READ_TRUTH.search(node.value):
                flag(node, f"string {node.value!r} names read_truth")
    return sorted(found)


def _is_allowed(relative: str) -> bool:
    return relative in ALLOWED_FILES or relative.startswith(ALLOWED_DIRS)


def _modules() -> list[tuple[str, Path]]:
    return sorted((p.relative_to(PACKAGE).as_posix(), p) for p in PACKAGE.rglob("*.py"))


class TestTruthViolations:
    @pytest.mark.parametrize(
        "source",
        [
            "from iiwa_ident.datasets import read_truth\n",
            "from iiwa_ident.datasets import read_truth as rt\n",
            "import iiwa_ident.datasets as d\nx = d.read_truth(p)\n",
            "x = read_truth(p)\n",
            "g = h5['/truth']\n",
            'g = h5["truth"]\n',
            "g = h5.get('truth')\n",
            "k = h5['truth/plant']['k']\n",
            "ok = 'truth' in h5\n",
            "p = f'/truth/{name}'\n",
            "fn = getattr(mod, 'read_truth')\n",
            "g = h5.require_group('truth')\n",
            "del h5['truth']\n",
            "k = group['/truth/plant/k']\n",
            "def f():\n    '''Doc.'''\n    return h5['truth']\n",
        ],
    )
    def test_flags_offending_source(self, source):
        assert truth_violations(source), source

    @pytest.mark.parametrize(
        "source",
        [
            '"""Ground truth is never read here; see read_truth and /truth."""\n',
            "# read_truth is for evaluation only; h5['truth']\nx = 1\n",
            "ds = Dataset(signals, truth=truth)\n",
            "msg = 'ground truth of the plant'\n",
            "truth = simulate()\n",
            "s = 'no /truth group here'\n",
            "path = 'truthful.h5'\n",
            "t = robot.truth() if hasattr(robot, 'truth') else None\n",
            "d = {'truth': 1.0}\n",
            "label = 'truth'\n",
            "def f():\n    '''Never calls read_truth.'''\n    return 1\n",
        ],
    )
    def test_accepts_clean_source(self, source):
        assert truth_violations(source) == []

    def test_detects_real_use_in_allowed_module(self):
        # The format module defines and uses read_truth; the checker must see it.
        source = (PACKAGE / "datasets/_format.py").read_text(encoding="utf-8")
        assert any("read_truth" in v for v in truth_violations(source))


class TestPackageFollowsTruthRule:
    def test_scans_the_package(self):
        names = [rel for rel, _ in _modules()]
        assert "datasets/_import.py" in names and "cli/_data_cmds.py" in names

    def test_allow_list(self):
        assert _is_allowed("datasets/_format.py")
        assert _is_allowed("evaluation/scores.py")
        assert not _is_allowed("datasets/_import.py")
        assert not _is_allowed("ident/evaluation_helpers.py")

    def test_no_module_outside_allow_list_touches_truth(self):
        offences = []
        for relative, path in _modules():
            if _is_allowed(relative):
                continue
            for problem in truth_violations(path.read_text(encoding="utf-8")):
                offences.append(f"iiwa_ident/{relative} {problem}")
        assert not offences, "ground truth used outside evaluation code:\n" + "\n".join(offences)
