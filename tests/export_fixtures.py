"""History with every kind of value, and the two views of it the export tests
compare: what the history API answers, and what an export file holds."""

from __future__ import annotations

import io
from collections import defaultdict
from urllib.parse import quote

import orjson
import pyarrow as pa
import pyarrow.csv as pa_csv
import pyarrow.parquet as pq

from tsdb_service.faces.export import SCHEMA

TENANT = "exportland"
H_A = {"Content-Type": "application/json", "Fiware-Service": TENANT, "Fiware-ServicePath": "/site/a"}
H_B = {**H_A, "Fiware-ServicePath": "/site/b"}
H_OTHER = {**H_A, "Fiware-Service": "elsewhere"}
READ = {"Fiware-Service": TENANT}


def moment(i: int) -> str:
    """Sample times with microseconds (the API shows milliseconds of them)."""
    return f"2024-05-01T10:{i // 60:02d}:{i % 60:02d}.{250_000 + 37 * i:06d}Z"


def robot(i: int, eid: str = "Robot:1", etype: str = "Robot") -> dict:
    attrs = {
        "battery": {"type": "Number", "value": 90.5 - i},
        "count": {"type": "Integer", "value": i * 1000},
        "mode": {"type": "Text", "value": ["mowing", "docked", "", 'a,"quoted"\nline'][i % 4]},
        "docked": {"type": "Boolean", "value": i % 3 == 0},
        "seen": {"type": "DateTime", "value": "2024-04-30T08:00:00.000Z"},
        "odom": {"type": "StructuredValue", "value": {"twist": {"linear": {"x": i / 10}}, "tags": [1, "b", None]}},
        "location": {"type": "geo:point", "value": f"40.41{i % 10}, -3.70{i % 7}"},
        "owner": {"type": "Relationship", "value": f"Person:{i % 2}"},
        "spare": {"type": "Number", "value": None},
        # A type change: numbers first, then text (both kept, QuantumLeap #778).
        "temperature": {"type": "Number", "value": 20 + i} if i < 4 else {"type": "Text", "value": "n/a"},
        "TimeInstant": {"type": "DateTime", "value": moment(i)},
    }
    return {"subscriptionId": "s", "data": [{"id": eid, "type": etype, **attrs}]}


def sensor(i: int) -> dict:
    return {
        "subscriptionId": "s",
        "data": [
            {
                "id": "Sensor:1",
                "type": "Sensor",
                "humidity": {"type": "Number", "value": 40 + i % 5},
                "area": {
                    "type": "geo:json",
                    "value": {
                        "type": "Polygon",
                        "coordinates": [[[-3.7, 40.4], [-3.6, 40.4], [-3.6, 40.5], [-3.7, 40.4]]],
                    },
                },
                "TimeInstant": {"type": "DateTime", "value": moment(i)},
            }
        ],
    }


def load(client) -> None:
    """Two tenants, two service paths, three types, one id in two types."""
    for i in range(8):
        bodies = [(robot(i), H_A), (robot(i, "Robot:2"), H_B), (sensor(i), H_A), (robot(i), H_OTHER)]
        if i % 2:
            bodies.append((robot(i, "Robot:1", "Dock"), H_B))
        for body, headers in bodies:
            response = client.post("/v2/notify", json=body, headers=headers)
            assert response.status_code == 200, response.text


# -- the API's view ----------------------------------------------------------------------


def api_view(client, params: dict, headers: dict) -> dict:
    """{(type, id, attr): [(time, value)]} as the history API answers the
    export's parameters, one attribute of one entity at a time."""
    ask = {k: v for k, v in params.items() if k in ("type", "id", "idPattern", "fromDate", "toDate")}
    wanted = set(params["attrs"].split(",")) if params.get("attrs") else None
    listed = client.get("/v2/entities", params={**ask, "limit": 10000}, headers=headers)
    assert listed.status_code == 200, listed.text
    view = {}
    for entity in listed.json():
        one = {k: v for k, v in ask.items() if k in ("fromDate", "toDate")} | {"type": entity["type"]}
        path = "/v2/entities/" + quote(entity["id"], safe="")
        attrs = client.get(path, params=one, headers=headers).json()["attributes"]
        for name in (a["attrName"] for a in attrs):
            if wanted is not None and name not in wanted:
                continue
            got = client.get(f"{path}/attrs/{quote(name, safe='')}", params=one, headers=headers).json()
            if got["index"]:
                view[(entity["type"], entity["id"], name)] = list(zip(got["index"], got["values"], strict=True))
    return view


# -- the export's view ---------------------------------------------------------------------


def read_parquet(data: bytes) -> pa.Table:
    return pq.read_table(io.BytesIO(data))


def read_csv(data: bytes) -> pa.Table:
    """CSV back into the export's schema: empty fields are nulls, ``""`` is an empty string."""
    table = pa_csv.read_csv(
        io.BytesIO(data),
        convert_options=pa_csv.ConvertOptions(
            column_types=SCHEMA, strings_can_be_null=True, quoted_strings_can_be_null=False
        ),
    )
    return table.cast(SCHEMA)


def value_of(row: dict):
    """The one value column that is set, as the API would show it."""
    present = [k for k in ("value_number", "value_text", "value_bool", "value_json") if row[k] is not None]
    assert len(present) <= 1, row
    if not present:
        return None
    if present[0] == "value_json":
        return orjson.loads(row["value_json"])
    return row[present[0]]


def iso_ms(moment) -> str:
    return moment.strftime("%Y-%m-%dT%H:%M:%S.") + f"{moment.microsecond // 1000:03d}+00:00"


def export_view(table: pa.Table) -> dict:
    assert table.schema.equals(SCHEMA), table.schema
    view = defaultdict(list)
    for row in table.to_pylist():
        key = (row["entity_type"], row["entity_id"], row["attribute"])
        view[key].append((iso_ms(row["time"]), value_of(row)))
    return dict(view)
