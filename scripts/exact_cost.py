"""What one exact set of `make load`'s mix costs in-process: the set, its tubes, its transfer.

The ten humans of ``scripts/load.py`` (their first predictions, beta 0.5), each set computed as a
worker computes it (``service.runtime.exact_worker.ExactTask``): alone, and with the tubes the
mix's time-indexed checks need (``LOAD_MIX_TUBES``); then pickled and unpickled, and written and
read as bytes as the pipe pool sends them (``reach.set_bytes``; a checkout without it reports
pickling only). Medians per set over ``--repeats`` passes.

``--cases`` also times ``make bench``'s in-process cases (``scripts/bench.py``'s ``EXACT_CASES``:
a moving, a parked and a wide car, each as the service's engine builds it), each the median of
``--repeats`` x 10 sets. ``--src DIR`` imports the project from another checkout (e.g. an older
commit exported with ``git archive``) for side-by-side figures on one machine: run it once per
checkout, alternately; ``--json`` prints one JSON object per run.

    python scripts/exact_cost.py --cases
    python scripts/exact_cost.py --cases --src /tmp/base
"""

from __future__ import annotations

import argparse
import json
import pickle
import random
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

#: The tubes a worker draws for make load's checks: 20 points 0.1 s apart, starting up to ~0.2 s
#: after the agent's observation, reach tube 21 (``service.runtime.tube_demand``).
LOAD_MIX_TUBES = 21


def mix_set_costs(model: Path, repeats: int = 5, as_bytes: bool = True) -> dict[str, float]:
    """Median ms per set: the exact set alone, with the tubes checks need, pickling and
    unpickling it, writing and reading its bytes (``as_bytes``); and its sizes in kB."""
    from reach.frames import Pose
    from scripts.fallback_cost import served_engine
    from scripts.load import make_humans
    from service.flows.bounds import control_bounds, validate_prediction
    from service.runtime.exact_worker import ExactTask
    from service.runtime.settings import Settings

    engine = served_engine(model)
    settings = Settings()
    plain, with_tubes = [], []
    for human in make_humans(10, "cost", 20.0, random.Random(0)):
        p = human.prediction(0.0)
        mean, cov = validate_prediction(p["mean"], p["cov"], p["dt"], 64)
        bounds = control_bounds(
            mean,
            cov,
            p["dt"],
            0.5,
            settings.gamma,
            horizon=settings.horizon_s,
            method=settings.bounds_fit,
            limits=(settings.u1_limit, settings.u2_limit),
        ).as_array()
        pose = Pose(human.x, human.y, human.heading)
        plain.append(ExactTask(pose, human.speed, bounds, engine))
        with_tubes.append(ExactTask(pose, human.speed, bounds, engine, tubes_upto=LOAD_MIX_TUBES))

    def per_set(work: Callable[[], object], count: int) -> float:
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            work()
            times.append((time.perf_counter() - start) / count * 1000.0)
        return statistics.median(times)

    sets = [task() for task in with_tubes]
    blobs = [pickle.dumps(frt, 4) for frt in sets]
    alone = per_set(lambda: [task() for task in plain], len(plain))
    full = per_set(lambda: [task() for task in with_tubes], len(with_tubes))
    costs = {
        "exact set alone": alone,
        "with the tubes checks need": full,
        "of which the tubes": full - alone,
        "pickling": per_set(lambda: [pickle.dumps(frt, 4) for frt in sets], len(sets)),
        "unpickling": per_set(lambda: [pickle.loads(b) for b in blobs], len(blobs)),
        "kB": sum(map(len, blobs)) / len(blobs) / 1000.0,
    }
    if not as_bytes:
        return costs
    from reach.set_bytes import set_from_bytes, set_to_bytes

    written = [set_to_bytes(frt) for frt in sets]
    costs.update(
        {
            "writing bytes": per_set(lambda: [set_to_bytes(frt) for frt in sets], len(sets)),
            "reading bytes": per_set(lambda: [set_from_bytes(b) for b in written], len(written)),
            "bytes kB": sum(map(len, written)) / len(written) / 1000.0,
        }
    )
    return costs


def case_costs(model: Path, repeats: int = 5) -> dict[str, float]:
    """Median ms of each of ``make bench``'s in-process exact-set cases (the moving car also with
    the load mix's tubes), as the service's engine builds them."""
    import numpy as np

    from reach.frames import Pose
    from scripts.bench import EXACT_CASES
    from scripts.fallback_cost import served_engine

    engine = served_engine(model)
    costs = {}
    for name, (v_start, bounds) in EXACT_CASES.items():
        tubes = [-1, LOAD_MIX_TUBES] if "moving" in name else [-1]
        for upto in tubes:
            key = name.removeprefix("exact_set_in_process_") + ("" if upto < 0 else "_with_tubes")
            times = []
            for i in range(repeats * 10 + 2):  # two to warm up
                start = time.perf_counter()
                engine.exact(Pose(0.0, 0.0, 0.0), v_start, np.array(bounds), tubes_upto=upto)
                if i >= 2:
                    times.append((time.perf_counter() - start) * 1000.0)
            costs[key] = statistics.median(times)
    return costs


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--src", type=Path, default=ROOT, help="the project checkout to import")
    p.add_argument("--model", type=Path, default=ROOT / "models" / "frt_unicycle.onnx")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--cases", action="store_true", help="also make bench's in-process cases")
    p.add_argument("--json", action="store_true", help="one JSON object")
    args = p.parse_args(argv)
    sys.path.insert(0, str(args.src.resolve()))
    # (A checkout from before the binary layout has no reach/set_bytes.py: the installed
    # project's would be imported in its place.)
    as_bytes = (args.src / "reach" / "set_bytes.py").exists()
    costs = mix_set_costs(args.model, args.repeats, as_bytes)
    if args.cases:
        costs.update(case_costs(args.model, args.repeats))
    if args.json:
        print(json.dumps({"src": str(args.src), **costs}))
    else:
        print(f"{args.src}: " + ", ".join(f"{k} {v:.2f}" for k, v in costs.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
