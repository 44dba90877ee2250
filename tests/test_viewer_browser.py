"""The viewer in a real browser: headless Chromium over the DevTools Protocol loads ``/viewer``
from a live server fed by a scripted agent.

Ground truth is the API, not the page: the contours come from ``GET /v1/agents/{id}/frt`` and
the test maps world points to pixels itself (the page is told its view: centre and pixels per
metre), so a pixel inside a contour must have the set's colour composited over the background,
and one far outside must be the background. A new observation must move the drawn set, and the
beta plot must follow the API's beta. A second test feeds 50 agents at 2 Hz and prints the
page's frame times; it asserts only that the page caught up with every version.

Skips, saying why, where no Chromium is there and none can be installed
(``scripts/ensure_chromium.sh``: Debian's ``chromium``, as root).
"""

from __future__ import annotations

import importlib.util
import io
import json
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from types import ModuleType

import httpx
import pytest
import shapely
from PIL import Image
from shapely.geometry import Point, mapping, shape
from websockets.sync.client import connect

from tests.conftest import LiveServer
from tests.fixtures.payloads import observation
from tests.test_agent_maps import BOTH as MAP_ASSUMPTIONS
from tests.test_agent_maps import body as map_observation
from tests.test_maps_api import ON_ROAD, RAW

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parent.parent
WIDTH, HEIGHT = 1280, 800


