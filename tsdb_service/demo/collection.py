"""The request collection: one Python definition, three ways to use it.

Each ``Query`` names a request people really make against the demo data
(QuantumLeap's classic "first N / latest N / aggregate over a period", geo
queries, and one or more per use case), with the checks its answer must
pass. From this single list come:

* ``queries/tsdb-service.postman_collection.json`` (Postman v2.1; each
  request carries the same checks as a test script),
* ``queries/tsdb-service.http`` (VS Code REST Client / JetBrains HTTP Client),
* ``tsdb-service queries run`` and the curl lines the demo prints.

Checks address the JSON answer with dotted paths: ``*`` walks every element
of a list, ``a|b`` takes the first key present (QuantumLeap versions differ
between ``entityId`` and ``id``), and a list at the end of the path is
flattened, so ``entities.*.values`` is every value of every entity.
"""

from __future__ import annotations

import json
import time
import urllib.parse
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import httpx

from tsdb_service.usecases import sites
from tsdb_service.usecases.enums import DOOR_STATE, DRONE_MISSION_STATE, LAWNMOWER_NAVIGATION_STATE
from tsdb_service.usecases.sites import Tenancy

DEFAULT_BASE_URL = "http://localhost:8668"
# Wide defaults so the period queries cover any demo run; narrow them per request.
VARIABLES = {
    "baseUrl": DEFAULT_BASE_URL,
    "fromDate": "2024-01-01T00:00:00.000Z",
    "toDate": "2099-12-31T23:59:59.999Z",
}
PERIOD = (("fromDate", "{{fromDate}}"), ("toDate", "{{toDate}}"))

# -- checks --------------------------------------------------------------------


@dataclass(frozen=True)
class Check:
    """One expectation on a JSON answer, evaluated here and exported as JavaScript."""

    kind: str  # count | each_in | between | inside | ascending
    path: str
    args: dict[str, Any] = field(default_factory=dict)

    @property
    def title(self) -> str:
        a = self.args
        return {
            "count": f"{self.path}: between {a.get('min')} and {a.get('max', 'any number of')} items",
            "each_in": f"every {self.path} is one of {a.get('allowed')}",
            "between": f"every {self.path} is a number in [{a.get('lo')}, {a.get('hi')}]",
            "inside": f"every {self.path} is a point inside the given area",
            "ascending": f"{self.path} is in ascending order",
        }[self.kind]

    def failure(self, doc: Any) -> str | None:
        """Why ``doc`` fails this check, or None when it passes."""
        found = select(doc, self.path)
        return _FAILURES[self.kind](found, **self.args)


def count(path: str, min: int = 1, max: int | None = None) -> Check:
    return Check("count", path, {"min": min} | ({} if max is None else {"max": max}))


def each_in(path: str, allowed: Iterable[Any]) -> Check:
    return Check("each_in", path, {"allowed": list(allowed)})


def between(path: str, lo: float, hi: float) -> Check:
    return Check("between", path, {"lo": lo, "hi": hi})


def inside(path: str, ring: Sequence[tuple[float, float]]) -> Check:
    return Check("inside", path, {"ring": [list(point) for point in ring]})


def ascending(path: str) -> Check:
    return Check("ascending", path)


def select(doc: Any, path: str) -> list[Any]:
    """The values at a dotted path (see the module docstring)."""
    nodes = [doc]
    for segment in path.split("."):
        following = []
        for node in nodes:
            if segment == "*":
                if isinstance(node, list):
                    following.extend(node)
            elif isinstance(node, dict):
                key = next((k for k in segment.split("|") if k in node), None)
                if key is not None:
                    following.append(node[key])
        nodes = following
    return [item for node in nodes for item in (node if isinstance(node, list) else [node])]


def _count_failure(found, min, max=None):
    if len(found) < min or (max is not None and len(found) > max):
        return f"{len(found)} items, expected between {min} and {max if max is not None else 'any number of'}"
    return None


