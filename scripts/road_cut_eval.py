"""Sets cut by the road on recorded traffic: ``python scripts/road_cut_eval.py``.

Data: the Argoverse 2 scenario in ``data/av2/`` and its map archive, © Argo AI, LLC, licensed
under CC BY-NC-SA 4.0 (https://creativecommons.org/licenses/by-nc-sa/4.0/); see
``data/av2/NOTICE.md``. The figures derived from it carry the same licence.

Method: the Argoverse 2 replay's (``experiments.av2``): every vehicle track of at least 4 s is
observed every 0.5 s while 3 s of future remain; the predictor is constant velocity and turn rate,
Gaussian, its diagonal covariance cross-fitted on the other fold of tracks. Each observation goes
through the real service in-process (``POST /v1/frt``, the shipped model, the map registered from
``FRT_MAP``), with confidence off (beta = 1) at each gamma of ``--gammas``, twice: without a map,
and with ``map_id`` (the set cut to the drivable area grown by each margin of ``--margins``,
``FRT_MAP_MARGIN_M``, while the car is on it), and a third time cut to the drivable area and the
lanes it can reach (``reach.road_cut.lane_cut``, start lanes within ``--heading-tolerance`` of its
heading; to the drivable area alone where the lane assumption does not apply). The three come
from the same exact set (uncut by the notch refinement, which is off here, so they differ by the
road cut alone); the third is cut in-process from the set the service answered from (the service
does not serve the lane assumption). For each, the actual positions of the next 3 s (30 points)
are checked with ``collision_radius`` 0, so a clearance is the signed distance to K:

- coverage: the share of those positions inside C = K ⊕ 1.5 m, at each position's time (the tube
  up to it, as the calibration and the audit score) and in the whole-horizon C;
- area: the area of the whole-horizon C (K ⊕ 1.5 m, as the contours draw it).

Moving vehicles are those observed at 1 m/s or more. Prints a table and writes
``results/road_cut.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from fastapi.testclient import TestClient
from shapely.geometry import shape

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from experiments import av2  # noqa: E402
from reach.dynamics import wrap_angle  # noqa: E402
from reach.frames import Pose  # noqa: E402
from reach.lanes import HEADING_TOLERANCE, REACHABLE_LANES  # noqa: E402
from reach.road_cut import CutSet, lane_cut  # noqa: E402
from reach.sets import FRTSet  # noqa: E402
from service.api.app import create_app  # noqa: E402
from service.flows.stateless import request_bounds  # noqa: E402
from service.runtime.jobs import FRTJob  # noqa: E402
from service.runtime.settings import Settings  # noqa: E402
from service.wire.schemas import FRTRequest  # noqa: E402

COLLISION_RADIUS_M = 1.5
MOVING_MPS = 1.0
MAP_ID = "av2"
OUT = ROOT / "results" / "road_cut.json"


def service(margin: float) -> TestClient:
    """The service in-process with the shipped model and the scenario's map as ``MAP_ID``."""
    settings = Settings(
        map=av2.DATA_DIR / av2.MAP_FILE,
        map_id=MAP_ID,
        map_margin_m=margin,
        frt_executor="thread",
        frt_workers=1,
        frt_notch_cut=False,
        log_requests=False,
    )
    return TestClient(create_app(settings))


def wait_ready(client: TestClient) -> None:
    deadline = time.monotonic() + 300.0
    while client.get("/readyz").status_code != 200:
        if time.monotonic() > deadline:
            raise TimeoutError(client.get("/readyz").text)
        time.sleep(0.1)


def observations(tracks: list[av2.Track], v_max: float) -> list[dict[str, Any]]:
    """Every observation of the replay: its request fields and its actual future."""
    fold_a, fold_b = av2.folds(tracks)
    sigma_a, sigma_b = av2.fit_sigma(fold_a), av2.fit_sigma(fold_b)
    sigma_for = {t.track_id: sigma_b for t in fold_a} | {t.track_id: sigma_a for t in fold_b}
    out = []
    for track in tracks:
        for i in track.observation_indices():
            if not 0.0 <= track.speed[i] <= v_max:
                continue
            j = slice(i + 1, i + av2.HORIZON_SAMPLES + 1)
            out.append({
                "track_id": track.track_id,
                "timestamp": float(track.t[i]),
                "state": {"x": float(track.x[i]), "y": float(track.y[i]),
                          "heading": float(wrap_angle(track.heading[i])),
                          "speed": float(track.speed[i])},
                "prediction": av2.prediction(av2.cvtr_mean(track, i), sigma_for[track.track_id]),
                "future": [{"t": float(t), "x": float(x), "y": float(y)}
                           for t, x, y in zip(track.t[j], track.x[j], track.y[j], strict=True)],
            })  # fmt: skip
    return out


