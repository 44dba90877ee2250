"""Where the time goes under `make load`: py-spy samples of the server and its workers, by part.

Starts one server as ``make serve`` does (``scripts/load_topology.py``), samples it and its
worker processes with py-spy (``--subprocesses``, active threads only: a thread waiting on a
socket, a pipe or a lock is not counted) while ``scripts/load.py`` runs the mix, and sorts every
sample into one part of the work by the frames on its stack:

* workers: the exact set's fields and geometry, the whole-horizon tube, the tubes drawn for
  time-indexed checks, the notch cut's refinements, writing the set back as bytes;
* server, event loop: answering collision checks, the observation flow, serialising responses,
  logging, the rest of the HTTP stack and the loop itself;
* server, other threads: the pipe pool's reader (reading the sets back: it takes the GIL from the
  event loop while it does), the request thread pool, the rest.

Seconds are sampled wall time of active threads (CPU, or runnable and waiting for a core: on a
busy machine the two are not told apart). The servers' own counters say how long exact sets
queued and travelled (``frt_exact_phase_seconds``).

    python scripts/profile_load.py --duration 40 --out results/profile_load.json
"""

from __future__ import annotations

import argparse
import collections
import json
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from scripts.exact_cost import mix_set_costs  # noqa: E402
from scripts.load_topology import LOAD, counters, http_floor, servers  # noqa: E402

#: Parts of a worker's work, by the first of these frames (function names) found on the stack,
#: looked for in this order.
WORKER_PARTS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("refinement (notch cut)", ("partition_supports", "FRTEngine._notch", "_notch_tube",
                                "_notch_region")),
    ("tubes for time-indexed checks", ("@tubes_for_checks",)),
    ("whole-horizon tube", ("@whole_tube",)),
    ("exact set: outer bound", ("FRTEngine.outer",)),
    ("exact set: lattice and polygon fields", ("FRTEngine._grid",)),
    ("exact set: instant and interval fields", ("FRTEngine._instant_fields",
                                                "FRTEngine._interval_fields")),
    ("exact set: whether it needs its fields (held check)", ("FRTEngine._held_set",)),
    ("exact set: rest", ("FRTEngine.exact", "exact_union")),
    ("sending the set back", ("_ConnectionBase.send_bytes", "set_to_bytes", "encode_result",
                              "dumps", "BaseGeometry.__reduce__")),
    ("reading the task", ("_ConnectionBase.recv_bytes", "loads")),
)  # fmt: skip
SERVER_LOOP_PARTS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("collision checks: answering", ("answer_states", "_check_agents_at_once", "check_agent")),
    ("observations", ("observe",)),
    ("serialising responses", ("render", "model_dump_json", "jsonable_encoder", "dumps",
                               "serialize_response")),
    ("logging", ("Logger._log", "Logger.info", "Logger.warning", "Logger.handle")),
    ("HTTP stack and middleware", ("RequestResponseCycle.run_asgi", "HttpToolsProtocol",
                                   "H11Protocol")),
)  # fmt: skip


def classify(frames: list[str], parts: tuple[tuple[str, tuple[str, ...]], ...]) -> str | None:
    names = [f.split(" (")[0] for f in frames]
    for part, markers in parts:
        for marker in markers:
            if marker in names:
                return part
    return None


def tube_lines() -> tuple[set[int], set[int]]:
    """Lines of reach/engine.py that draw the tubes for checks and the whole tube."""
    lines = (ROOT / "reach" / "engine.py").read_text().splitlines()
    for_checks = {i + 1 for i, line in enumerate(lines) if line.strip() == "frt.tube(j)"}
    whole = {i + 1 for i, line in enumerate(lines) if line.strip() == "frt.tube(last)"}
    return for_checks, whole


def mark_tubes(frames: list[str], for_checks: set[int], whole: set[int]) -> list[str]:
    """Add a marker frame naming which tube an engine-drawn ``FieldTubeSet.tube`` is."""
    for i, frame in enumerate(frames[:-1]):
        match = re.match(r"FRTEngine\.exact \(reach/engine\.py:(\d+)\)", frame)
        if match and frames[i + 1].startswith("FieldTubeSet.tube"):
            line = int(match.group(1))
            if line in for_checks:
                return [*frames, "@tubes_for_checks"]
            if line in whole:
                return [*frames, "@whole_tube"]
        if frame.startswith("FRTSet.draw_tubes"):
            return [*frames, "@tubes_for_checks"]
    return frames