def _each_in_failure(found, allowed):
    bad = [v for v in found if v not in allowed]
    return f"unexpected values {bad[:5]}" if bad else None


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _between_failure(found, lo, hi):
    bad = [v for v in found if not (_is_number(v) and lo <= v <= hi)]
    return f"values outside [{lo}, {hi}]: {bad[:5]}" if bad else None


def _inside_failure(found, ring):
    def point_inside(value):
        try:  # a GeoJSON Point, or a position row {"lat", "lon", ...}
            lon, lat = value["coordinates"][:2] if "coordinates" in value else (value["lon"], value["lat"])
        except (TypeError, KeyError, ValueError):
            return False
        return sites.inside(tuple(map(tuple, ring)), (lat, lon))

    bad = [v for v in found if not point_inside(v)]
    return f"{len(bad)} of {len(found)} points outside the area, e.g. {bad[:2]}" if bad else None


def _ascending_failure(found):
    bad = [i for i in range(1, len(found)) if not found[i - 1] <= found[i]]
    return f"out of order at position {bad[0]}: {found[bad[0] - 1]!r} > {found[bad[0]]!r}" if bad else None


_FAILURES: dict[str, Callable[..., str | None]] = {
    "count": _count_failure,
    "each_in": _each_in_failure,
    "between": _between_failure,
    "inside": _inside_failure,
    "ascending": _ascending_failure,
}

# The same checks for Postman's sandbox; keep in step with the functions above.
_JS_HELPERS = """\
function select(doc, path) {
  let nodes = [doc];
  for (const seg of path.split(".")) {
    const next = [];
    for (const n of nodes) {
      if (seg === "*") { if (Array.isArray(n)) next.push(...n); }
      else if (n && typeof n === "object" && !Array.isArray(n)) {
        const key = seg.split("|").find(k => k in n);
        if (key !== undefined) next.push(n[key]);
      }
    }
    nodes = next;
  }
  return nodes.flatMap(n => Array.isArray(n) ? n : [n]);
}
function isNumber(v) { return typeof v === "number"; }
function pointInside(v, ring) {
  if (!v) return false;
  let lon, lat;
  if (Array.isArray(v.coordinates)) [lon, lat] = v.coordinates;
  else if (typeof v.lon === "number" && typeof v.lat === "number") [lon, lat] = [v.lon, v.lat];
  else return false;
  let inside = false;
  for (let i = 1; i < ring.length; i++) {
    const [lat1, lon1] = ring[i - 1], [lat2, lon2] = ring[i];
    if ((lat1 > lat) !== (lat2 > lat) && lon < lon1 + (lat - lat1) * (lon2 - lon1) / (lat2 - lat1)) inside = !inside;
  }
  return inside;
}
function failure(c, doc) {
  const found = select(doc, c.path), a = c.args;
  switch (c.kind) {
    case "count":
      return (found.length < a.min || (a.max !== undefined && found.length > a.max)) ? `${found.length} items` : null;
    case "each_in": {
      const bad = found.filter(v => !a.allowed.some(x => JSON.stringify(x) === JSON.stringify(v)));
      return bad.length ? `unexpected values ${JSON.stringify(bad.slice(0, 5))}` : null; }
    case "between": {
      const bad = found.filter(v => !(isNumber(v) && a.lo <= v && v <= a.hi));
      return bad.length ? `values outside [${a.lo}, ${a.hi}]: ${JSON.stringify(bad.slice(0, 5))}` : null; }
    case "inside": {
      const bad = found.filter(v => !pointInside(v, a.ring));
      return bad.length ? `${bad.length} points outside the area` : null; }
    case "ascending": {
      for (let i = 1; i < found.length; i++) if (found[i - 1] > found[i]) return `out of order at ${i}`;
      return null; }
  }
  return `unknown check ${c.kind}`;
}"""

# -- queries ---------------------------------------------------------------------


