"""Live server API: authentication on every endpoint, input limits, admin edits, fuzzing.

Runs against SQLite and PostgreSQL (``db_url`` fixture in ``server_support``).
"""

from __future__ import annotations

import json

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from radiopose.server.auth import create_token
from radiopose.server.schemas import MAX_FRAMES_PER_BATCH
from server_support import (  # fixtures and helpers
    Running,
    db_url,
    frame_dicts,
    pg_server,
    server,
    tiny,
)

OK_PATTERN = "rx1"


def _batch(tiny, rid="rx1", n=5, batch_id="b1"):
    return {
        "receiver_id": rid,
        "batch_id": batch_id,
        "frames": frame_dicts(tiny.frames[rid].take(slice(0, n))),
    }


def _endpoints(tiny):
    """(method, path, json body, roles allowed) of every API endpoint."""
    receiver = {
        "x_m": 1.0,
        "y_m": 1.0,
        "z_m": 1.0,
        "azimuth_deg": 0.0,
        "pitch_deg": 0.0,
        "roll_deg": 0.0,
        "pattern": OK_PATTERN,
    }
    pattern_csv = (tiny.site_dir / "patterns" / "rx1.csv").read_text()
    survey_csv = (tiny.site_dir / "survey.csv").read_text()
    return [
        ("POST", "/api/v1/reports", _batch(tiny, batch_id="auth"), {"rx1"}),
        ("GET", "/api/v1/transmitters", None, {"rx1", "rx2", "viewer", "admin"}),
        ("GET", "/api/v1/estimates", None, {"viewer", "admin"}),
        ("GET", "/api/v1/alarms", None, {"viewer", "admin"}),
        ("GET", "/api/v1/site", None, {"viewer", "admin"}),
        ("GET", "/api/v1/patterns/rx1", None, {"viewer", "admin"}),
        ("GET", "/health", None, {"viewer", "admin"}),
        ("GET", "/api/v1/stream", None, {"viewer", "admin"}),
        ("PUT", "/api/v1/admin/receivers/rx1", receiver, {"admin"}),
        (
            "PUT",
            "/api/v1/admin/devices/02:00:00:00:00:09",
            {"pattern": "device", "tx_power_dbm": 10.0},
            {"admin"},
        ),
        ("DELETE", "/api/v1/admin/devices/02:00:00:00:00:09", None, {"admin"}),
        ("PUT", "/api/v1/admin/patterns/extra", {"csv": pattern_csv}, {"admin"}),
        ("DELETE", "/api/v1/admin/patterns/extra", None, {"admin"}),
        ("PUT", "/api/v1/admin/survey", {"csv": survey_csv}, {"admin"}),
        ("DELETE", "/api/v1/admin/receivers/rx3", None, {"admin"}),
    ]


def _call(client, method, path, body):
    if path == "/api/v1/stream":
        with client.stream(method, path) as r:
            return r.status_code
    return client.request(method, path, json=body).status_code


def test_every_endpoint_needs_the_right_token(server: Running, tiny) -> None:
    table = _endpoints(tiny)
    routes = {
        (m, r.path)
        for r in server.app.routes
        if r.path.startswith(("/api", "/health"))
        for m in getattr(r, "methods", ())
    }
    covered = {(m, p) for m, p, _, _ in table}
    for m, p in routes:  # every API route is in the table above
        assert any(m == cm and _same_route(p, cp) for cm, cp in covered), (m, p)
    wrong = server.client("rp_not-a-token")
    nobody = server.client(None)
    basic = server.client(None, Authorization="Basic dXNlcjpwYXNz")
    for method, path, body, allowed in table:
        assert _call(nobody, method, path, body) == 401, (method, path)
        assert _call(wrong, method, path, body) == 401, (method, path)
        assert _call(basic, method, path, body) == 401, (method, path)
        for role in ("rx1", "rx2", "viewer", "admin"):
            status = _call(server.client(server.tokens[role]), method, path, body)
            if role in allowed:
                assert status < 400, (role, method, path, status)
            else:
                assert status == 403, (role, method, path, status)


def _same_route(route: str, path: str) -> bool:
    a, b = route.strip("/").split("/"), path.strip("/").split("/")
    return len(a) == len(b) and all(x == y or x.startswith("{") for x, y in zip(a, b, strict=True))


