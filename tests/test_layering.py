"""The runtime and the SDK never import torch (house rule; keeps the container small)."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
TORCH_FREE = [
    "service",
    "client/frt_client",
    "models/contract.py",
    "models/dynamics.py",
    "models/outer_bound.py",
]


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text())
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module.split(".")[0])
    return names


def test_no_torch_in_runtime_sources() -> None:
    files = []
    for entry in TORCH_FREE:
        p = ROOT / entry
        files += [p] if p.is_file() else sorted(p.rglob("*.py"))
    assert files, "nothing scanned"
    offenders = [str(f) for f in files if "torch" in _imports(f)]
    assert offenders == []


def test_importing_the_service_does_not_load_torch() -> None:
    code = "import sys, service.app, models.dynamics; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "False"
