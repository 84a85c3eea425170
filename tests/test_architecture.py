"""The layer rules of docs/architecture.md, checked on the code as it is."""

from __future__ import annotations

import ast
import shutil
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DJANGO_CODE = [REPO / "portal", REPO / "bookings"]


def _python_files(roots: list[Path]) -> list[Path]:
    return [p for root in roots for p in root.rglob("*.py") if "migrations" not in p.parts]


def test_the_import_contracts_hold():
    """web → runs → experiments → bookings → shared; the agent imports nothing of Django."""
    lint_imports = shutil.which("lint-imports", path=str(Path(sys.executable).parent))
    assert lint_imports, "import-linter is installed with the dev packages"
    result = subprocess.run(
        [lint_imports, "--no-cache"], cwd=REPO, capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-2000:]
    assert "0 broken" in result.stdout


def test_no_import_inside_a_function_dodges_a_cycle():
    found = []
    for path in _python_files(DJANGO_CODE):
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                for inner in ast.walk(node):
                    if isinstance(inner, ast.Import | ast.ImportFrom):
                        found.append(f"{path.relative_to(REPO)}:{inner.lineno}")
    assert not found, found


def test_bookings_never_names_a_web_page():
    found = []
    for path in _python_files([REPO / "bookings"]):
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.Call) and getattr(node.func, "id", "") in {
                "reverse",
                "reverse_lazy",
                "redirect",
            }:
                found.append(f"{path.relative_to(REPO)}:{node.lineno}")
    assert not found, found