def test_dashboard_page_is_public_and_holds_no_data(server: Running) -> None:
    r = server.client(None).get("/")
    assert r.status_code == 200 and "radiopose" in r.text
    assert "rx1" not in r.text
    assert server.client(None).get("/static/app.js").status_code == 200
    assert server.client(None).get("/openapi.json").json()["info"]["version"] == "1"


def test_strangers_and_glitches_are_skipped_and_counted_not_the_batch(
    server: Running, tiny
) -> None:
    """A sniffer reports every frame it hears: a frame of a transmitter that is not
    enrolled, or with an RSS outside [-120, 0] dBm, is skipped and counted in the
    answer (as ``sync`` skips and counts it), and the batch's other frames are
    stored (the whole batch was once a 422 over one stranger)."""
    c = server.client(server.tokens["rx1"])
    body = _batch(tiny, n=6, batch_id="mixed")
    body["frames"][1].update(transmitter="aa:bb:cc:dd:ee:ff")  # the contract's example id
    body["frames"][2].update(transmitter="some-other-phone")
    body["frames"][3].update(rss_dbm=-130.0)
    body["frames"][4].update(rss_dbm=5.0)
    r = c.post("/api/v1/reports", json=body)
    assert r.status_code == 201, r.text
    assert r.json() == {
        "batch_id": "mixed",
        "frames_stored": 2,
        "duplicate": False,
        "frames_not_enrolled": 2,
        "frames_implausible_rss": 2,
    }
    assert server.db.count_frames() == 2
    only_strangers = _batch(tiny, n=2, batch_id="strangers")
    for f in only_strangers["frames"]:
        f.update(transmitter="aa:bb:cc:dd:ee:ff")
    r = c.post("/api/v1/reports", json=only_strangers)
    assert r.status_code == 201 and r.json()["frames_not_enrolled"] == 2
    assert c.post("/api/v1/reports", json=only_strangers).json()["duplicate"] is True
    assert server.db.count_frames() == 2


def test_report_is_stored_once(server: Running, tiny) -> None:
    c = server.client(server.tokens["rx1"])
    body = _batch(tiny, n=7, batch_id="once")
    r = c.post("/api/v1/reports", json=body)
    assert r.status_code == 201 and r.json() == {
        "batch_id": "once",
        "frames_stored": 7,
        "duplicate": False,
        "frames_not_enrolled": 0,
        "frames_implausible_rss": 0,
    }
    before = server.db.count_frames()
    for _ in range(2):  # the same batch id again: 2xx, nothing new
        r = c.post("/api/v1/reports", json=body)
        assert r.status_code == 200 and r.json()["duplicate"] is True
    assert server.db.count_frames() == before == 7