@dataclass(frozen=True)
class Query:
    name: str
    folder: str
    description: str
    path: str
    params: tuple[tuple[str, str], ...]
    tenancy: Tenancy
    checks: tuple[Check, ...]
    method: str = "GET"
    status: int = 200

    @property
    def geo(self) -> bool:
        """Uses NGSI geo-query parameters (georel, geometry, coords)."""
        return any(key == "georel" for key, _ in self.params)

    def headers(self) -> dict[str, str]:
        return {"Fiware-Service": self.tenancy.service, "Fiware-ServicePath": self.tenancy.service_path}

    def target(self, variables: dict[str, str] | None = None) -> str:
        """Path and query string, percent-encoded except for the characters NGSI
        queries read better with (and ``{{variables}}`` unless ``variables`` fills them)."""
        query = "&".join(f"{key}={_quote(value)}" for key, value in self.params)
        text = self.path + ("?" + query if query else "")
        return substitute(text, variables) if variables else text


def _quote(value: str) -> str:
    return urllib.parse.quote(value, safe=",:;(){}")


def substitute(text: str, variables: dict[str, str]) -> str:
    for key, value in variables.items():
        text = text.replace("{{" + key + "}}", value)
    return text


def _entity(entity_id: str, attr: str) -> str:
    return f"/v2/entities/{entity_id}/attrs/{attr}"


def _type(entity_type: str, attr: str) -> str:
    return f"/v2/types/{entity_type}/attrs/{attr}"


def _coords(points: Iterable[tuple[float, float]]) -> str:
    return ";".join(f"{lat},{lon}" for lat, lon in points)


WAREHOUSE_TEMPERATURE = _entity(sites.WAREHOUSE_ID, "temperature(data)")
LAWNMOWER_SPEED = _entity(sites.LAWNMOWER_ID, "odom(twist.twist.linear.x)")
SENSOR_IDS = list(sites.SENSOR_IDS)
ENTITY_IDS = "entities.*.id|entityId"
NEAR_POINT, NEAR_METRES = sites.SENSOR_FIELD_CENTRE, 300
EAST_AREA = ((40.6050, -3.6860), (40.6110, -3.6860), (40.6110, -3.6812), (40.6050, -3.6812), (40.6050, -3.6860))


def _basics() -> list[Query]:
    folder, where = "Sampled values", sites.WAREHOUSE
    values = (between("values", 10, 30), ascending("index"))
    return [
        Query(
            "List the first N sampled values",
            folder,
            "The 5 oldest warehouse temperatures (std_msgs/Float32, read through the value path `(data)`).",
            WAREHOUSE_TEMPERATURE,
            (("limit", "5"),),
            where,
            (count("index", 1, 5), *values),
        ),
        Query(
            "List N sampled values at an offset",
            folder,
            "5 warehouse temperatures after skipping the 5 oldest: paging with offset and limit.",
            WAREHOUSE_TEMPERATURE,
            (("offset", "5"), ("limit", "5")),
            where,
            (count("index", 1, 5), *values),
        ),
        Query(
            "List the latest N sampled values",
            folder,
            "The 5 most recent warehouse temperatures, oldest first.",
            WAREHOUSE_TEMPERATURE,
            (("lastN", "5"),),
            where,
            (count("index", 1, 5), *values),
        ),
    ]


def _aggregations() -> list[Query]:
    folder = "Aggregations over a time period"
    return [
        Query(
            "Sum over a time period: how far the lawnmower drove",
            folder,
            "Sum of the 1 Hz odometry forward speed between fromDate and toDate, i.e. metres driven.",
            LAWNMOWER_SPEED,
            (("aggrMethod", "sum"), *PERIOD),
            sites.LAWNMOWER,
            (count("values", 1, 1), between("values", -1_000_000, 1_000_000)),
        ),
        Query(
            "Min over a time period: coldest reading of each sensor",
            folder,
            "The minimum temperature each remote sensor reported to the drone in the period.",
            _type(sites.SENSOR_TYPE, "temperature"),
            (("aggrMethod", "min"), *PERIOD),
            sites.DRONE,
            (count(ENTITY_IDS, 1, 8), each_in(ENTITY_IDS, SENSOR_IDS), between("entities.*.values", -20, 50)),
        ),
        Query(
            "Max over a time period: warehouse temperature per hour",
            folder,
            "Hourly maxima of the warehouse temperature (aggrPeriod=hour) in the period.",
            WAREHOUSE_TEMPERATURE,
            (("aggrMethod", "max"), ("aggrPeriod", "hour"), *PERIOD),
            sites.WAREHOUSE,
            (count("values", 1), between("values", 10, 30), ascending("index")),
        ),
    ]