def _load(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(f"frt_{name}", ROOT / "scripts" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


chromium = _load("headless_chromium")


@pytest.fixture(scope="module")
def browser_binary() -> str:
    try:
        return chromium.find_chromium(install=True)
    except chromium.BrowserError as exc:
        pytest.skip(f"no headless Chromium for the browser tests: {exc}")


@pytest.fixture(scope="module")
def server(start_server: Callable[..., LiveServer]) -> LiveServer:
    """A server of its own: the page shows every agent, so none of the other tests' agents."""
    return start_server()


@pytest.fixture
def page(browser_binary: str, server: LiveServer) -> Iterator[chromium.Page]:
    with chromium.launch(browser_binary, WIDTH, HEIGHT) as page:
        page.navigate(f"{server.url}/viewer")
        page.wait_for("window.frtViewer && window.frtViewer.snapshot().connected")
        yield page
        assert page.errors == [], page.errors


def snapshot(page: chromium.Page) -> dict:
    return page.evaluate("window.frtViewer.snapshot()")


def next_frame(page: chromium.Page) -> None:
    """Wait until the page has drawn a frame after this call (what was set is on the canvas)."""
    page.evaluate(
        "new Promise(r => requestAnimationFrame(() => requestAnimationFrame(() => r(true))))"
    )


def pixels(page: chromium.Page) -> Image.Image:
    image = Image.open(io.BytesIO(page.screenshot())).convert("RGB")
    assert image.size == (WIDTH, HEIGHT)
    return image


class View:
    """The view the page is told to use: world (cx, cy) at the map's centre, s pixels per metre."""

    def __init__(self, page: chromium.Page, cx: float, cy: float, s: float) -> None:
        self.cx, self.cy, self.s = cx, cy, s
        page.evaluate(f"window.frtViewer.setView({cx}, {cy}, {s})")
        self.width, self.height = snapshot(page)["size"]

    def world(self, px: float, py: float) -> tuple[float, float]:
        return self.cx + (px - self.width / 2) / self.s, self.cy - (py - self.height / 2) / self.s

    def pixel(self, x: float, y: float) -> tuple[int, int]:
        px = self.width / 2 + (x - self.cx) * self.s
        py = self.height / 2 - (y - self.cy) * self.s
        assert 0 <= px < self.width and 0 <= py < self.height, (x, y)
        return int(px), int(py)


def rgb(hex_colour: str) -> tuple[int, int, int]:
    h = hex_colour.lstrip("#")
    return int(h[0:2], 16), int(h[2:4], 16), int(h[4:6], 16)


def over(below: tuple[float, ...], colour: tuple[int, ...], alpha: float) -> tuple[float, ...]:
    return tuple(b * (1 - alpha) + c * alpha for b, c in zip(below, colour, strict=True))


def assert_colour(image: Image.Image, xy: tuple[int, int], want: tuple[float, ...]) -> None:
    got = image.getpixel(xy)
    assert max(abs(g - w) for g, w in zip(got, want, strict=True)) <= 4, (xy, got, want)


def observe(http: httpx.Client, agent: str, body: dict) -> dict:
    r = http.post(f"/v1/agents/{agent}/observations", params={"wait_frt_ms": 5000}, json=body)
    assert r.status_code == 200, r.text
    return r.json()


def contours(http: httpx.Client, agent: str, slices: list[float]) -> dict:
    query = {"include": "K,C", "slices": ",".join(f"{t:g}" for t in slices)}
    r = http.get(f"/v1/agents/{agent}/frt", params=query)
    assert r.status_code == 200, r.text
    return r.json()


def wait_drawn(page: chromium.Page, agent: str, version: int, timeout_s: float = 15.0) -> dict:
    page.wait_for(
        f"(window.frtViewer.snapshot().agents[{json.dumps(agent)}] || {{}}).drawnVersion"
        f" >= {version}",
        timeout_s,
    )
    return snapshot(page)["agents"][agent]


def inside_point(geometry: dict, avoid: tuple[float, float], margin_m: float) -> Point:
    """A point at least ``margin_m`` inside ``geometry`` and 3 m or more from ``avoid`` (the
    agent's marker), found on a grid over the shape (from the API's GeoJSON, by shapely)."""
    inner = shape(geometry).buffer(-margin_m)
    x0, y0, x1, y1 = inner.bounds
    for i in range(41):
        for j in range(41):
            p = Point(x0 + (x1 - x0) * (i / 40), y0 + (y1 - y0) * (j / 40))
            if inner.contains(p) and p.distance(Point(avoid)) >= 3.0:
                return p
    raise AssertionError("no interior point away from the marker")


def test_the_set_is_drawn_where_the_api_says_and_follows_new_observations(
    page: chromium.Page, server: LiveServer
) -> None:
    agent = "viewer-scripted"
    x0, y0 = 100.0, -40.0
    with httpx.Client(base_url=server.url, timeout=20.0) as http:
        first = observe(http, agent, observation(1.0, x=x0, y=y0, speed=5.0))
        page.evaluate(f"window.frtViewer.select({json.dumps(agent)})")
        drawn = wait_drawn(page, agent, first["frt_version"])
        assert drawn["state"]["x"] == x0 and drawn["conservative"] is False
        page.evaluate("window.frtViewer.setOptions({showSlice: false, showGrid: false})")
        view = View(page, cx=x0 + 22.0, cy=y0, s=12.0)
        style = page.evaluate("window.frtViewer.style")
        colour = rgb(drawn["colour"])
        assert drawn["cls"] == "car" and drawn["colour"] == style["classColours"]["car"]
        background = rgb(style["background"])
        in_k = over(over(background, colour, style["tubeC"]), colour, style["tubeK"])

        slices = snapshot(page)["slices"]
        sets = contours(http, agent, slices)
        tube_k, tube_c = shape(sets["tube"]["K"]), shape(sets["tube"]["C"])
        p = inside_point(sets["tube"]["K"], (x0, y0), margin_m=0.6)
        far = Point(x0 - 10.0, y0 + 25.0)
        assert far.distance(tube_c) > 5.0
        next_frame(page)
        image = pixels(page)
        assert_colour(image, view.pixel(p.x, p.y), in_k)
        assert_colour(image, view.pixel(far.x, far.y), background)

        # The slider's slice: its K has the slice's colour, the tube outside it does not.
        i = 3
        t = slices[i]
        slice_k = shape(next(s for s in sets["slices"] if abs(s["t"] - t) < 1e-9)["K"])
        slice_c = shape(next(s for s in sets["slices"] if abs(s["t"] - t) < 1e-9)["C"])
        show = f"{{showTube: false, showSlice: true, sliceIndex: {i}}}"
        page.evaluate(f"window.frtViewer.setOptions({show})")
        page.wait_for(
            f"window.frtViewer.snapshot().agents[{json.dumps(agent)}].contoursSlice === {t}"
        )
        q = inside_point(mapping_of(slice_k), (x0, y0), margin_m=0.4)
        rest = mapping_of(tube_k.difference(slice_c.buffer(1.0)))
        outside_slice = inside_point(rest, (x0, y0), margin_m=0.3)
        next_frame(page)
        image = pixels(page)
        assert_colour(image, view.pixel(q.x, q.y), over(background, colour, style["sliceK"]))
        assert_colour(image, view.pixel(outside_slice.x, outside_slice.y), background)

        # A new observation 30 m on: the set moves there, the old place is empty, beta is plotted.
        page.evaluate("window.frtViewer.setOptions({showTube: true, showSlice: false})")
        assert snapshot(page)["plot"]["points"] == 1
        x1, y1 = x0 + 30.0, y0 + 5.0
        second = observe(http, agent, observation(1.5, x=x1, y=y1, speed=5.0, action=(1.5, -8.0)))
        assert second["frt_version"] > first["frt_version"] and second["action_scored"]
        wait_drawn(page, agent, second["frt_version"])
        moved = contours(http, agent, slices)
        p1 = inside_point(moved["tube"]["K"], (x1, y1), margin_m=0.6)
        assert p.distance(shape(moved["tube"]["C"])) > 1.0  # the old point is outside the new C
        next_frame(page)
        image = pixels(page)
        assert_colour(image, view.pixel(p1.x, p1.y), in_k)
        assert_colour(image, view.pixel(p.x, p.y), background)
        plot = page.wait_for(
            "(s => s.plot.points === 2 && s.plot)(window.frtViewer.snapshot())", timeout_s=5.0
        )
        assert plot["beta"] == pytest.approx(second["beta"], abs=1e-12)
        assert second["beta"] < first["beta"]  # the wild action lowered it: the plot shows that

        # A planner's check through the agent is listed to the page with its answer.
        path = [{"t": 1.6 + 0.05 * k, "x": x1 + 5.0, "y": y1 + 20.0 - k} for k in range(41)]
        r = http.post(f"/v1/agents/{agent}/collision-check", json={"trajectory": path})
        assert r.status_code == 200 and r.json()["collision"] is True
        checks = page.wait_for(
            "(s => s.checks.length > 0 && s.checks)(window.frtViewer.snapshot())", timeout_s=5.0
        )
        assert checks[0]["points"] == 41 and checks[0]["collision"] is True
        http.delete(f"/v1/agents/{agent}")


def mapping_of(geometry: object) -> dict:
    return dict(mapping(geometry))


MAP = "viewer-austin"


def changed(before: Image.Image, after: Image.Image, xy: tuple[int, int]) -> bool:
    """Whether any pixel of the 3 x 3 around ``xy`` differs between the two images."""
    x, y = xy
    return any(
        max(
            abs(a - b) for a, b in zip(before.getpixel((i, j)), after.getpixel((i, j)), strict=True)
        )
        > 30
        for i in range(x - 1, x + 2)
        for j in range(y - 1, y + 2)
    )


def test_the_map_is_drawn_under_the_sets_and_the_uncut_outline_beside_them(
    page: chromium.Page, server: LiveServer
) -> None:
    """A car named with the shipped map: the road is drawn where the map's GeoJSON puts it, read
    once for the view and not per frame; with the uncut set on, its outline appears beside the
    cut set where the API's uncut C leaves the cut one."""
    agent = "viewer-map-car"
    with httpx.Client(base_url=server.url, timeout=20.0) as http:
        r = http.put(f"/v1/maps/{MAP}", content=RAW, headers={"content-type": "application/json"})
        assert r.status_code == 200, r.text
        first = observe(http, agent, map_observation(1.0, ON_ROAD, map_id=MAP))
        page.evaluate("window.frtViewer.setOptions({showSlice: false, showGrid: false})")
        drawn = wait_drawn(page, agent, first["frt_version"])
        assert drawn["mapId"] == MAP and drawn["assumptions"] == MAP_ASSUMPTIONS
        view = View(page, cx=ON_ROAD["x"], cy=ON_ROAD["y"] + 10.0, s=12.0)
        page.wait_for(
            f"(m => m && m.drawable && !m.fetching)(window.frtViewer.snapshot().maps['{MAP}'])"
        )
        next_frame(page)
        shown = snapshot(page)
        assert shown["mapsDrawn"] == 1 and shown["maps"][MAP]["features"] > 0
        style = page.evaluate("window.frtViewer.style")
        background, road = rgb(style["background"]), rgb(style["mapFill"])

        # Where the map's GeoJSON (read by the test) has road clear of lane lines and of the
        # car's uncut C, the pixel is the road's fill; off the road and clear of C, background.
        sets = http.get(f"/v1/agents/{agent}/frt", params={"include_uncut": "true"}).json()
        cut_c, uncut_c = shape(sets["tube"]["C"]), shape(sets["uncut"]["tube"]["C"])
        seen = shapely.box(*view.world(8, view.height - 8), *view.world(view.width - 8, 8))
        bbox = ",".join(f"{v:.2f}" for v in seen.bounds)
        geo = http.get(f"/v1/maps/{MAP}/geojson", params={"bbox": bbox, "simplify_m": 0}).json()
        kinds = {k: [shape(f["geometry"]) for f in geo["features"] if f["properties"]["kind"] == k]
                 for k in ("drivable_area", "lane", "centerline")}  # fmt: skip
        d = shapely.union_all(kinds["drivable_area"])
        lines = shapely.union_all([p.boundary for p in kinds["lane"]] + kinds["centerline"])
        clear = uncut_c.buffer(1.0).union(Point(ON_ROAD["x"], ON_ROAD["y"]).buffer(3.0))
        on_road = d.buffer(-0.5).difference(lines.buffer(0.5)).difference(clear)
        off_road = seen.buffer(-2.0).difference(d.buffer(1.0)).difference(clear)
        assert on_road.area > 5.0 and off_road.area > 5.0
        image = pixels(page)
        for region, want in ((on_road, road), (off_road, background)):
            p = inside_point(mapping_of(region), (ON_ROAD["x"], ON_ROAD["y"]), margin_m=0.2)
            assert_colour(image, view.pixel(p.x, p.y), want)

        # Redrawing does not read the map again: it is read per view, not per frame.
        fetches = snapshot(page)["stats"]["mapFetches"]
        for colour in ("beta", "class", "beta", "class"):
            page.evaluate(f"window.frtViewer.setOptions({{colour: '{colour}'}})")
            next_frame(page)
        assert snapshot(page)["stats"]["mapFetches"] == fetches

        # The uncut outline: drawn along the uncut C where it runs clear of the cut set.
        page.evaluate("window.frtViewer.setOptions({showUncut: true})")
        page.wait_for(f"window.frtViewer.snapshot().agents['{agent}'].uncut")
        next_frame(page)
        with_uncut = pixels(page)
        assert uncut_c.area > 1.2 * cut_c.area
        edge = uncut_c.exterior if uncut_c.geom_type == "Polygon" else uncut_c.boundary
        far = [edge.interpolate(k / 200, normalized=True) for k in range(200)]
        far = [q for q in far if q.distance(cut_c) > 1.0 and seen.buffer(-1.0).contains(q)]
        assert len(far) > 20
        hits = [changed(image, with_uncut, view.pixel(q.x, q.y)) for q in far]
        assert sum(hits) > 0.7 * len(hits), (sum(hits), len(hits))
        inside = inside_point(sets["tube"]["K"], (ON_ROAD["x"], ON_ROAD["y"]), margin_m=0.6)
        assert not changed(image, with_uncut, view.pixel(inside.x, inside.y))
        page.evaluate("window.frtViewer.setOptions({showUncut: false, showGrid: true})")

        http.delete(f"/v1/agents/{agent}")
        page.wait_for("window.frtViewer.snapshot().mapsDrawn === 0")
        http.delete(f"/v1/maps/{MAP}")


AGENTS = 50
RATE_HZ = 2.0
FEED_S = 10.0


def feed(ws_url: str, stop: threading.Event, rounds: list[int]) -> None:
    """50 agents in rows, 5 m/s along +x, each observed at 2 Hz, over one WebSocket."""
    with connect(f"{ws_url}/v1/stream") as ws:
        k = 0
        start = time.monotonic()
        while not stop.is_set():
            t = 1.0 + k / RATE_HZ
            for i in range(AGENTS):
                x = 12.0 * (i % 10) + 5.0 * (t - 1.0)
                y = 15.0 * (i // 10)
                action = None if k == 0 else (0.0, 0.0)
                body = observation(t, x=x, y=y, speed=5.0, action=action)
                ws.send(
                    json.dumps({"id": i, "op": "observe", "agent_id": f"fleet-{i:02d}", **body})
                )
            for _ in range(AGENTS):
                answer = json.loads(ws.recv(timeout=30))
                assert answer["ok"], answer
            k += 1
            rounds.append(k)
            stop.wait(max(0.0, start + k / RATE_HZ - time.monotonic()))


def test_fifty_agents_at_two_hertz_keep_up(page: chromium.Page, server: LiveServer) -> None:
    page.evaluate("window.frtViewer.resetStats()")
    stop = threading.Event()
    rounds: list[int] = []
    feeder = threading.Thread(target=feed, args=(server.ws_url, stop, rounds), daemon=True)
    feeder.start()
    time.sleep(FEED_S)
    during = snapshot(page)
    stop.set()
    feeder.join(timeout=30)
    assert not feeder.is_alive() and rounds, "the feeder stopped early"
    fleet = [f"fleet-{i:02d}" for i in range(AGENTS)]
    with httpx.Client(base_url=server.url, timeout=20.0) as http:
        latest = {a: http.get(f"/v1/agents/{a}").json()["frt_version"] for a in fleet}
        # Did not fall behind: every agent's latest version is drawn soon after the feed stops.
        deadline = time.monotonic() + 10.0
        while True:
            agents = snapshot(page)["agents"]
            behind = {a: latest[a] - agents.get(a, {}).get("drawnVersion", 0) for a in fleet}
            if all(b <= 0 for b in behind.values()) or time.monotonic() > deadline:
                break
            time.sleep(0.1)
        after = snapshot(page)
        stats = after["stats"]
        print(
            f"\nviewer, {AGENTS} agents at {RATE_HZ:g} Hz for {FEED_S:g} s ({len(rounds)} rounds):"
            f" draw p50 {stats['drawMsP50']:.2f} ms, p95 {stats['drawMsP95']:.2f} ms,"
            f" max {stats['drawMsMax']:.2f} ms over {stats['drawSamples']} frames;"
            f" frame interval p50 {stats['frameIntervalMsP50']:.1f} ms;"
            f" poll p50 {stats['pollMsP50']:.1f} ms; contour fetches {stats['fetches']};"
            f" versions not yet drawn at most {stats['maxLag']} in all"
            f" ({stats['maxLag'] / AGENTS:.2f} per agent, mid-run {during['stats']['lag']}),"
            f" the stalest agent at most {stats['maxWorstAgentLag']} behind"
        )
        assert len(after["agents"]) >= AGENTS
        assert all(b <= 0 for b in behind.values()), behind
        assert stats["fetchErrors"] == 0
        # Generous: no agent's drawn set ever more than 12 versions (6 s at 2 Hz) old.
        assert stats["maxWorstAgentLag"] <= 12, stats
        for agent in fleet:
            http.delete(f"/v1/agents/{agent}")
