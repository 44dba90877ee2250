"""The tiers and rooms of DESIGN.md: arrows run one way, and the runtime never imports torch.

* ``reach/`` (the certified geometry) imports neither ``service`` nor ``models``, nor torch,
  onnxruntime or FastAPI;
* ``models/`` never imports ``service``;
* the runtime (``reach/``, ``service/``, the ONNX wrapper ``models/runtime.py`` and
  ``models/value_fields.py``) and the client SDK never import torch.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
TORCH_FREE = [
    "reach",
    "service",
    "client/frt_client",
    "models/runtime.py",
    "models/value_fields.py",
]
#: Per room: top-level packages its modules must not import.
FORBIDDEN = {
    "reach": {"service", "models", "torch", "onnxruntime", "fastapi", "starlette", "pydantic"},
    "models": {"service"},
    "client/frt_client": {"service", "models", "reach", "torch", "onnxruntime"},
}


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text())
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module.split(".")[0])
    return names


def _files(entry: str) -> list[Path]:
    p = ROOT / entry
    return [p] if p.is_file() else sorted(p.rglob("*.py"))


def test_no_torch_in_runtime_sources() -> None:
    files = [f for entry in TORCH_FREE for f in _files(entry)]
    assert len(files) > 20, "nothing scanned"
    offenders = [str(f) for f in files if "torch" in _imports(f)]
    assert offenders == []


@pytest.mark.parametrize("room", sorted(FORBIDDEN))
def test_imports_run_one_way(room: str) -> None:
    files = _files(room)
    assert files, f"no sources in {room}"
    offenders = {
        str(f.relative_to(ROOT)): sorted(_imports(f) & FORBIDDEN[room])
        for f in files
        if _imports(f) & FORBIDDEN[room]
    }
    assert offenders == {}


def test_the_scan_sees_a_forbidden_import(tmp_path: Path) -> None:
    """The scan itself: a module importing ``service`` lazily inside a function is caught."""
    module = tmp_path / "m.py"
    module.write_text("def f():\n    from service.api import app\n    import torch.nn\n")
    assert {"service", "torch"} <= _imports(module)


def test_importing_the_service_does_not_load_torch() -> None:
    code = (
        "import sys, service.api.app, models.value_fields, reach.engine; "
        "print('torch' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "False"


def test_importing_reach_loads_neither_service_nor_models() -> None:
    code = (
        "import sys, pkgutil, importlib, reach\n"
        "for m in pkgutil.iter_modules(reach.__path__): importlib.import_module('reach.' + m.name)\n"
        "print(sorted({n.split('.')[0] for n in sys.modules} & {'service', 'models', 'torch', "
        "'onnxruntime', 'fastapi'}))"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"
