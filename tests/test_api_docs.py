"""docs/api.md against the app's OpenAPI schema: every operation documented, nothing else.

A route is documented by a heading ``### METHOD /path`` (``WS`` for the WebSocket, which OpenAPI
does not describe); its section, up to the next heading, must name every top-level field of the
route's request body and every query parameter in backticks. The WebSocket section must name every
op of ``service.api.stream.OPS``.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from service.api import stream
from service.api.app import app

API_MD = Path(__file__).resolve().parent.parent / "docs" / "api.md"
HEADING = re.compile(r"^### (GET|POST|PUT|PATCH|DELETE|WS) (/\S*)\s*$", re.MULTILINE)
ANY_HEADING = re.compile(r"^#{1,3} ", re.MULTILINE)
HTTP_METHODS = {"get", "post", "put", "patch", "delete"}

Operation = tuple[str, str]


def documented_sections(text: str) -> dict[Operation, str]:
    """(METHOD, path) of every route heading -> the text of its section."""
    sections: dict[Operation, str] = {}
    for match in HEADING.finditer(text):
        following = ANY_HEADING.search(text, match.end())
        end = following.start() if following else len(text)
        sections[(match.group(1), match.group(2))] = text[match.end() : end]
    return sections


def schema_operations(schema: dict[str, Any]) -> dict[Operation, dict[str, Any]]:
    return {
        (method.upper(), path): operation
        for path, methods in schema["paths"].items()
        for method, operation in methods.items()
        if method in HTTP_METHODS
    }


def _resolve(schema: dict[str, Any], node: dict[str, Any]) -> dict[str, Any]:
    ref = node.get("$ref")
    if ref is None:
        return node
    target: Any = schema
    for part in ref.removeprefix("#/").split("/"):
        target = target[part]
    return target


def named_inputs(schema: dict[str, Any], operation: dict[str, Any]) -> set[str]:
    """The operation's query parameters and the top-level properties of its JSON body."""
    names = {p["name"] for p in operation.get("parameters", []) if p["in"] == "query"}
    body = operation.get("requestBody", {}).get("content", {}).get("application/json")
    if body is not None:
        names |= set(_resolve(schema, body["schema"]).get("properties", {}))
    return names


def problems(schema: dict[str, Any], text: str, websocket_paths: set[str]) -> list[str]:
    """Everything in which ``text`` (docs/api.md) and the schema disagree."""
    sections = documented_sections(text)
    operations = schema_operations(schema)
    found = [f"{m} {p}: in the schema, no heading" for m, p in operations if (m, p) not in sections]
    for (method, path), section in sections.items():
        if method == "WS":
            if path not in websocket_paths:
                found.append(f"WS {path}: documented, no such WebSocket route")
            continue
        operation = operations.get((method, path))
        if operation is None:
            found.append(f"{method} {path}: documented, not in the schema")
            continue
        for name in sorted(named_inputs(schema, operation)):
            if f"`{name}`" not in section:
                found.append(f"{method} {path}: input `{name}` not named in its section")
    return found


@pytest.fixture(scope="module")
def schema() -> dict[str, Any]:
    return app.openapi()


@pytest.fixture(scope="module")
def api_md() -> str:
    return API_MD.read_text()


def test_schema_has_the_contracts_routes(schema: dict[str, Any]) -> None:
    """The comparison below is not empty: the schema holds the routes of API.md."""
    operations = schema_operations(schema)
    assert ("POST", "/v1/agents/{agent_id}/observations") in operations
    assert ("POST", "/v1/frt") in operations
    assert len(operations) >= 10


def test_api_md_matches_the_openapi_schema(schema: dict[str, Any], api_md: str) -> None:
    ws_paths = {p for (m, p) in documented_sections(api_md) if m == "WS"}
    assert problems(schema, api_md, ws_paths) == []


def test_documented_websocket_routes_answer() -> None:
    """Each ``### WS`` path is a live WebSocket route of the app: it answers a ping."""
    paths = [p for (m, p) in documented_sections(API_MD.read_text()) if m == "WS"]
    assert paths == ["/v1/stream"]
    client = TestClient(app)  # no lifespan: the model is not needed for a ping
    for path in paths:
        with client.websocket_connect(path) as socket:
            socket.send_json({"id": 1, "op": "ping"})
            assert socket.receive_json() == {"id": 1, "ok": True, "result": {"pong": True}}


def test_stream_section_names_every_op(api_md: str) -> None:
    section = documented_sections(api_md)[("WS", "/v1/stream")]
    assert [op for op in stream.OPS if f"`{op}`" not in section] == []


def test_a_missing_heading_or_field_is_found(schema: dict[str, Any], api_md: str) -> None:
    """The check fails on a page with a route's heading removed, a field dropped from a section,
    or a heading for a route that does not exist."""
    ws_paths = {"/v1/stream"}
    no_heading = api_md.replace("### POST /v1/frt\n", "POST /v1/frt\n", 1)
    assert no_heading != api_md
    assert "POST /v1/frt: in the schema, no heading" in problems(schema, no_heading, ws_paths)

    start = api_md.index("### POST /v1/agents/{agent_id}/collision-check")
    end = api_md.index("###", start + 4)
    section = api_md[start:end]
    no_field = api_md[:start] + section.replace("`deadline_ms`", "deadline") + api_md[end:]
    found = problems(schema, no_field, ws_paths)
    assert (
        "POST /v1/agents/{agent_id}/collision-check: input `deadline_ms` not named in its section"
        in found
    )

    extra = api_md + "\n### GET /v1/nothing\n\n### WS /v1/nowhere\n"
    found = problems(schema, extra, ws_paths)
    assert "GET /v1/nothing: documented, not in the schema" in found
    assert "WS /v1/nowhere: documented, no such WebSocket route" in found