def _geo() -> list[Query]:
    folder = "Geo queries"
    near = sites.sensors_within(NEAR_POINT, NEAR_METRES)
    in_area = sites.sensors_inside(EAST_AREA)
    return [
        Query(
            "Latest N of devices near a point",
            folder,
            f"The latest temperatures of the remote sensors within {NEAR_METRES} m of the field centre "
            f"(expected: {', '.join(i.rsplit(':', 1)[1] for i in near)}).",
            _type(sites.SENSOR_TYPE, "temperature"),
            (
                ("lastN", "5"),
                ("georel", f"near;maxDistance:{NEAR_METRES}"),
                ("geometry", "point"),
                ("coords", _coords([NEAR_POINT])),
            ),
            sites.DRONE,
            (count(ENTITY_IDS, 1, len(near)), each_in(ENTITY_IDS, near)),
        ),
        Query(
            "Latest N of devices in an area",
            folder,
            f"The latest temperatures of the remote sensors in the east half of the field "
            f"(expected: {', '.join(i.rsplit(':', 1)[1] for i in in_area)}).",
            _type(sites.SENSOR_TYPE, "temperature"),
            (("lastN", "5"), ("georel", "coveredBy"), ("geometry", "polygon"), ("coords", _coords(EAST_AREA))),
            sites.DRONE,
            (count(ENTITY_IDS, 1, len(in_area)), each_in(ENTITY_IDS, in_area)),
        ),
    ]


