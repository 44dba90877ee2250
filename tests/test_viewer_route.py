"""``GET /viewer`` and its static files in-process: the auth rule of ``/v1``, the setting that
turns it off, and the stream's ``list_agents`` op the page polls."""

from __future__ import annotations

import fnmatch
import tomllib
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from service.api.app import create_app
from service.api.routes.viewer import STATIC, VIEWER_DIR
from service.runtime.settings import Settings
from tests.fixtures.payloads import observation
from tests.test_api_errors import client_for


def settings(model: Path, **extra: object) -> Settings:
    return Settings(model_path=model, log_requests=False, frt_executor="thread", **extra)


@pytest.fixture(scope="module")
def open_client(analytic_model_path: Path) -> Iterator[TestClient]:
    yield from client_for(settings(analytic_model_path, max_agents_per_check=2))


def test_page_and_its_files_are_served(open_client: TestClient) -> None:
    page = open_client.get("/viewer")
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    assert "default-src 'self'" in page.headers["content-security-policy"]
    assert page.headers["referrer-policy"] == "no-referrer"
    # Every script and style the page names is served, with its media type.
    for name in (
        "viewer.js",
        "vendor/d3.min.js",
        "vendor/uPlot.iife.min.js",
        "vendor/uPlot.min.css",
    ):
        assert f"viewer/static/{name}" in page.text
        r = open_client.get(f"/viewer/static/{name}")
        assert r.status_code == 200, name
        assert r.content == (VIEWER_DIR / name).read_bytes()
        kind = "text/css" if name.endswith(".css") else "text/javascript"
        assert r.headers["content-type"].startswith(kind)


def test_only_the_viewers_own_scripts_and_styles_are_served(open_client: TestClient) -> None:
    assert "viewer.js" in STATIC and all(p.suffix in (".js", ".css") for p in STATIC.values())
    for name in ("index.html", "vendor/VENDORED.md", "vendor/LICENSE.d3", "../routes/viewer.py",
                 "..%2Froutes%2Fviewer.py", "/etc/passwd", "nope.js"):  # fmt: skip
        assert open_client.get(f"/viewer/static/{name}").status_code == 404, name


def test_list_agents_op_answers_every_agent_as_get_agent_does(open_client: TestClient) -> None:
    with open_client.websocket_connect("/v1/stream") as ws:

        def call(message: dict) -> dict:
            ws.send_json(message)
            return ws.receive_json()

        before = call({"id": 0, "op": "list_agents"})["result"]
        for agent in ("view-b", "view-a"):
            assert call({"id": 1, "op": "observe", "agent_id": agent, **observation(1.0, x=3.0)})[
                "ok"
            ]
        listed = call({"id": 2, "op": "list_agents"})
        assert listed["ok"] is True
        result = listed["result"]
        assert result["total"] == before["total"] + 2
        # max_agents_per_check = 2 here: the first two by id, and the answer says it is cut.
        assert result["truncated"] is (result["total"] > 2)
        ids = [a["agent_id"] for a in result["agents"]]
        assert ids == sorted(ids) and len(ids) == 2
        one = call({"id": 3, "op": "get_agent", "agent_id": "view-a"})["result"]
        row = next(a for a in result["agents"] if a["agent_id"] == "view-a")
        for key in ("state", "beta", "belief", "control_bounds", "frt_version", "timestamp"):
            assert row[key] == one[key], key
        assert row["state"]["x"] == 3.0
        assert call({"id": 4, "op": "list_agents", "agent_id": "x"})["error"]["field"] == "agent_id"
        # A planner's check, over the stream and over HTTP, is listed with its answer, newest first.
        path = [{"t": 1.1, "x": 3.0, "y": 0.0}, {"t": 1.2, "x": 40.0, "y": 30.0}]
        one = call({"id": 7, "op": "collision_check", "agent_id": "view-a", "trajectory": path})
        assert one["ok"] and one["result"]["collision"] is True  # it starts on the agent
        far = [{"t": 1.1, "x": 90.0, "y": 90.0}]
        many = open_client.post("/v1/collision-check", json={"trajectory": far}).json()
        assert many["collision"] is False
        checks = call({"id": 8, "op": "list_agents"})["result"]["checks"]
        assert [c["trajectory"] for c in checks[:2]] == [
            [[1.1, 90.0, 90.0]],
            [[1.1, 3.0, 0.0], [1.2, 40.0, 30.0]],
        ]
        assert checks[1]["collision"] is True and checks[0]["collision"] is False
        assert checks[1]["agents"]["view-a"]["first_collision_index"] == 0
        assert set(checks[0]["agents"]) == {"view-a", "view-b"}
        for agent in ("view-a", "view-b"):
            call({"id": 5, "op": "delete_agent", "agent_id": agent})
        assert call({"id": 6, "op": "list_agents"})["result"]["total"] == before["total"]


def test_token_guards_the_page_as_it_guards_v1(analytic_model_path: Path) -> None:
    with TestClient(create_app(settings(analytic_model_path, auth_token="s3cret"))) as client:
        refused = client.get("/viewer")
        assert refused.status_code == 401 and refused.headers["www-authenticate"] == "Bearer"
        assert client.get("/viewer?token=nope").status_code == 401
        assert client.get("/viewer", headers={"Authorization": "Bearer nope"}).status_code == 401
        assert client.get("/viewer?token=s3cret").status_code == 200
        assert client.get("/viewer", headers={"Authorization": "Bearer s3cret"}).status_code == 200
        # The data stays behind /v1's own rule; the static files hold none.
        assert client.get("/v1/model?token=s3cret").status_code == 401
        assert client.get("/viewer/static/viewer.js").status_code == 200


def test_setting_off_makes_every_viewer_path_404(analytic_model_path: Path) -> None:
    with TestClient(create_app(settings(analytic_model_path, viewer=False))) as client:
        assert client.get("/viewer").status_code == 404
        assert client.get("/viewer/static/viewer.js").status_code == 404
        assert client.get("/healthz").status_code == 200


def test_setting_reads_frt_viewer_from_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("FRT_VIEWER", "0")
    assert Settings().viewer is False
    monkeypatch.setenv("FRT_VIEWER", "1")
    assert Settings().viewer is True


def test_the_package_ships_every_viewer_file() -> None:
    """pip install . (the Docker image's build) copies only what package-data names."""
    pyproject = tomllib.loads((VIEWER_DIR.parents[2] / "pyproject.toml").read_text())
    patterns = pyproject["tool"]["setuptools"]["package-data"]["service.api"]
    files = [p.relative_to(VIEWER_DIR.parent).as_posix() for p in VIEWER_DIR.rglob("*")]
    files = [f for f in files if (VIEWER_DIR.parent / f).is_file() and "__pycache__" not in f]
    assert "viewer/index.html" in files and "viewer/vendor/LICENSE.uplot" in files
    unshipped = [f for f in files if not any(fnmatch.fnmatch(f, p) for p in patterns)]
    assert unshipped == []