@pytest.mark.parametrize(
    ("mutate", "status", "words"),
    [
        (lambda b: b["frames"][0].update(rss_dbm=float("nan")), 422, "rss_dbm"),
        (lambda b: b["frames"][0].update(timestamp_s=-1.0), 422, "timestamp_s"),
        (lambda b: b["frames"][0].update(timestamp_s=float("inf")), 422, "timestamp_s"),
        # past 2**63 ns (the database's integer): a 422, not a 500 the agent retries forever
        (lambda b: b["frames"][0].update(timestamp_s=9.3e9), 422, "timestamp_s"),
        # numbers are JSON numbers: not converted from text or booleans
        (lambda b: b["frames"][0].update(timestamp_s="12.5"), 422, "timestamp_s"),
        (lambda b: b["frames"][0].update(rss_dbm=True), 422, "rss_dbm"),
        (lambda b: b.update(batch_id="a\u0000b"), 422, "batch_id"),
        (lambda b: b["frames"][0].update(frame_sha256="ab"), 422, "frame_sha256"),
        (lambda b: b["frames"][0].update(transmitter="a,b"), 422, "transmitter"),
        # the contract's rule, as every reader applies it (ids.transmitter_id_problem)
        (lambda b: b["frames"][0].update(transmitter="a\u0000b"), 422, "not a transmitter id"),
        (lambda b: b["frames"][0].update(transmitter="a\u200bb"), 422, "not a transmitter id"),
        (lambda b: b["frames"][0].pop("rss_dbm"), 422, "rss_dbm"),
        (lambda b: b.update(batch_id=""), 422, "batch_id"),
        (lambda b: b.update(batch_id="x" * 129), 422, "batch_id"),
        (lambda b: b.update(frames=b["frames"] * (MAX_FRAMES_PER_BATCH // 5 + 1)), 422, "frames"),
        (lambda b: b.update(receiver_id="rx2"), 403, "rx1"),
        # the receiver-id rule every reader applies (ids.receiver_id_problem): no space
        (lambda b: b.update(receiver_id="rx 1"), 422, "not a receiver id"),
    ],
)
def test_bad_reports_are_rejected_whole(server: Running, tiny, mutate, status, words) -> None:
    body = _batch(tiny, n=5, batch_id="bad")
    mutate(body)
    r = server.client(server.tokens["rx1"]).post(
        "/api/v1/reports", content=json.dumps(body), headers={"Content-Type": "application/json"}
    )
    assert r.status_code == status, r.text
    detail = r.json()["detail"]
    assert words in detail and "\n" not in detail
    assert server.db.count_frames() == 0
    assert server.client(server.tokens["viewer"]).get("/health").status_code == 200


def test_limits_at_their_edges_and_in_queries(server: Running, tiny) -> None:
    """The largest timestamp is stored (both databases); a transmitter id of 64
    characters can be enrolled and report (PostgreSQL once stored 17); bad query
    values are 422s naming the parameter."""
    rx1, admin = server.client(server.tokens["rx1"]), server.client(server.tokens["admin"])
    body = _batch(tiny, n=1, batch_id="edge")
    body["frames"][0]["timestamp_s"] = 9.2e9
    assert rx1.post("/api/v1/reports", json=body).status_code == 201
    (batch,) = server.db.batches_after(0, 10)
    assert batch.timestamp_ns == (9_200_000_000_000_000_000,)
    long_id = "phone-" + "x" * 58
    r = admin.put(f"/api/v1/admin/devices/{long_id}", json={"pattern": "device", "tx_power_dbm": 1})
    assert r.status_code == 200, r.text
    body = _batch(tiny, n=1, batch_id="long-id")
    body["frames"][0]["transmitter"] = long_id
    assert rx1.post("/api/v1/reports", json=body).status_code == 201
    assert server.db.count_frames() == 2
    # the admin's numbers are JSON numbers too
    r = admin.put("/api/v1/admin/devices/phone-3", json={"pattern": "device", "tx_power_dbm": "1"})
    assert r.status_code == 422 and "tx_power_dbm" in r.json()["detail"]
    viewer = server.client(server.tokens["viewer"])
    for path, words in (
        ("/api/v1/estimates?transmitter=a,b", "transmitter"),
        ("/api/v1/estimates?transmitter=", "transmitter"),
        ("/api/v1/alarms?transmitter=%00", "transmitter"),
        ("/api/v1/estimates?transmitter=a%E2%80%8Bb", "transmitter"),
        (f"/api/v1/stream?after_id={2**63}", "after_id"),
    ):
        r = viewer.get(path)
        assert r.status_code == 422 and words in r.json()["detail"], (path, r.text)


@pytest.mark.parametrize("db_url", ["postgresql"], indirect=True)
def test_an_old_postgresql_database_gains_the_longer_transmitter_column(db_url: str) -> None:
    """A database of the release that stored MAC addresses only (17 characters)
    is widened when opened, so a device named with up to 64 characters reports."""
    from sqlalchemy import text

    from radiopose.server.db import Database

    db = Database(db_url)
    with db.engine.begin() as c:  # what the old release created
        c.execute(text("ALTER TABLE frames ALTER COLUMN transmitter TYPE VARCHAR(17)"))
    url = db.url
    db.close()
    again = Database(url, create=False)  # a worker's connection migrates too
    long_id = "phone-" + "x" * 58
    again.store_batch("rx1", "b1", [(1_000_000_000, "ab" * 32, long_id, -60.0)])
    (batch,) = again.batches_after(0, 10)
    assert batch.transmitter == (long_id,)
    again.close()


def test_unknown_receiver_and_oversized_body(server: Running, tiny) -> None:
    token = create_token(server.db, "receiver", "rx9")
    r = server.client(token).post("/api/v1/reports", json=_batch(tiny) | {"receiver_id": "rx9"})
    assert r.status_code == 422 and "unknown receiver 'rx9'" in r.json()["detail"]
    big = b'{"receiver_id": "rx1", "batch_id": "big", "frames": [], "pad": "' + b"x" * 2_100_000
    r = server.client(server.tokens["rx1"]).post(
        "/api/v1/reports", content=big + b'"}', headers={"Content-Type": "application/json"}
    )
    assert r.status_code == 413

    def chunks():  # no Content-Length: the limit must trip while the body streams in
        yield b'{"receiver_id": "rx1", "batch_id": "big", "frames": [], "pad": "'
        for _ in range(40):
            yield b"x" * 65_536
        yield b'"}'

    r = server.client(server.tokens["rx1"]).post(
        "/api/v1/reports", content=chunks(), headers={"Content-Type": "application/json"}
    )
    assert r.status_code == 413
    for raw in (b"not json", b"[1, 2]", b'"text"', b"{}"):
        r = server.client(server.tokens["rx1"]).post(
            "/api/v1/reports", content=raw, headers={"Content-Type": "application/json"}
        )
        assert r.status_code == 422, raw
    assert server.db.count_frames() == 0


def test_admin_edits_are_validated_whole(server: Running, tiny) -> None:
    admin = server.client(server.tokens["admin"])
    site0 = admin.get("/api/v1/site").json()
    bad = [
        (
            "PUT",
            "/api/v1/admin/receivers/rx1",
            {"x_m": 1, "y_m": 1, "z_m": 1, "pattern": "no-such-pattern"},
            "no-such-pattern",
        ),
        (
            "PUT",
            "/api/v1/admin/receivers/rx1",
            {"x_m": 1, "y_m": 1, "z_m": 1, "pitch_deg": 120, "pattern": "rx1"},
            "pitch_deg",
        ),
        (
            "PUT",
            "/api/v1/admin/receivers/rx7",
            {"x_m": 1, "y_m": 1, "z_m": 1, "pattern": "rx1"},
            "survey",
        ),
        (
            "PUT",
            "/api/v1/admin/patterns/rx1",
            {"csv": "azimuth_deg,polar_deg\n0,90\n"},
            "directivity_dbi",
        ),
        (
            "PUT",
            "/api/v1/admin/patterns/rx1",
            {"csv": "azimuth_deg,polar_deg,directivity_dbi\n0,90,1\n90,90,nan\n"},
            "rx1.csv",
        ),
        ("DELETE", "/api/v1/admin/patterns/rx1", None, "rx1"),
        ("PUT", "/api/v1/admin/survey", {"csv": "x_m,y_m\n1,2\n"}, "survey.csv"),
        # a pattern no receiver or device uses yet is still a pattern file
        ("PUT", "/api/v1/admin/patterns/spare", {"csv": "x"}, "spare.csv"),
        (
            "PUT",
            "/api/v1/admin/patterns/spare",
            {"csv": "azimuth_deg,polar_deg,directivity_dbi\n0,90,1\n90,90,nan\n"},
            "spare.csv",
        ),
        ("PUT", "/api/v1/admin/patterns/spare", {"csv": "a\u0000"}, "csv"),
        (
            "PUT",
            "/api/v1/admin/receivers/rx1",
            {"x_m": "1", "y_m": 1, "z_m": 1, "pattern": "rx1"},
            "x_m",
        ),
        (
            "PUT",
            "/api/v1/admin/devices/a%2Cb",
            {"pattern": "device", "tx_power_dbm": 1},
            "transmitter id",
        ),
    ]
    for method, path, body, words in bad:
        r = admin.request(method, path, json=body)
        assert r.status_code == 422, (path, r.text)
        assert words in r.json()["detail"], r.json()
    assert admin.get("/api/v1/site").json() == site0  # nothing changed
    r = admin.put(
        "/api/v1/admin/receivers/rx1",
        json={"x_m": 2.5, "y_m": 0.5, "z_m": 1.0, "azimuth_deg": 90, "pattern": "rx1"},
    )
    assert r.status_code == 200
    site1 = r.json()
    assert site1["version"] == site0["version"] + 1
    assert site1["receivers"][0] == {
        "receiver_id": "rx1",
        "x_m": 2.5,
        "y_m": 0.5,
        "z_m": 1.0,
        "azimuth_deg": 90.0,
        "pitch_deg": 0.0,
        "roll_deg": 0.0,
        "pattern": "rx1",
    }
    # a newly enrolled device may report at once
    r = admin.put(
        "/api/v1/admin/devices/02:00:00:00:00:42", json={"pattern": "device", "tx_power_dbm": 12.0}
    )
    assert r.status_code == 200
    body = _batch(tiny, n=1, batch_id="new-device")
    body["frames"][0]["transmitter"] = "02:00:00:00:00:42"
    assert server.client(server.tokens["rx1"]).post("/api/v1/reports", json=body).status_code == 201
    # contract: a transmitter id is any string without commas or whitespace (a simulated
    # device's name): it can be enrolled and report, matched case-insensitively
    r = admin.put("/api/v1/admin/devices/phone-2", json={"pattern": "device", "tx_power_dbm": 12.0})
    assert r.status_code == 200
    body = _batch(tiny, n=1, batch_id="named-device")
    body["frames"][0]["transmitter"] = "Phone-2"
    assert server.client(server.tokens["rx1"]).post("/api/v1/reports", json=body).status_code == 201
    assert "phone-2" in server.client(server.tokens["viewer"]).get("/api/v1/transmitters").json()
    body["frames"][0]["transmitter"] = "phone 2"
    body["batch_id"] = "spaced"
    r = server.client(server.tokens["rx1"]).post("/api/v1/reports", json=body)
    assert r.status_code == 422 and "transmitter" in r.json()["detail"]


_json = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=80),
    lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(max_size=12), c, max_size=5),
    max_leaves=20,
)
_frame = st.fixed_dictionaries(
    {},
    optional={
        "timestamp_s": st.floats() | st.integers() | st.text(max_size=10),
        "frame_sha256": st.text(alphabet="0123456789abcdefX", min_size=60, max_size=66) | _json,
        "transmitter": st.sampled_from(
            ["02:00:00:00:00:01", "02-00-00-00-00-01", "02:00:00:00:00:02", "zz"]
        )
        | _json,
        "rss_dbm": st.floats(-200, 50) | st.floats() | _json,
    },
)
_body = (
    st.fixed_dictionaries(
        {},
        optional={
            "receiver_id": st.sampled_from(["rx1", "rx2", ""]) | _json,
            "batch_id": st.text(max_size=140) | _json,
            "frames": st.lists(_frame, max_size=6) | _json,
        },
    )
    | _json
)