def _use_cases() -> list[Query]:
    door, drone, mower = sites.WAREHOUSE, sites.DRONE, sites.LAWNMOWER
    return [
        Query(
            "Warehouse: door state history",
            "PIAP warehouse",
            f"The last 100 door states: {DOOR_STATE}.",
            _entity(sites.WAREHOUSE_ID, "doorState(data)"),
            (("lastN", "100"),),
            door,
            (count("values", 1, 100), each_in("values", DOOR_STATE), ascending("index")),
        ),
        Query(
            "Warehouse: door command and laser distance together",
            "PIAP warehouse",
            "Two value paths of one entity in one wide answer: what the door did and how far the robot was.",
            f"/v2/entities/{sites.WAREHOUSE_ID}",
            (("attrs", "doorCommand(data),laserDistance(range)"), ("lastN", "20")),
            door,
            (count("attributes", 2, 2), count("index", 1, 20)),
        ),
        Query(
            "Lawnmower: linear speed",
            "Bosch lawnmower",
            "The forward speed from nav_msgs/Odometry, read through the value path `odom(twist.twist.linear.x)`.",
            LAWNMOWER_SPEED,
            (("lastN", "20"),),
            mower,
            (count("values", 1, 20), between("values", -0.5, 0.7), ascending("index")),
        ),
        Query(
            "Lawnmower: average speed per minute",
            "Bosch lawnmower",
            "A value path aggregates like a numeric attribute: the per-minute mean forward speed.",
            LAWNMOWER_SPEED,
            (("aggrMethod", "avg"), ("aggrPeriod", "minute"), *PERIOD),
            mower,
            (count("values", 1), between("values", -0.5, 0.7)),
        ),
        Query(
            "Lawnmower: navigation state history",
            "Bosch lawnmower",
            f"The last 50 navigation states: {LAWNMOWER_NAVIGATION_STATE}.",
            _entity(sites.LAWNMOWER_ID, "navigationState(data)"),
            (("lastN", "50"),),
            mower,
            (count("values", 1, 50), each_in("values", LAWNMOWER_NAVIGATION_STATE)),
        ),
        Query(
            "Lawnmower: left perimeter detections",
            "Bosch lawnmower",
            "std_msgs/Bool of the left border-wire coil.",
            _entity(sites.LAWNMOWER_ID, "perimeterLeft(data)"),
            (("lastN", "100"),),
            mower,
            (count("values", 1, 100), each_in("values", [True, False])),
        ),
        Query(
            "Drone: positions inside the sensor field",
            "eProsima drone",
            "Where the drone flew over the field: each GPS position covered by the field's polygon. "
            "The history API's geo filter selects *devices* by their latest location; this asks about "
            "*positions*, so it uses the positions endpoint, which applies the filter to every sample.",
            "/grafana/infinity/positions",
            (
                ("id", sites.DRONE_ID),
                ("georel", "coveredBy"),
                ("geometry", "polygon"),
                ("coords", _coords(sites.SENSOR_FIELD)),
                ("max_points", "5000"),
            ),
            drone,
            (count("*", 1, 5000), inside("*", sites.SENSOR_FIELD)),
        ),
        Query(
            "Drone: mission states",
            "eProsima drone",
            f"The last 50 mission states: {DRONE_MISSION_STATE}.",
            _entity(sites.DRONE_ID, "missionState(data)"),
            (("lastN", "50"),),
            drone,
            (count("values", 1, 50), each_in("values", DRONE_MISSION_STATE)),
        ),
        Query(
            "Drone: readings per sensor",
            "eProsima drone",
            "How many temperature samples each sensor has: one at installation, then one per drone visit.",
            _type(sites.SENSOR_TYPE, "temperature"),
            (("aggrMethod", "count"),),
            drone,
            (count(ENTITY_IDS, 1, 8), each_in(ENTITY_IDS, SENSOR_IDS), between("entities.*.values", 1, 10**9)),
        ),
        Query(
            "Drone: average humidity per sensor",
            "eProsima drone",
            "The mean humidity each sensor reported: the dashboard's 'average measures per sensor'.",
            _type(sites.SENSOR_TYPE, "humidity"),
            (("aggrMethod", "avg"),),
            drone,
            (count(ENTITY_IDS, 1, 8), each_in(ENTITY_IDS, SENSOR_IDS), between("entities.*.values", 0, 100)),
        ),
    ]


LD_ENTITIES = "/ngsi-ld/v1/temporal/entities"
LD_IDS = "*.id"


def _lon_lat(points: Iterable[tuple[float, float]]) -> list[list[float]]:
    return [[lon, lat] for lat, lon in points]


