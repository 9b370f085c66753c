"""The REST API over HTTP, against a real uvicorn server on 127.0.0.1 (see conftest)."""

from __future__ import annotations

import re
import socket
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx2 as httpx
import pytest

from ncmeasure.errors import ConfigError, StoreError
from ncmeasure.formats.results import Results
from ncmeasure.store import open_store
from ncmeasure.web import MAX_BODY_BYTES, ServerInfo, check_binding, create_app, is_loopback, serve
from tests.web.conftest import TOKEN, WAIT_S, Fleet, running


def client(server: ServerInfo, **headers: str) -> httpx.Client:
    return httpx.Client(base_url=server.url, timeout=WAIT_S, headers=headers)


@pytest.fixture(scope="module")
def api(server: ServerInfo) -> Iterator[httpx.Client]:
    with client(server) as found:
        yield found


def _one_line_error(response: httpx.Response, status: int) -> str:
    assert response.status_code == status, response.text
    assert response.headers["content-type"] == "application/json"
    body = response.json()
    assert set(body) == {"detail"}
    detail = body["detail"]
    assert isinstance(detail, str) and detail and "\n" not in detail
    assert "Traceback" not in detail
    return detail


# --- reading -----------------------------------------------------------------------


def test_lists_every_machine_with_its_latest_verdicts(api: httpx.Client) -> None:
    found = api.get("/api/v1/machines")
    assert found.status_code == 200
    machines = {m["serial"]: m for m in found.json()}
    assert list(machines) == ["M-100", "M-101", "M-102", "M-103"]
    assert machines["M-100"]["measurements"] == 2
    assert machines["M-100"]["latest_label"] == "service"
    assert machines["M-100"]["site"] == "Hall 1"
    assert machines["M-101"]["latest_verdicts"] == {"X": "ok", "Y": "fault"}
    assert machines["M-102"]["latest_verdicts"] == {"X": "ok", "Y": "check"}
    assert machines["M-103"]["latest_verdicts"] == {"X": "ok"}
    assert machines["M-100"]["machine_type"] == "synthetic"


def test_lists_go_in_pages(api: httpx.Client) -> None:
    first = api.get("/api/v1/machines", params={"limit": 3})
    assert [m["serial"] for m in first.json()] == ["M-100", "M-101", "M-102"]
    assert first.headers["x-total-count"] == "4"
    assert first.headers["x-next-cursor"] == "M-102"
    assert first.headers["link"].endswith('?limit=3&cursor=M-102>; rel="next"')
    last = api.get("/api/v1/machines", params={"limit": 3, "cursor": "M-102"})
    assert [m["serial"] for m in last.json()] == ["M-103"]
    assert "x-next-cursor" not in last.headers and "link" not in last.headers
    found = api.get("/api/v1/machines", params={"search": "HALL 1"})
    assert [m["serial"] for m in found.json()] == ["M-100", "M-101"]
    assert found.headers["x-total-count"] == "2"
    assert api.get("/api/v1/machines", params={"search": "%"}).json() == []  # not a pattern
    measured = api.get("/api/v1/machines/M-100/measurements", params={"limit": 1})
    (one,) = measured.json()
    assert measured.headers["x-total-count"] == "2"
    assert measured.headers["x-next-cursor"] == str(one["id"])
    rest = api.get("/api/v1/machines/M-100/measurements", params={"limit": 1, "cursor": one["id"]})
    assert [m["label"] for m in rest.json()] == ["service"] and "link" not in rest.headers
    for bad in ({"limit": 0}, {"limit": 1001}):
        assert "limit" in _one_line_error(api.get("/api/v1/machines", params=bad), 422)


def test_shows_a_machine_with_its_measurements(api: httpx.Client, fleet: Fleet) -> None:
    found = api.get("/api/v1/machines/M-100")
    assert found.status_code == 200
    body = found.json()
    assert body["machine"]["serial"] == "M-100"
    delivery, service = body["measurements"]
    assert [delivery["id"], service["id"]] == [s.measurement_id for s in fleet.of("M-100")]
    assert delivery["label"] == "delivery" and service["label"] == "service"
    assert service["operator"] == "B. Service"
    assert service["temperature_c"] == 23.0 and service["operating_hours"] == 2012.0
    assert service["measured_utc"].startswith("2025-07-10T09:00:00")
    assert service["verdicts"] == {"X": "ok", "Y": "ok"}
    assert api.get("/api/v1/machines/M-100/measurements").json() == body["measurements"]