def measure(client: TestClient, obs: dict[str, Any], gamma: float, map_id: str | None) -> dict:
    """Coverage of the observation's future and area of C, from one set (with or without map)."""
    body: dict[str, Any] = {
        "timestamp": obs["timestamp"], "state": obs["state"], "prediction": obs["prediction"],
        "beta": 1.0, "gamma": gamma, "collision_radius": 0.0, "trajectory": obs["future"],
    }  # fmt: skip
    if map_id is not None:  # the drivable area alone; the lanes are cut in-process below
        body["map_id"] = map_id
        body["assumptions"] = ["drivable_area"]
    tube = _post(client, {**body, "mode": "tube", "contours": {"include": ["K"]}})
    timed = _post(client, {**body, "mode": "time_indexed"})
    return figures(
        np.asarray(tube["collision"]["clearance"]),
        np.asarray(timed["collision"]["clearance"]),
        shape(tube["contours"]["tube"]["K"]),
        tube["assumptions"],
        bool(tube["conservative"] or timed["conservative"]),
    )


def figures(
    d_tube: np.ndarray, d_time: np.ndarray, k_set: Any, assumptions: list[str], conservative: bool
) -> dict:
    """One observation's coverage (from the future positions' clearances over the whole tube and
    at their times) and area of K and C."""
    return {
        "in_c": float(np.mean(d_tube <= COLLISION_RADIUS_M)),
        "in_c_time": float(np.mean(d_time <= COLLISION_RADIUS_M)),
        "in_k_time": float(np.mean(d_time <= 0.0)),
        "area_c": float(k_set.buffer(COLLISION_RADIUS_M, quad_segs=8).area),
        "area_k": float(k_set.area),
        "assumptions": assumptions,
        "conservative": conservative,
    }


def measure_lanes(
    client: TestClient, obs: dict[str, Any], gamma: float, margin: float, tolerance: float
) -> dict:
    """As :func:`measure`, from the set the service answered ``obs`` from (after its POSTs), cut
    to the drivable area and the reachable lanes (``reach.road_cut.lane_cut``), to the drivable
    area alone where the lane assumption does not apply, uncut off the drivable area."""
    services = client.app.state.services  # type: ignore[attr-defined]
    road = services.maps.require(MAP_ID).road
    body = {"timestamp": obs["timestamp"], "state": obs["state"],
            "prediction": obs["prediction"], "beta": 1.0, "gamma": gamma}  # fmt: skip
    bounds = request_bounds(services, FRTRequest.model_validate(body))
    state = obs["state"]
    pose = Pose(state["x"], state["y"], state["heading"])
    job = FRTJob.make("", 0, pose, state["speed"], bounds)
    frt: FRTSet | None = services.cached_exact([job])[0]
    conservative = frt is None
    if frt is None:
        frt = services.conservative(job)
    assumptions: list[str] = []
    if road.on_road(pose.x, pose.y, margin):
        cut = lane_cut(frt, road, margin, tolerance=tolerance)
        frt = cut if cut is not None else CutSet(frt, road, margin)
        assumptions = list(frt.assumptions)
    xy = np.array([[p["x"], p["y"]] for p in obs["future"]])
    t_rel = np.array([p["t"] for p in obs["future"]]) - obs["timestamp"]
    k_set = shape(frt.geojson("tube", None, 0.0)["K"])
    return figures(frt.clearance(xy), frt.clearance(xy, t_rel), k_set, assumptions, conservative)


def _post(client: TestClient, body: dict[str, Any]) -> dict[str, Any]:
    r = client.post("/v1/frt", json=body)
    if r.status_code != 200:
        raise RuntimeError(f"POST /v1/frt: {r.status_code} {r.text}")
    return r.json()  # type: ignore[no-any-return]


def summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Means over rows (each observation's 30 positions weigh the same)."""
    if not rows:
        return {"observations": 0}

    def mean(key: str) -> float:
        return float(np.mean([r[key] for r in rows]))

    return {
        "observations": len(rows),
        "positions": len(rows) * av2.HORIZON_SAMPLES,
        "coverage_c_time_indexed": round(mean("in_c_time"), 5),
        "coverage_c_tube": round(mean("in_c"), 5),
        "coverage_k_time_indexed": round(mean("in_k_time"), 5),
        "mean_area_c_m2": round(mean("area_c"), 2),
        "mean_area_k_m2": round(mean("area_k"), 2),
        "cut": sum("drivable_area" in r["assumptions"] for r in rows),
        "lanes": sum(REACHABLE_LANES in r["assumptions"] for r in rows),
        "conservative": sum(r["conservative"] for r in rows),
    }


def run(
    client: TestClient, obs: list[dict[str, Any]], gamma: float, margin: float, tolerance: float
) -> dict:
    """Every observation with and without the map at ``gamma``: the summaries of all vehicles, of
    the moving ones, and of the moving ones observed inside the map's extent."""
    x0, y0, x1, y1 = client.get(f"/v1/maps/{MAP_ID}").json()["extent"]
    groups = {
        "all": lambda r: True,
        "moving": lambda r: r["speed"] >= MOVING_MPS,
        "moving_in_extent": lambda r: (
            r["speed"] >= MOVING_MPS and x0 <= r["x"] <= x1 and y0 <= r["y"] <= y1
        ),
    }
    rows: dict[str, list[dict[str, Any]]] = {name: [] for name in VARIANTS}
    for o in obs:
        found = {
            "without_map": measure(client, o, gamma, None),
            "with_map": measure(client, o, gamma, MAP_ID),
            "with_lanes": measure_lanes(client, o, gamma, margin, tolerance),
        }
        for name, row in found.items():
            state = o["state"]
            row.update(track_id=o["track_id"], t=o["timestamp"], speed=state["speed"])
            row.update(x=state["x"], y=state["y"])
            rows[name].append(row)
    out: dict[str, Any] = {"margin_m": margin, "gamma": gamma, "beta": 1.0,
                           "heading_tolerance_deg": round(math.degrees(tolerance), 3)}  # fmt: skip
    for group, keep in groups.items():
        out[group] = {name: summary([r for r in rs if keep(r)]) for name, rs in rows.items()}
        without = out[group]["without_map"]
        for name in ("with_map", "with_lanes"):
            cut = out[group][name]
            suffix = "" if name == "with_map" else "_lanes"
            out[group]["area_c_change" + suffix] = round(
                cut["mean_area_c_m2"] / without["mean_area_c_m2"] - 1.0, 4
            )
            out[group]["coverage_c_change_points" + suffix] = round(
                100.0 * (cut["coverage_c_time_indexed"] - without["coverage_c_time_indexed"]), 3
            )
    return out


#: Each observation's answers: uncut, cut to the drivable area, cut to it and the lanes.
VARIANTS = ("without_map", "with_map", "with_lanes")


GROUPS = {
    "moving": f"Moving vehicles (>= {MOVING_MPS:g} m/s)",
    "moving_in_extent": "Moving vehicles observed inside the map's extent",
}


def table(results: list[dict[str, Any]], group: str = "moving") -> str:
    lines = [
        f"{GROUPS[group]}, confidence off (beta = 1); coverage: actual positions of the next 3 s "
        "inside C at their time (in the whole-horizon C)",
        "",
        "| margin (m) | γ | assumptions | observations (lanes apply) | coverage "
        "| change (points) | mean area of C (m²) | change |",
        "| ---: | ---: | --- | ---: | ---: | ---: | ---: | ---: |",
    ]
    labels = {"without_map": "none", "with_map": "drivable_area",
              "with_lanes": "drivable_area, reachable_lanes"}  # fmt: skip
    for r in results:
        m = r[group]
        for name in VARIANTS:
            a = m[name]
            suffix = "_lanes" if name == "with_lanes" else ""
            change = (
                ("—", "—")
                if name == "without_map"
                else (f"{m['coverage_c_change_points' + suffix]:+.2f}",
                      f"{m['area_c_change' + suffix]:+.1%}")
            )  # fmt: skip
            count = f"{a['observations']}" + (f" ({a['lanes']})" if suffix else "")
            lines.append(
                f"| {r['margin_m']:g} | {r['gamma']:g} | {labels[name]} | {count} "
                f"| {a['coverage_c_time_indexed']:.2%} ({a['coverage_c_tube']:.2%}) "
                f"| {change[0]} | {a['mean_area_c_m2']:.1f} | {change[1]} |"
            )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--gammas", default="0.075,0.8,0.99", help="comma-separated")
    parser.add_argument(
        "--margins", default="1,0.5,0", help="FRT_MAP_MARGIN_M (m), comma-separated"
    )
    parser.add_argument(
        "--heading-tolerance",
        type=float,
        default=math.degrees(HEADING_TOLERANCE),
        help="degrees: a lane holding the car is a start lane within this of its heading",
    )
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args()
    gammas = [float(g) for g in args.gammas.split(",")]
    results = []
    for margin in (float(m) for m in args.margins.split(",")):
        with service(margin) as client:
            wait_ready(client)
            ranges = client.get("/v1/model").json()["ranges"]
            obs = observations(av2.load_tracks(), float(ranges.get("v_start", [0, math.inf])[1]))
            tolerance = math.radians(args.heading_tolerance)
            results += [run(client, obs, gamma, margin, tolerance) for gamma in gammas]
    tables = [table(results, group) for group in GROUPS]
    print("\n\n".join(tables))
    args.out.write_text(json.dumps({
        "attribution": av2.ATTRIBUTION,
        "licence": "CC BY-NC-SA 4.0 (derived data carries the same licence; non-commercial use)",
        "licence_url": av2.LICENCE_URL,
        "scenario": av2.SCENARIO_ID,
        "command": " ".join(["python scripts/road_cut_eval.py", *sys.argv[1:]]),
        "settings": {"collision_radius_m": COLLISION_RADIUS_M, "moving_mps": MOVING_MPS,
                     "notch_cut": False, "beta": 1.0},
        "tables": tables,
        "results": results,
    }, indent=1) + "\n")  # fmt: skip
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