def _ngsi_ld() -> list[Query]:
    """The mission's queries in NGSI-LD form (the temporal API): the drone's
    remote sensors, stored from NGSIv2 notifications, read as Properties."""
    folder, drone = "NGSI-LD temporal API", sites.DRONE
    sensor = f"{LD_ENTITIES}/{sites.SENSOR_IDS[0]}"
    sensors = (("type", sites.SENSOR_TYPE), ("attrs", "temperature"))
    period = (("timerel", "between"), ("timeAt", "{{fromDate}}"), ("endTimeAt", "{{toDate}}"))
    near = sites.sensors_within(NEAR_POINT, NEAR_METRES)
    in_area = sites.sensors_inside(EAST_AREA)
    lat, lon = NEAR_POINT
    return [
        Query(
            "NGSI-LD: first N instances",
            folder,
            "The 5 oldest temperatures of one remote sensor (firstN, simplified temporal representation).",
            sensor,
            (("attrs", "temperature"), ("firstN", "5"), ("format", "temporalValues")),
            drone,
            (count("temperature.values", 1, 5),),
        ),
        Query(
            "NGSI-LD: last N instances",
            folder,
            "The 5 newest temperatures of one remote sensor, oldest first (lastN).",
            sensor,
            (("attrs", "temperature"), ("lastN", "5"), ("format", "temporalValues")),
            drone,
            (count("temperature.values", 1, 5),),
        ),
        Query(
            "NGSI-LD: entities at an offset",
            folder,
            "Remote sensors 4 to 6 (by id) with their newest temperature: paging with limit and offset.",
            LD_ENTITIES,
            (*sensors, ("lastN", "1"), ("limit", "3"), ("offset", "3"), ("count", "true")),
            drone,
            (count(LD_IDS, 1, 3), each_in(LD_IDS, SENSOR_IDS[3:6])),
        ),
        Query(
            "NGSI-LD: sum, min and max over a period",
            folder,
            "Hourly sum, minimum and maximum of every remote sensor's temperature between fromDate and toDate "
            "(aggregatedValues).",
            LD_ENTITIES,
            (
                *sensors,
                ("format", "aggregatedValues"),
                ("aggrMethods", "sum,min,max"),
                ("aggrPeriodDuration", "PT1H"),
                *period,
            ),
            drone,
            (count(LD_IDS, 1, 8), each_in(LD_IDS, SENSOR_IDS)),
        ),
        Query(
            "NGSI-LD: near a point",
            folder,
            f"The newest temperatures of the remote sensors within {NEAR_METRES} m of the field centre "
            "(coordinates are longitude, latitude).",
            LD_ENTITIES,
            (
                *sensors,
                ("lastN", "5"),
                ("georel", f"near;maxDistance=={NEAR_METRES}"),
                ("geometry", "Point"),
                ("coordinates", json.dumps([lon, lat], separators=(",", ":"))),
            ),
            drone,
            (count(LD_IDS, 1, len(near)), each_in(LD_IDS, near)),
        ),
        Query(
            "NGSI-LD: in an area",
            folder,
            "The newest temperatures of the remote sensors in the east half of the field (georel=within).",
            LD_ENTITIES,
            (
                *sensors,
                ("lastN", "5"),
                ("georel", "within"),
                ("geometry", "Polygon"),
                ("coordinates", json.dumps([_lon_lat(EAST_AREA)], separators=(",", ":"))),
            ),
            drone,
            (count(LD_IDS, 1, len(in_area)), each_in(LD_IDS, in_area)),
        ),
    ]


QUERIES: tuple[Query, ...] = (*_basics(), *_aggregations(), *_geo(), *_use_cases(), *_ngsi_ld())

# What the demo prints as "try this".
DEMO_EXAMPLES = (
    "List the latest N sampled values",
    "Lawnmower: linear speed",
    "Warehouse: door state history",
    "Latest N of devices near a point",
)


def by_name(name: str) -> Query:
    for query in QUERIES:
        if query.name == name:
            return query
    raise KeyError(name)


def matching(only: str | None) -> list[Query]:
    """Queries whose name contains ``only`` (case-insensitive); all when None."""
    if not only:
        return list(QUERIES)
    return [q for q in QUERIES if only.lower() in q.name.lower()]


# -- running -----------------------------------------------------------------------


@dataclass(frozen=True)
class Outcome:
    query: Query
    ok: bool
    detail: str
    status: int | None
    elapsed_ms: float
    body: Any = None


def execute(client: httpx.Client, query: Query, variables: dict[str, str]) -> Outcome:
    """Send one query and apply its checks."""
    started = time.perf_counter()
    try:
        response = client.request(query.method, query.target(variables), headers=query.headers())
    except httpx.HTTPError as exc:
        return Outcome(query, False, f"{type(exc).__name__}: {exc}", None, _ms(started))
    elapsed = _ms(started)
    if response.status_code != query.status:
        text = response.text.strip()[:300]
        return Outcome(
            query, False, f"HTTP {response.status_code}, expected {query.status}: {text}", response.status_code, elapsed
        )
    try:
        body = response.json()
    except ValueError:
        return Outcome(query, False, "the answer is not JSON", response.status_code, elapsed)
    problems = [f"{check.title}: {why}" for check in query.checks if (why := check.failure(body))]
    return Outcome(query, not problems, "; ".join(problems) or "ok", response.status_code, elapsed, body)


