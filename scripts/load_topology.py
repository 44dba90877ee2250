"""`make load` against a service this script starts: one process, or replicas behind nginx.

Topologies (loopback only, every process started here and stopped by its pid at the end):

* ``single``: one ``uvicorn service.api.app:app`` as ``make serve`` runs it (its worker
  processes as the settings say);
* ``replicas``: redis-server, ``--replicas`` uvicorn replicas sharing agent state through it
  (``FRT_STORE_URL``) and nginx running ``docker/nginx.conf`` in front of them, rewritten for
  loopback as ``make scale-test`` does (``tests/test_deploy_files.render_nginx_conf``).

Before the load it records how busy the machine is, in the same run: the HTTP floor (``GET
/healthz`` one at a time through the same front: nginx for replicas), an exact set alone
in-process (this process, the shipped model) and the load average. Then it runs
``scripts/load.py`` with the given mix, and sums the servers' own counters (``/metrics`` of
every replica, so nothing is missed behind nginx): per-agent answers from exact sets, checks
answered late at the server, exact sets computed by origin (``frt_exact_sets``: a ``read`` set is
one a replica computed for a version it did not store, i.e. computed twice across replicas or
rebuilt). It prints one line per run and writes a JSON summary, with each server's own counters.

``--frames --scenes S`` is load.py's frames mode: the humans split into S scenes, each observed in
one ``POST /v1/frames`` per period and checked by its own planners, every request with its
``X-FRT-Scene`` (nginx routes each scene to one replica).

    python scripts/load_topology.py --topology single --humans 50 --obs-hz 10 --duration 60
    python scripts/load_topology.py --topology replicas --replicas 3 --humans 50 --obs-hz 10
    python scripts/load_topology.py --topology replicas --frames --scenes 6 --planners 1

``--src DIR`` serves another checkout of the project (e.g. an older commit exported with ``git
archive``) with this venv, for side-by-side comparisons on a shared machine.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import httpx

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

LOAD = ROOT / "scripts" / "load.py"
MAX_REPLICAS = 8
SBIN_PATH = os.pathsep.join([os.environ.get("PATH", ""), "/usr/sbin", "/usr/local/sbin", "/sbin"])
#: The servers' counters summed over every replica (name as /metrics prints it -> key).
COUNTERS = {
    "frt_deadline_misses_total": "deadline_misses",
    'frt_collision_checks_total{source="conservative"}': "conservative",
    'frt_collision_checks_total{source="exact"}': "exact",
    'frt_conservative_answers_total{reason="not_ready"}': "not_ready",
    'frt_conservative_answers_total{reason="no_time"}': "no_time",
    'frt_conservative_answers_total{reason="tubes"}': "tubes",
    'frt_compute_seconds_count{kind="exact"}': "exact_sets",
    'frt_compute_seconds_sum{kind="exact"}': "exact_seconds",
    'frt_exact_phase_seconds_sum{phase="queued"}': "queued_seconds",
    'frt_exact_phase_seconds_count{phase="queued"}': "queued_sets",
    'frt_exact_phase_seconds_sum{phase="transfer"}': "transfer_seconds",
    'frt_exact_sets_total{origin="observed"}': "sets_observed",
    'frt_exact_sets_total{origin="read"}': "sets_read",
}


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--topology", choices=("single", "replicas"), default="single")
    p.add_argument("--replicas", type=int, default=3, help=f"replicas (1..{MAX_REPLICAS})")
    p.add_argument(
        "--workers", type=int, default=None, help="exact-set worker processes per server "
        "(default: the settings' for single, 1 per replica)"
    )  # fmt: skip
    p.add_argument("--port", type=int, default=8270, help="first loopback port to use")
    p.add_argument("--duration", type=float, default=60.0)
    p.add_argument("--planners", type=int, default=2)
    p.add_argument("--humans", type=int, default=10)
    p.add_argument("--obs-hz", type=float, default=5.0)
    p.add_argument("--check-hz", type=float, default=10.0)
    p.add_argument("--scenes", type=int, default=1, help="load.py --scenes")
    p.add_argument("--frames", action="store_true", help="load.py --frames")
    p.add_argument("--model", type=Path, default=ROOT / "models" / "frt_unicycle.onnx")
    p.add_argument("--src", type=Path, default=ROOT, help="the project checkout to serve")
    p.add_argument("--env", action="append", default=[], help="FRT_X=value for the servers")
    p.add_argument("--out", type=Path, default=ROOT / "results" / "load_topology.json")
    p.add_argument("--label", default="", help="a name for this run in the summary")
    return p.parse_args(argv)


# ------------------------------------------------------------------------------ processes


def port_free(port: int) -> bool:
    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) != 0


def wait_http(url: str, proc: subprocess.Popen[bytes], log: Path, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"{url}: process exited:\n{log.read_text()[-3000:]}")
        try:
            if httpx.get(url, timeout=1.0).status_code == 200:
                return
        except httpx.TransportError:
            pass
        time.sleep(0.2)
    raise TimeoutError(f"{url} not ready in {timeout_s:g} s:\n{log.read_text()[-3000:]}")


def stop(proc: subprocess.Popen[bytes], sig: int = signal.SIGTERM) -> None:
    if proc.poll() is None:
        proc.send_signal(sig)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@contextmanager
def servers(args: argparse.Namespace, workdir: Path) -> Iterator[tuple[str, list[str], list[int]]]:
    """Start the topology; yields (the URL clients use, every server's own URL, their pids)."""
    procs: list[tuple[subprocess.Popen[bytes], int]] = []
    env = {k: v for k, v in os.environ.items() if not k.startswith("FRT_")}
    env["FRT_MODEL_PATH"] = str(args.model.resolve())
    env["PYTHONPATH"] = str(args.src.resolve())
    for item in args.env:
        key, _, value = item.partition("=")
        env[key] = value
    ports = iter(p for p in range(args.port, args.port + 100) if port_free(p))
    try:
        if args.topology == "replicas":
            redis_port = next(ports)
            redis = shutil.which("redis-server", path=SBIN_PATH)
            if redis is None:
                raise RuntimeError("redis-server not installed (apt-get install redis-server)")
            redis_proc = subprocess.Popen(
                [redis, "--port", str(redis_port), "--bind", "127.0.0.1", "--dir", str(workdir),
                 "--save", "", "--appendonly", "no", "--logfile", str(workdir / "redis.log")],
                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            )  # fmt: skip
            procs.append((redis_proc, signal.SIGTERM))
            env["FRT_STORE_URL"] = f"redis://127.0.0.1:{redis_port}/0"
        count = args.replicas if args.topology == "replicas" else 1
        workers = args.workers or (1 if args.topology == "replicas" else None)
        if workers is not None:
            env["FRT_FRT_WORKERS"] = str(workers)
        addresses = []
        for i in range(count):
            port = next(ports)
            log = workdir / f"server{i}.log"
            proc = subprocess.Popen(
                [sys.executable, "-m", "uvicorn", "service.api.app:app", "--host", "127.0.0.1",
                 "--port", str(port)],
                cwd=args.src, env=env, stdout=log.open("wb"), stderr=subprocess.STDOUT,
            )  # fmt: skip
            procs.append((proc, signal.SIGTERM))
            addresses.append((f"127.0.0.1:{port}", proc, log))
        for address, proc, log in addresses:
            wait_http(f"http://{address}/readyz", proc, log, 240.0)
        own = [f"http://{address}" for address, _, _ in addresses]
        pids = [proc.pid for _, proc, _ in addresses]
        if args.topology == "single":
            yield own[0], own, pids
            return
        from tests.test_deploy_files import NGINX_CONF, render_nginx_conf

        nginx = shutil.which("nginx", path=SBIN_PATH)
        if nginx is None:
            raise RuntimeError("nginx not installed (apt-get install nginx)")
        front = next(ports)
        conf = workdir / "nginx.conf"
        conf.write_text(
            render_nginx_conf(
                NGINX_CONF.read_text(),
                upstreams=[a for a, _, _ in addresses],
                listen_port=front,
                workdir=workdir,
            )
        )
        log = workdir / "nginx.log"
        nginx_proc = subprocess.Popen(
            [nginx, "-p", str(workdir), "-c", str(conf), "-e", "stderr", "-g", "daemon off;"],
            stdout=subprocess.DEVNULL, stderr=log.open("wb"),
        )  # fmt: skip
        procs.append((nginx_proc, signal.SIGQUIT))
        wait_http(f"http://127.0.0.1:{front}/readyz", nginx_proc, log, 30.0)
        yield f"http://127.0.0.1:{front}", own, pids
    finally:
        for proc, sig in reversed(procs):
            stop(proc, sig)


# ------------------------------------------------------------------------------ measurement


def http_floor(url: str, count: int = 200) -> dict[str, float]:
    """``GET /healthz`` one at a time: p50 and p99 in ms (what any request costs right now)."""
    times = []
    with httpx.Client(timeout=5.0) as http:
        for _ in range(count):
            start = time.perf_counter()
            http.get(f"{url}/healthz")
            times.append((time.perf_counter() - start) * 1000.0)
    times.sort()
    return {"p50_ms": statistics.median(times), "p99_ms": times[int(0.99 * (len(times) - 1))]}


def exact_reference(model: Path, repeats: int = 20) -> float:
    """Median ms of one exact set (a moving car) in this process: the CPU left right now."""
    from scripts.fallback_cost import served_engine
    from service.runtime.exact_worker import warm_up_task

    task = warm_up_task(served_engine(model))
    task()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        task()
        times.append((time.perf_counter() - start) * 1000.0)
    return statistics.median(times)


def cpu_seconds(pid: int) -> float:
    """User + system CPU seconds of process ``pid`` so far (Linux ``/proc``; 0 if it is gone)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def children(pid: int) -> list[int]:
    """The child processes of ``pid`` (its exact-set workers, for a server)."""
    found: list[int] = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            found += [int(c) for c in (task / "children").read_text().split()]
        except OSError:
            continue
    return found


def counters_each(urls: list[str]) -> list[dict[str, float]]:
    """COUNTERS of each server."""
    found = []
    for url in urls:
        values = dict.fromkeys(COUNTERS.values(), 0.0)
        text = httpx.get(f"{url}/metrics", timeout=5.0).text
        for line in text.splitlines():
            match = re.match(r"^(\S+?)\s+(\S+)$", line)
            if match and match.group(1) in COUNTERS:
                values[COUNTERS[match.group(1)]] += float(match.group(2))
        found.append(values)
    return found


def counters(urls: list[str]) -> dict[str, float]:
    """COUNTERS summed over every server."""
    each = counters_each(urls)
    return {key: sum(values[key] for values in each) for key in COUNTERS.values()}


def run(args: argparse.Namespace) -> dict[str, Any]:
    workdir = Path(tempfile.mkdtemp(prefix="frt-topology-"))
    workdir.chmod(0o755)  # nginx's workers (user nobody) write temp files here
    try:
        with servers(args, workdir) as (url, own, pids):
            reference_ms = exact_reference(args.model)
            floor = http_floor(url)
            load_avg = os.getloadavg()[0]
            before = counters_each(own)
            workers = [child for pid in pids for child in children(pid)]
            cpu_before = (sum(map(cpu_seconds, pids)), sum(map(cpu_seconds, workers)))
            harness_before = resource.getrusage(resource.RUSAGE_CHILDREN)
            out = workdir / "load.json"
            cmd = [
                sys.executable, str(LOAD), "--url", url, "--duration", str(args.duration),
                "--planners", str(args.planners), "--humans", str(args.humans),
                "--obs-hz", str(args.obs_hz), "--check-hz", str(args.check_hz),
                "--scenes", str(args.scenes), "--model", str(args.model), "--out", str(out),
                *(["--frames"] if args.frames else []),
            ]  # fmt: skip
            done = subprocess.run(cmd, capture_output=True, text=True, timeout=args.duration + 300)
            after = counters_each(own)
            harness_after = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu = {
                "servers": sum(map(cpu_seconds, pids)) - cpu_before[0],
                "workers": sum(map(cpu_seconds, workers)) - cpu_before[1],
                "load_harness": harness_after.ru_utime
                + harness_after.ru_stime
                - harness_before.ru_utime
                - harness_before.ru_stime,
            }
            if not out.exists():
                raise RuntimeError(f"load.py wrote nothing:\n{done.stdout}\n{done.stderr}")
            load = json.loads(out.read_text())
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    each = [{k: a[k] - b[k] for k in a} for a, b in zip(after, before, strict=True)]
    server = {key: sum(values[key] for values in each) for key in COUNTERS.values()}
    answers = server["exact"] + server["conservative"]
    check = load["operations"].get("check", {})
    return {
        "label": args.label,
        "topology": args.topology,
        "replicas": args.replicas if args.topology == "replicas" else 1,
        "workers_per_server": args.workers,
        "src": str(args.src),
        "env": args.env,
        "mix": {
            k: load["config"][k]
            for k in ("planners", "humans", "obs_hz", "check_hz", "scenes", "frames")
        },
        "duration_s": args.duration,
        "machine": {
            "http_floor_p50_ms": floor["p50_ms"],
            "http_floor_p99_ms": floor["p99_ms"],
            "exact_set_in_process_ms": reference_ms,
            "load_average_1min": load_avg,
        },
        "exact_share_client": load["deadline"]["exact_share"],
        "exact_share_server": server["exact"] / answers if answers else None,
        #: Per-agent answers from the exact set or cleared by a set holding it (load.py's count).
        "decision_exact_share_client": load["deadline"]["decision_exact_share"],
        "verdicts": load["deadline"]["verdicts"],
        "versions_stored": load["versions_stored"],
        "server": server,
        "per_server": each,
        #: CPU seconds over the load, of the servers' own processes, of their exact-set workers
        #: and of the load harness (the rest of the machine's two cores went to other work).
        "cpu_seconds": cpu,
        "check_p50_ms": check.get("p50_ms"),
        "check_p99_ms": check.get("p99_ms"),
        "frame_p50_ms": load["operations"].get("frame", {}).get("p50_ms"),
        "frame_p99_ms": load["operations"].get("frame", {}).get("p99_ms"),
        "late_client": load["deadline"]["client_over_deadline"],
        "late_server": server["deadline_misses"],
        "checks": check.get("count"),
        "observations": load["operations"].get("observe", {}).get("count"),
        "frames": load["operations"].get("frame", {}).get("count"),
        "errors": load["errors"],
        "errors_by_op": load["errors_by_op"],
        "error_samples": load["error_samples"],
        "skipped_ticks": load["skipped_ticks"],
        "fallback_area_ratio": load["fallback_area_ratio"],
        "load_exit": done.returncode,
        "finished_at": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }


def line(r: dict[str, Any]) -> str:
    m, s = r["machine"], r["server"]
    share = r["exact_share_server"]
    decision = r["decision_exact_share_client"] or 0.0
    sets = s["exact_sets"]
    mix = r["mix"]
    scenes = f" in {mix['scenes']} scenes" if mix["scenes"] > 1 else ""
    return (
        f"{r['label'] or r['topology']}: {r['replicas']} server(s), {mix['humans']} humans "
        f"at {mix['obs_hz']:g} Hz{scenes}{' observed in frames' if mix['frames'] else ''}, "
        f"{mix['planners']} planners{' per scene' if scenes else ''} at "
        f"{mix['check_hz']:g} Hz: exact {100 * share:.1f} % of per-agent answers, exact or "
        f"decision-exact {100 * decision:.1f} % "
        f"(not ready {s['not_ready']:.0f}, no time {s['no_time']:.0f}, tubes {s['tubes']:.0f}); "
        f"check p50/p99 {r['check_p50_ms']:.2f}/{r['check_p99_ms']:.2f} ms, late "
        f"{r['late_client']} client / {r['late_server']:.0f} server of {r['checks']}; "
        f"{sets:.0f} exact sets computed ({s['sets_observed']:.0f} observed, {s['sets_read']:.0f} "
        f"read) for {r['versions_stored']} versions stored, "
        f"{1000 * s['exact_seconds'] / max(sets, 1):.1f} ms each "
        f"in a worker, {1000 * s['queued_seconds'] / max(s['queued_sets'], 1):.1f} ms queued, "
        f"{1000 * s['transfer_seconds'] / max(sets, 1):.1f} ms in transfer; "
        f"CPU s: servers {r['cpu_seconds']['servers']:.0f}, workers "
        f"{r['cpu_seconds']['workers']:.0f}, load harness {r['cpu_seconds']['load_harness']:.0f}; "
        f"{r['observations'] or 0} observations, {r['frames'] or 0} frames"
        + (
            f" (p50/p99 {r['frame_p50_ms']:.1f}/{r['frame_p99_ms']:.1f} ms); "
            if r["frames"]
            else "; "
        )
        + f"skipped ticks {r['skipped_ticks']}; "
        f"floor {m['http_floor_p50_ms']:.2f} ms, exact set in-process "
        f"{m['exact_set_in_process_ms']:.1f} ms, load average {m['load_average_1min']:.2f}"
    )


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if not 1 <= args.replicas <= MAX_REPLICAS or not 0 < args.duration <= 600:
        print("load_topology.py: --replicas 1..8 and --duration (0, 600] s", file=sys.stderr)
        return 2
    result = run(args)
    print(line(result))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    runs = json.loads(args.out.read_text()) if args.out.exists() else []
    runs.append(result)
    args.out.write_text(json.dumps(runs, indent=2) + "\n")
    return 0 if result["errors"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
