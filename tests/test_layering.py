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


#: The packages of ``service/`` from the bottom up: a module may import its own package and the
#: ones below it, never one above (``service/wire/__init__.py``).
SERVICE_TIERS = ("wire", "runtime", "flows", "api")


def _service_imports(path: Path) -> set[str]:
    """The ``service`` sub-packages ``path`` imports (``service.flows.agents`` -> ``flows``)."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        modules: list[str] = []
        if isinstance(node, ast.Import):
            modules = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            modules = [node.module]
            if node.module == "service":
                modules = [f"service.{a.name}" for a in node.names]
        names.update(m.split(".")[1] for m in modules if m.startswith("service.") and "." in m)
    return names


@pytest.mark.parametrize("tier", SERVICE_TIERS)
def test_service_packages_import_downwards_only(tier: str) -> None:
    rank = SERVICE_TIERS.index(tier)
    files = _files(f"service/{tier}")
    assert files, f"no sources in service/{tier}"
    offenders = {
        str(f.relative_to(ROOT)): sorted(above)
        for f in files
        if (above := {p for p in _service_imports(f) if p in SERVICE_TIERS[rank + 1 :]})
    }
    assert offenders == {}


def test_every_service_module_is_in_a_tier() -> None:
    packages = {p.name for p in (ROOT / "service").iterdir() if (p / "__init__.py").exists()}
    assert packages == set(SERVICE_TIERS)


def test_the_wire_knows_no_web_framework() -> None:
    offenders = {
        str(f.relative_to(ROOT)): sorted(_imports(f) & {"fastapi", "starlette"})
        for f in _files("service/wire")
        if _imports(f) & {"fastapi", "starlette"}
    }
    assert offenders == {}


def test_the_tier_scan_sees_an_upward_import(tmp_path: Path) -> None:
    module = tmp_path / "m.py"
    module.write_text(
        "def f():\n    from service.flows.agents import observe\n    import service.api\n"
    )
    assert _service_imports(module) == {"flows", "api"}


def test_training_and_export_do_not_import_each_other() -> None:
    """``models.pipeline`` runs train -> export; ``models.train`` knows nothing of the export."""

    def models_imported(path: Path) -> set[str]:
        found: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if (
                isinstance(node, ast.ImportFrom)
                and node.module
                and node.module.startswith("models.")
            ):
                found.add(node.module)
        return found

    assert "models.export" not in models_imported(ROOT / "models" / "train.py")
    assert {"models.train", "models.export"} <= models_imported(ROOT / "models" / "pipeline.py")
