"""Writing the model card: the JSON beside the ONNX file, with the file's sha256."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any


def file_sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def write_card(card: dict[str, Any], onnx_path: Path) -> Path:
    card = dict(card)
    card["sha256"] = file_sha256(onnx_path)
    card["file"] = Path(onnx_path).name
    path = Path(onnx_path).with_suffix(".json")
    path.write_text(json.dumps(card, indent=2) + "\n")
    return path