def breakdown(raw: Path, rate: float) -> dict[str, Any]:
    """Seconds per part, from py-spy's raw (collapsed) output."""
    for_checks, whole = tube_lines()
    parts: dict[str, collections.Counter[str]] = {
        "workers": collections.Counter(),
        "server event loop": collections.Counter(),
        "server other threads": collections.Counter(),
    }
    processes: dict[str, set[str]] = {"workers": set(), "server": set()}
    for text in raw.read_text().splitlines():
        stack, _, count = text.rpartition(" ")
        if not stack:
            continue
        seconds = int(count) / rate
        frames = stack.split(";")
        owners = [f for f in frames if f.startswith("process ")]
        frames = [f for f in frames if not f.startswith("process ") and not f.startswith("thread ")]
        threads = [f for f in stack.split(";") if f.startswith("thread ")]
        if len(owners) > 1:
            processes["workers"].add(owners[-1].split(":")[0])
            frames = mark_tubes(frames, for_checks, whole)
            parts["workers"][classify(frames, WORKER_PARTS) or "worker: other"] += seconds
            continue
        processes["server"].add(owners[0].split(":")[0] if owners else "?")
        names = [f.split(" (")[0] for f in frames]
        if "PipePool._read" in names:
            parts["server other threads"]["pipe pool reader (reading sets)"] += seconds
        elif "Runner.run" in names or "Server.run" in names:
            part = classify(frames, SERVER_LOOP_PARTS) or "event loop: other"
            parts["server event loop"][part] += seconds
        elif "WorkerThread.run" in names or "_worker" in names:
            parts["server other threads"]["thread pool"] += seconds
        else:
            label = threads[0] if threads else "other"
            parts["server other threads"][f"other ({label[:40]})"] += seconds
    return {
        "processes": {k: len(v) for k, v in processes.items()},
        "parts": {
            group: dict(sorted(counter.items(), key=lambda kv: -kv[1]))
            for group, counter in parts.items()
        },
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--duration", type=float, default=40.0)
    p.add_argument("--port", type=int, default=8270)
    p.add_argument("--rate", type=int, default=100, help="py-spy samples per second")
    p.add_argument("--humans", type=int, default=10)
    p.add_argument("--obs-hz", type=float, default=5.0)
    p.add_argument("--planners", type=int, default=2)
    p.add_argument("--check-hz", type=float, default=10.0)
    p.add_argument("--model", type=Path, default=ROOT / "models" / "frt_unicycle.onnx")
    p.add_argument("--src", type=Path, default=ROOT)
    p.add_argument("--env", action="append", default=[])
    p.add_argument("--out", type=Path, default=ROOT / "results" / "profile_load.json")
    args = p.parse_args(argv)
    args.topology, args.replicas, args.workers = "single", 1, None
    if not 0 < args.duration <= 300:
        print("profile_load.py: --duration (0, 300] s", file=sys.stderr)
        return 2
    py_spy = shutil.which("py-spy") or str(Path(sys.executable).parent / "py-spy")
    in_process = mix_set_costs(args.model)
    workdir = Path(tempfile.mkdtemp(prefix="frt-profile-"))
    raw = workdir / "samples.txt"
    try:
        with servers(args, workdir) as (url, own, pids):
            pid = pids[0]
            floor = http_floor(url)
            before = counters(own)
            spy = subprocess.Popen(
                [py_spy, "record", "--pid", str(pid), "--subprocesses", "--threads",
                 "--format", "raw", "--rate", str(args.rate), "--duration",
                 str(int(args.duration)), "--output", str(raw), "--nonblocking"],
                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
            )  # fmt: skip
            time.sleep(1.0)
            load = subprocess.run(
                [sys.executable, str(LOAD), "--url", url, "--duration", str(args.duration - 2),
                 "--planners", str(args.planners), "--humans", str(args.humans),
                 "--obs-hz", str(args.obs_hz), "--check-hz", str(args.check_hz),
                 "--out", str(workdir / "load.json")],
                capture_output=True, text=True, timeout=args.duration + 300,
            )  # fmt: skip
            spy.wait(timeout=120)
            after = counters(own)
        result = breakdown(raw, args.rate)
        loaded = json.loads((workdir / "load.json").read_text())
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    server = {k: after[k] - before[k] for k in after}
    sets = max(server["exact_sets"], 1.0)
    result.update(
        duration_s=args.duration,
        http_floor_p50_ms=floor["p50_ms"],
        per_exact_set_ms={
            "computing (worker)": 1000 * server["exact_seconds"] / sets,
            "queued": 1000 * server["queued_seconds"] / max(server["queued_sets"], 1.0),
            "transfer": 1000 * server["transfer_seconds"] / sets,
        },
        exact_sets=server["exact_sets"],
        in_process_ms=in_process,
        exact_share=loaded["deadline"]["exact_share"],
        load_exit=load.returncode,
        finished_at=time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    )
    print(f"{args.duration:g} s of make load's mix, HTTP floor {floor['p50_ms']:.2f} ms, exact "
          f"share {100 * (result['exact_share'] or 0):.1f} %, {server['exact_sets']:.0f} exact sets")  # fmt: skip
    for group, part in result["parts"].items():
        total = sum(part.values())
        print(f"{group}: {total:.1f} s sampled")
        for name, seconds in part.items():
            print(f"  {name:<42}{seconds:8.2f} s {100 * seconds / max(total, 1e-9):6.1f} %")
    print("per exact set: " + ", ".join(f"{k} {v:.1f} ms" for k, v in result["per_exact_set_ms"].items()))  # fmt: skip
    print("in-process, per set of the mix: " + ", ".join(f"{k} {v:.2f}" for k, v in in_process.items()))  # fmt: skip
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
