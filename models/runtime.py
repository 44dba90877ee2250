"""The value network at run time: an onnxruntime session and its model card.

The card (models/<name>.json) carries the semantics ("set" or "tube"), the calibrated margin delta,
the trained input ranges and the sha256 of the ONNX file, which is checked on load.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort

from reach.contract import COLUMNS, INPUT_NAME, N_INPUTS


class ModelLoadError(RuntimeError):
    """The model or its card is missing, corrupt or does not follow the contract."""


@dataclass(frozen=True)
class ModelCard:
    name: str
    semantics: str
    delta: float
    ranges: dict[str, tuple[float, float]]
    horizon_s: float
    initial_set: dict[str, float]
    raw: dict[str, Any] = field(repr=False)

    @classmethod
    def from_json(cls, raw: dict[str, Any]) -> ModelCard:
        try:
            semantics = raw["semantics"]
            if semantics not in ("set", "tube"):
                raise ModelLoadError(f"unknown semantics {semantics!r}")
            ranges = {k: (float(v[0]), float(v[1])) for k, v in raw["ranges"].items()}
            missing = [c for c in COLUMNS if c not in ranges]
            if missing:
                raise ModelLoadError(f"card ranges miss columns {missing}")
            return cls(
                name=str(raw["name"]),
                semantics=semantics,
                delta=float((raw.get("calibration") or {}).get("delta", 0.0)),
                ranges=ranges,
                horizon_s=float(raw["horizon_s"]),
                initial_set={k: float(v) for k, v in raw["initial_set"].items()},
                raw=raw,
            )
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise ModelLoadError(f"malformed model card: {exc!r}") from exc


def file_sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _session(path: Path, threads: int) -> ort.InferenceSession:
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    try:
        session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime raises its own exception types
        raise ModelLoadError(f"onnxruntime cannot load {path}: {exc}") from exc
    inputs = session.get_inputs()
    if len(inputs) != 1 or inputs[0].name != INPUT_NAME or inputs[0].shape[-1] != N_INPUTS:
        raise ModelLoadError(f"{path.name}: model input must be x: float32 [N, 14]")
    return session


class ValueModel:
    """V(x) for [N, 14] physical inputs, evaluated with onnxruntime on the CPU."""

    def __init__(
        self,
        session: ort.InferenceSession,
        card: ModelCard,
        projection: ort.InferenceSession | None = None,
    ) -> None:
        self.session = session
        self.card = card
        self.projection = projection
        self._output = session.get_outputs()[0].name

    @classmethod
    def load(
        cls,
        onnx_path: Path,
        card_path: Path | None = None,
        threads: int = 1,
        prefer_runtime_graph: bool = True,
    ) -> ValueModel:
        """Load the contract graph and its card; evaluate with the card's faster float32 twin
        (``runtime_graph``) when it is present and its sha256 matches."""
        onnx_path = Path(onnx_path)
        card_path = Path(card_path) if card_path else onnx_path.with_suffix(".json")
        if not onnx_path.is_file():
            raise ModelLoadError(f"model file not found: {onnx_path}")
        if not card_path.is_file():
            raise ModelLoadError(f"model card not found: {card_path}")
        try:
            raw = json.loads(card_path.read_text())
        except json.JSONDecodeError as exc:
            raise ModelLoadError(f"model card is not JSON: {exc}") from exc
        card = ModelCard.from_json(raw)
        expected = raw.get("sha256")
        if expected and expected != file_sha256(onnx_path):
            raise ModelLoadError(f"sha256 of {onnx_path.name} does not match its card")
        session = _session(onnx_path, threads)
        runtime = raw.get("runtime_graph") or {}
        fast_path = onnx_path.parent / str(runtime.get("file", ""))
        if prefer_runtime_graph and runtime and fast_path.is_file():
            if runtime.get("sha256") != file_sha256(fast_path):
                raise ModelLoadError(f"sha256 of {fast_path.name} does not match the card")
            session = _session(fast_path, threads)
        projection = None
        listed = raw.get("projection_graph") or {}
        projection_path = onnx_path.parent / str(listed.get("file", ""))
        if listed and projection_path.is_file():
            if listed.get("sha256") != file_sha256(projection_path):
                raise ModelLoadError(f"sha256 of {projection_path.name} does not match the card")
            projection = _session(projection_path, threads)
        return cls(session, card, projection)

    def evaluate(self, x: np.ndarray) -> np.ndarray:
        """Values at the rows of ``x`` ([N, 14], physical units, contract column order)."""
        x = np.ascontiguousarray(x, dtype=np.float32)
        if x.ndim != 2 or x.shape[1] != N_INPUTS:
            raise ValueError(f"expected [N, {N_INPUTS}] inputs, got {x.shape}")
        if x.shape[0] == 0:
            return np.zeros(0, dtype=np.float32)
        return self.session.run([self._output], {INPUT_NAME: x})[0][:, 0]

    def evaluate_projection(self, x: np.ndarray) -> np.ndarray:
        """W, the distilled (x, y) projection (models/projection.py), at the rows of ``x``."""
        if self.projection is None:
            raise RuntimeError("this model has no projection graph")
        x = np.ascontiguousarray(x, dtype=np.float32)
        if x.shape[0] == 0:
            return np.zeros(0, dtype=np.float32)
        return self.projection.run(None, {INPUT_NAME: x})[0][:, 0]