def test_results_come_back_as_they_were_added(api: httpx.Client, fleet: Fleet) -> None:
    for stored in fleet.stored:
        found = api.get(f"/api/v1/measurements/{stored.measurement_id}/results")
        assert found.status_code == 200
        assert Results.model_validate(found.json()) == stored.results


def test_check_compares_with_the_baseline_and_the_fleet(api: httpx.Client) -> None:
    healthy = api.get("/api/v1/machines/M-100/check").json()
    assert healthy["latest"]["label"] == "service"
    assert healthy["baseline"]["label"] == "delivery"
    assert [r["status"] for r in healthy["comparison"]["runs"]] == ["ok"]  # alike
    assert healthy["comparability"]["refused"] is None
    assert healthy["fleet_machines"] == 3  # the other machines of type "synthetic"
    assert {f["characteristic"] for f in healthy["fleet"]} >= {"coulomb", "spread_percent"}
    assert all(f["machines"] == 3 for f in healthy["fleet"] if f["axis"] == "X")
    broken = api.get("/api/v1/machines/M-101/check").json()
    assert broken["comparison"]["runs"][-1]["status"] in ("warning", "critical")  # Y: +33 %
    assert broken["status"] in ("warning", "critical")
    assert any("axis Y" in finding for finding in broken["findings"])
    alone = api.get("/api/v1/machines/M-103/check").json()
    assert alone["baseline"] is None and alone["comparison"] is None
    assert "only the baseline is stored" in alone["findings"][0]


def test_trend_follows_an_axis_oldest_first(api: httpx.Client, fleet: Fleet) -> None:
    found = api.get("/api/v1/machines/M-101/axes/Y/trend")
    assert found.status_code == 200
    points = found.json()
    assert [p["measurement_id"] for p in points] == [s.measurement_id for s in fleet.of("M-101")]
    assert [p["verdict"] for p in points] == ["ok", "fault"]
    assert points[0]["coulomb"] == pytest.approx(2.0, abs=0.1)  # the simulated friction
    assert points[1]["spread_percent"] > points[0]["spread_percent"] + 15
    assert points[1]["signature"] == "rising_to_loose_bearing"
    assert all(p["unit"] == "Nm" for p in points)


def test_unknown_things_are_404_in_one_line(api: httpx.Client) -> None:
    detail = _one_line_error(api.get("/api/v1/machines/NO-SUCH"), 404)
    assert "NO-SUCH" in detail
    _one_line_error(api.get("/api/v1/machines/NO-SUCH/measurements"), 404)
    _one_line_error(api.get("/api/v1/machines/NO-SUCH/check"), 404)
    assert "axis" in _one_line_error(api.get("/api/v1/machines/M-103/axes/Y/trend"), 404)
    _one_line_error(api.get("/api/v1/measurements/999999/results"), 404)
    _one_line_error(api.get("/api/v1/machines/bad%20serial%20/check"), 404)
    _one_line_error(api.get("/api/v1/measurements/abc/results"), 422)
    _one_line_error(api.get(f"/api/v1/measurements/{2**64}/results"), 422)


def test_openapi_describes_every_endpoint(api: httpx.Client) -> None:
    described = api.get("/openapi.json").json()
    paths = described["paths"]
    assert {
        "/api/v1/machines",
        "/api/v1/machines/{serial}",
        "/api/v1/machines/{serial}/measurements",
        "/api/v1/measurements/{measurement_id}/results",
        "/api/v1/machines/{serial}/check",
        "/api/v1/machines/{serial}/axes/{axis}/trend",
        "/api/v1/measurements",
    } == set(paths)
    assert set(paths["/api/v1/measurements"]) == {"post"}
    schemas = described["components"]["schemas"]
    assert {"Results", "StoreCheck", "NewMeasurement", "ErrorOut", "TrendPoint"} <= set(schemas)
    assert "bearer" in str(described["components"]["securitySchemes"]).lower()