@pytest.mark.parametrize("db_url", ["sqlite"], indirect=True)
@settings(
    max_examples=80,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(body=_body)
def test_fuzzed_reports_never_break_the_server(server: Running, body) -> None:
    c = server.client(server.tokens["rx1"])
    before = server.db.count_frames()
    raw = json.dumps(body, allow_nan=True)
    r = c.post("/api/v1/reports", content=raw, headers={"Content-Type": "application/json"})
    assert r.status_code in (200, 201, 403, 413, 422), (r.status_code, r.text)
    if r.status_code >= 400:
        assert server.db.count_frames() == before
        assert "\n" not in r.json()["detail"]
    elif r.status_code == 201:
        assert server.db.count_frames() == before + len(body["frames"])


def test_db_export_of_a_missing_file_writes_nothing_and_token_create_says_it_created(
    tmp_path, capsys
) -> None:
    """``db export`` reads a server's database: a mistyped SQLite path is one line
    and leaves neither an empty database nor an output directory behind (it
    created both). ``token create`` may set up a database before its server first
    starts, so it creates one, but says so on stderr (a mistyped path was silent)."""
    from radiopose.cli import main

    missing, out = tmp_path / "nosuch.db", tmp_path / "out"
    assert main(["db", "export", "--db", str(missing), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "no such database file" in err and err.count("\n") == 1
    assert not missing.exists() and not out.exists()
    fresh = tmp_path / "fresh.db"
    assert main(["token", "create", "--db", str(fresh), "--role", "viewer"]) == 0
    captured = capsys.readouterr()
    assert captured.out.startswith("rp_") and "created a new database" in captured.err
    assert main(["token", "create", "--db", f"sqlite:///{fresh}", "--role", "viewer"]) == 0
    assert capsys.readouterr().err == ""  # it exists now
