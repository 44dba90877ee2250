"""The FastAPI application: ``uvicorn service.app:app``."""

from __future__ import annotations

from fastapi import FastAPI

app = FastAPI(title="FRT service", version="0.1.0")


@app.get("/healthz")
def healthz() -> dict[str, str]:
    return {"status": "ok"}


@app.get("/readyz")
def readyz() -> dict[str, object]:
    return {"ready": False, "model": None}