def test_the_docs_page_needs_nothing_beyond_the_server(api: httpx.Client) -> None:
    # A shop-floor network is often offline: no script or style from elsewhere.
    page = api.get("/docs")
    assert page.status_code == 200
    sources = re.findall(r"""(?:src|href)=["']?([^"' >]+)""", page.text)
    sources += re.findall(r"""url: ['"]([^'"]+)['"]""", page.text)
    assert any(s.endswith(".js") for s in sources) and any(s.endswith(".css") for s in sources)
    for source in sources:
        assert not re.match(r"(https?:)?//", source), source
        fetched = api.get(source)
        assert fetched.status_code == 200 and fetched.content, source


# --- adding ------------------------------------------------------------------------


@pytest.fixture
def small_store(fleet: Fleet, tmp_path: Path) -> str:
    """A store of its own (adding must not change the shared fleet) with one measurement."""
    url = f"sqlite:///{tmp_path / 'small.db'}"
    first = fleet.stored[0]
    with open_store(url, write=True) as store:
        store.add(first.results, first.info)
    return url


def _body(results: Results, **info: Any) -> dict[str, Any]:
    return {**info, "results": results.model_dump(mode="json")}


def test_post_adds_once(small_store: str, fleet: Fleet) -> None:
    body = _body(fleet.spare, serial="M-200", label="delivery", site="Hall 2", temperature_c=20.0)
    with running(small_store) as server, client(server) as api:
        created = api.post("/api/v1/measurements", json=body)
        assert created.status_code == 201, created.text
        added = created.json()
        assert added["new"] is True and added["serial"] == "M-200"
        again = api.post("/api/v1/measurements", json=body)
        assert again.status_code == 200
        assert again.json() == {**added, "new": False}
        stored = api.get(f"/api/v1/measurements/{added['measurement_id']}/results").json()
        assert Results.model_validate(stored) == fleet.spare
        machine = api.get("/api/v1/machines/M-200").json()["machine"]
        assert machine["site"] == "Hall 2" and machine["measurements"] == 1
        # the same results for another machine: refused, in words
        other = api.post("/api/v1/measurements", json={**body, "serial": "M-201"})
        assert "M-200" in _one_line_error(other, 422)


def test_post_refuses_bad_input_in_one_line(small_store: str, fleet: Fleet) -> None:
    good = _body(fleet.spare, serial="M-300")
    results = good["results"]
    with running(small_store) as server, client(server) as api:

        def refused(body: object = None, content: bytes | None = None, **changes: Any) -> str:
            sent = (
                api.post("/api/v1/measurements", json={**good, **changes} if body is None else body)
                if content is None
                else api.post(
                    "/api/v1/measurements",
                    content=content,
                    headers={"content-type": "application/json"},
                )
            )
            return _one_line_error(sent, 422)

        assert "serial" in refused(serial="a/b")
        assert "label" in refused(label="Big Label")
        assert "temperature" in refused(temperature_c=900)
        assert "results.axes.X" in refused(results={**results, "axes": {"X": {"verdict": 1}}})
        assert "format_version" in refused(results={**results, "format_version": 1})
        assert "results" in refused(body={"serial": "M-300"})
        assert "unknown" in refused(unknown=1)
        assert "JSON" in refused(content=b'{"serial": "M-300", "results": {')
        content = httpx.Request("POST", "/", json=good).content
        nan = re.sub(rb'"median":\s*[-0-9.eE+]+', b'"median": NaN', content, count=1)
        assert nan != content
        assert "NaN" in refused(content=nan)
        assert [m["serial"] for m in api.get("/api/v1/machines").json()] == ["M-100"]


def test_a_store_that_fails_answers_503(small_store: str, tmp_path: Path) -> None:
    with running(small_store) as server, client(server) as api:
        Path(small_store.removeprefix("sqlite:///")).write_bytes(b"not a database" * 100)
        detail = _one_line_error(api.get("/api/v1/machines"), 503)
        assert "store" in detail