def run_all(base_url: str, queries: Iterable[Query], variables: dict[str, str] | None = None) -> list[Outcome]:
    values = dict(VARIABLES) | {"baseUrl": base_url} | dict(variables or {})
    with httpx.Client(base_url=base_url, timeout=30.0) as client:
        return [execute(client, query, values) for query in queries]


def _ms(started: float) -> float:
    return (time.perf_counter() - started) * 1000


# -- exports -----------------------------------------------------------------------

GENERATED = "Generated by `tsdb-service queries build` from tsdb_service/demo/collection.py: do not edit."
POSTMAN_SCHEMA = "https://schema.getpostman.com/json/collection/v2.1.0/collection.json"


def curl(query: Query, base_url: str, variables: dict[str, str] | None = None) -> str:
    """The request as a curl command line; ``-g`` when the URL holds ``[ ] { }``,
    which curl otherwise reads as a URL pattern (NGSI-LD ``coordinates=[...]``)."""
    values = dict(VARIABLES) | {"baseUrl": base_url} | dict(variables or {})
    headers = " ".join(f"-H '{key}: {value}'" for key, value in query.headers().items())
    target = query.target(values)
    globoff = " -g" if any(c in target for c in "[]{}") else ""
    return f"curl -s{globoff} '{base_url}{target}' {headers}"


def http_file(queries: Sequence[Query] = QUERIES) -> str:
    """The collection as a ``.http`` file (VS Code REST Client, JetBrains HTTP Client)."""
    lines = [f"# {GENERATED}", "# Start the demo first: tsdb-service demo", ""]
    lines += [f"@{key} = {value}" for key, value in VARIABLES.items()]
    for query in queries:
        lines += ["", f"### {query.name}", f"# {query.description}"]
        lines += [f"# expect: HTTP {query.status}; " + "; ".join(check.title for check in query.checks)]
        lines.append(f"{query.method} {{{{baseUrl}}}}{query.target()}")
        lines += [f"{key}: {value}" for key, value in query.headers().items()]
    return "\n".join(lines) + "\n"


def postman_collection(queries: Sequence[Query] = QUERIES) -> dict:
    """The collection in Postman's v2.1 format, folders per topic, checks as tests."""
    folders: dict[str, list[dict]] = {}
    for query in queries:
        folders.setdefault(query.folder, []).append(_postman_item(query))
    return {
        "info": {
            "_postman_id": "5f0c3d7e-3b8a-4c1e-9a57-2f4d6b1e8c90",
            "name": "tsdb-service",
            "description": "History queries on the tsdb-service demo data (three micro-ROS x FIWARE use cases). "
            + GENERATED,
            "schema": POSTMAN_SCHEMA,
        },
        "item": [{"name": name, "item": items} for name, items in folders.items()],
        "variable": [{"key": key, "value": value, "type": "string"} for key, value in VARIABLES.items()],
    }


def _postman_item(query: Query) -> dict:
    return {
        "name": query.name,
        "request": {
            "method": query.method,
            "header": [{"key": key, "value": value} for key, value in query.headers().items()],
            "url": {
                "raw": "{{baseUrl}}" + query.target(),
                "host": ["{{baseUrl}}"],
                "path": [segment for segment in query.path.split("/") if segment],
                "query": [{"key": key, "value": value} for key, value in query.params],
            },
            "description": query.description,
        },
        "event": [{"listen": "test", "script": {"type": "text/javascript", "exec": _postman_tests(query)}}],
    }


def _postman_tests(query: Query) -> list[str]:
    checks = [{"kind": c.kind, "path": c.path, "args": c.args, "title": c.title} for c in query.checks]
    lines = [f"// {GENERATED}", *_JS_HELPERS.splitlines()]
    lines.append(f'pm.test("HTTP {query.status}", () => pm.response.to.have.status({query.status}));')
    lines.append(f"const checks = {json.dumps(checks, ensure_ascii=False)};")
    lines.append("const doc = pm.response.json();")
    lines.append("for (const c of checks) pm.test(c.title, () => pm.expect(failure(c, doc), c.title).to.be.null);")
    return lines