def test_a_body_beyond_the_limit_is_refused_unread(server: ServerInfo) -> None:
    request = (
        "POST /api/v1/measurements HTTP/1.1\r\nHost: 127.0.0.1\r\n"
        f"Content-Type: application/json\r\nContent-Length: {MAX_BODY_BYTES + 1}\r\n\r\n"
    )
    with socket.create_connection((server.host, server.port), timeout=WAIT_S) as connection:
        connection.sendall(request.encode())
        answer = connection.recv(4096).decode("latin-1")
    assert answer.startswith("HTTP/1.1 413"), answer


# --- who may -----------------------------------------------------------------------


def test_with_a_token_every_request_needs_it(token_server: ServerInfo) -> None:
    with client(token_server) as anonymous:
        for path in ("/api/v1/machines", "/openapi.json", "/docs", "/", "/machines/M-100"):
            refused = anonymous.get(path)
            assert refused.status_code == 401, path
            assert refused.headers["www-authenticate"] == "Bearer"
        assert "token" in _one_line_error(anonymous.get("/api/v1/machines"), 401)
        wrong = anonymous.get("/api/v1/machines", headers={"Authorization": "Bearer " + "x" * 32})
        assert wrong.status_code == 401
        assert anonymous.post("/api/v1/measurements", json={}).status_code == 401
    with client(token_server, Authorization=f"Bearer {TOKEN}") as holder:
        assert holder.get("/api/v1/machines").status_code == 200
        assert holder.get("/").status_code == 200
        assert holder.post("/api/v1/measurements", json={}).status_code == 422  # let in


def test_a_browser_signs_in_once_with_the_token_in_the_address(token_server: ServerInfo) -> None:
    with client(token_server) as browser:
        signed = browser.get(f"/machines/M-100?token={TOKEN}")
        assert signed.status_code == 303
        assert signed.headers["location"] == "/machines/M-100"  # the token leaves the address
        cookie = signed.headers["set-cookie"]
        assert "HttpOnly" in cookie and "SameSite=Lax" in cookie and TOKEN not in cookie
        assert browser.get("/machines/M-100").status_code == 200  # the cookie now
        assert browser.get("/api/v1/machines").status_code == 200
        # reading only: writing needs the header, whatever the cookie
        assert browser.post("/api/v1/measurements", json={}).status_code == 401
    with client(token_server) as other:
        assert other.get("/?token=wrong-token-wrong-token").status_code == 401
        assert other.get(f"/api/v1/machines?token={TOKEN}").status_code == 200


def test_without_a_token_only_loopback_names_are_answered(server: ServerInfo) -> None:
    with client(server, Host="fleet.example.com") as rebound:
        refused = rebound.get("/api/v1/machines")
        assert "loopback" in _one_line_error(refused, 403)
    with client(server, Host=f"localhost:{server.port}") as local:
        assert local.get("/api/v1/machines").status_code == 200


def test_serving_beyond_loopback_needs_a_token(fleet: Fleet) -> None:
    for host in ("0.0.0.0", "192.168.1.20", "::", "", "fleet.example.com"):
        with pytest.raises(ConfigError, match="token"):
            serve(fleet.url, host=host, port=0)
        check_binding(host, TOKEN)  # with a token: allowed
    for host in ("127.0.0.1", "127.0.0.2", "::1", "localhost", "[::1]"):
        assert is_loopback(host)
        check_binding(host, None)
    with pytest.raises(ConfigError, match="at least 16"):
        check_binding("0.0.0.0", "short")
    with pytest.raises(ConfigError, match="printable"):
        create_app(fleet.url, token="a token with spaces in it")


def test_serving_a_missing_store_fails_in_words(tmp_path: Path) -> None:
    with pytest.raises(StoreError, match="no such file"):
        serve(f"sqlite:///{tmp_path / 'none.db'}", port=0)
    with pytest.raises(ConfigError, match="store"):
        serve("mysql://somewhere/db", port=0)


def test_a_port_in_use_fails_in_words(fleet: Fleet, server: ServerInfo) -> None:
    with pytest.raises(ConfigError, match="cannot listen"):
        serve(fleet.url, server.host, server.port)
