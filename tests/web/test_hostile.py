"""Issue 34 on the annotate page: nothing a person did is lost or locked away, nothing crashes, nothing spins.

Two servers on one file, edits the file's readers would refuse, cross-site and malformed requests, stalled
connections, ids and images that used to crash the page, and the time bound on refits."""

from __future__ import annotations

import http.client
import json
import socket
import time
from pathlib import Path

import pytest

from tests.web.conftest import make_session, serving
from tests.web.synthetic import NAMED, UNNAMED, clicks, write_sequence
from toosicubix.annotations.priors_file import load_priors
from toosicubix.annotations.schema import MAX_CLICKS_PER_VEHICLE
from toosicubix.web import session as session_module
from toosicubix.web.client import Client
from toosicubix.web.request_fields import ApiError
from toosicubix.web.server import serve_in_thread
from toosicubix.web.session import Session, load_cameras

# -- two servers on one file: every file the page writes is checked before it is written ---------------------------


def test_a_second_servers_done_mark_does_not_drop_an_unnamed_click(scene, tmp_path):
    """Issue 34: A saves an unnamed click (on disk in the extras file only), B, which read the files before, marks
    the vehicle done: B's write would drop A's click, so it is refused (409) and nothing is written; after a reload
    B has A's click and its done mark goes through, keeping the click."""
    out = tmp_path / "annotations.json"
    with serving(make_session(scene, out)) as a:
        assert a.edit({"op": "add_vehicle"})[0] == 200
        with serving(make_session(scene, out)) as b:
            waiting = clicks(UNNAMED)[0].uv
            status, doc = a.edit({"op": "add_click", "vehicle": "1", "uv": waiting})
            assert status == 200, doc
            on_disk = out.with_name("annotations.json.annotate.json").read_bytes()
            status, doc = b.edit({"op": "set_vehicle", "vehicle": "1", "done": True})
            assert status == 409 and "annotations.json.annotate.json was changed on disk" in doc["error"], doc
            assert out.with_name("annotations.json.annotate.json").read_bytes() == on_disk
            assert b.request("POST", "/api/reload", {})[0] == 200
            status, doc = b.edit({"op": "set_vehicle", "vehicle": "1", "done": True})
            assert status == 200, doc
    extras = json.loads(out.with_name("annotations.json.annotate.json").read_text())
    assert extras["images"]["car"]["1"] == {"done": True, "unnamed": waiting}


def test_a_second_servers_unnamed_click_does_not_drop_a_done_mark(scene, tmp_path):
    out = tmp_path / "annotations.json"
    with serving(make_session(scene, out)) as a:
        assert a.edit({"op": "add_vehicle"})[0] == 200
        with serving(make_session(scene, out)) as b:
            assert a.edit({"op": "set_vehicle", "vehicle": "1", "done": True})[0] == 200
            status, doc = b.edit({"op": "add_click", "vehicle": "1", "uv": clicks(UNNAMED)[0].uv})
            assert status == 409 and "changed on disk" in doc["error"]
    extras = json.loads(out.with_name("annotations.json.annotate.json").read_text())
    assert extras["images"]["car"]["1"] == {"done": True, "unnamed": []}


def test_the_extras_of_images_not_served_are_kept(scene, tmp_path):
    """A session serving some of the file's images writes the extras file back with the others' entries as read."""
    out = tmp_path / "annotations.json"
    session = make_session(scene, out)
    session.edit(0, {"revision": 0, "op": "add_vehicle"})
    document = json.loads(out.read_text())
    other = {**document["images"][0], "id": "other"}
    out.write_text(json.dumps({"toosicubix": 1, "images": [document["images"][0], other]}))
    session.extras_path.write_text(json.dumps({"toosicubix_annotate": 1, "images": {
        "other": {"1": {"done": True, "unnamed": [[10.0, 20.0]]}}}, "dismissed": {"other": ["0003-1"]}}))
    resumed = make_session(scene, out)
    resumed.edit(0, {"revision": resumed.revision, "op": "set_vehicle", "vehicle": "1", "done": True})
    extras = json.loads(session.extras_path.read_text())
    assert extras["images"] == {"other": {"1": {"done": True, "unnamed": [[10.0, 20.0]]}},
                                "car": {"1": {"done": True, "unnamed": []}}}
    assert extras["dismissed"] == {"other": ["0003-1"]}


def test_a_reload_that_fails_leaves_the_session_as_it_was(served, tmp_path):
    """Another program breaks the file: the reload is refused naming it, and the page keeps what it had (its next
    change is refused too, 409, rather than overwriting the file)."""
    client, _ = served
    assert client.edit({"op": "add_vehicle"})[0] == 200
    for c in clicks(NAMED)[:2]:
        assert client.edit({"op": "add_click", "vehicle": "1", "kind": c.kind, "name": c.name, "uv": c.uv})[0] == 200
    (tmp_path / "annotations.json").write_text('{"toosicubix": 1, "images": [')
    status, doc = client.request("POST", "/api/reload", {})
    assert status == 400 and "annotations.json" in doc["error"], doc
    view = client.request("GET", "/api/images/0")[1]
    assert [p["name"] for p in view["vehicles"][0]["parts"]] == [c.name for c in clicks(NAMED)[:2]]
    status, doc = client.edit({"op": "set_vehicle", "vehicle": "1", "done": True})
    assert status == 409 and "changed on disk" in doc["error"]
    assert (tmp_path / "annotations.json").read_text() == '{"toosicubix": 1, "images": ['


# -- the page never saves what fit would refuse -----------------------------------------------------------------------

#: What the readers' field rules (toosicubix.fields) say of a pixel coordinate out of the schema's bounds.
PIXEL = "expected a pixel coordinate from -1000000 to 1000000, got"


@pytest.mark.parametrize(("change", "field", "expected"), [
    ({"op": "set_vehicle", "vehicle": "1", "box2d": [0, 0, 1e308, 1e308]}, "box2d[2]", f"{PIXEL} 1e+308"),
    ({"op": "add_click", "vehicle": "1", "uv": [[5e6, 5e6]]}, "uv[0][0]", f"{PIXEL} 5000000"),
    ({"op": "add_click", "vehicle": "1", "uv": [[-1e300, 1]]}, "uv[0][0]", f"{PIXEL} -1e+300"),
    ({"op": "add_click", "vehicle": "1", "uv": [[10**400, 1]]}, "uv[0][0]", "an integer of 401 digits"),
    ({"op": "add_click", "vehicle": "1", "kind": "length", "name": "plate-rear", "uv": [[10.0, 10.0], [20.0, 10.0]],
      "known": [1e308, 1e-300]}, "known[0]", "expected a size in metres greater than 0 and at most 100, got 1e+308"),
    ({"op": "add_click", "vehicle": "1", "kind": "length", "name": "plate-rear", "uv": [[10.0, 10.0], [20.0, 10.0]],
      "known": [0.5, 1e-300]}, "known[1]", "expected a sigma in metres from 0.0001 to 100, got 1e-300"),
    # The synthetic image is 1240 x 375 px: 10 % around it is x in [-124, 1364], y in [-37.5, 412.5].
    ({"op": "add_click", "vehicle": "1", "uv": [[600, 413]]}, "uv[0]",
     "outside the 1240 x 375 image by more than 10 %"),
    ({"op": "add_click", "vehicle": "1", "uv": [[-125, 100]]}, "uv[0]", "expected x within [-124, 1364]"),
    ({"op": "add_click", "vehicle": "1", "kind": "symmetry", "name": "rear", "uv": [[600, 200], [1400, 200]]},
     "uv[1]", "outside the 1240 x 375 image"),
    ({"op": "set_vehicle", "vehicle": "1", "box2d": [100, 100, 1500, 300]}, "box2d[2:4]", "outside the 1240 x 375"),
    ({"op": "move_click", "vehicle": "1", "part": 0, "uv": [600, 5000]}, "uv", "outside the 1240 x 375 image"),
    ({"op": "add_click", "vehicle": "1", "uv": [[float("nan"), 1]]}, "uv[0][0]", f"{PIXEL} nan"),
])
def test_edits_fit_would_refuse_get_400_naming_the_field(served, tmp_path, change, field, expected):
    """Issue 34: each of these was saved (200) and then `validate`, `fit` and `annotate` refused the file. Now 400
    naming the field, and the file stays as it was."""
    client, _ = served
    assert client.edit({"op": "add_vehicle"})[0] == 200
    assert client.edit({"op": "add_click", "vehicle": "1", "uv": [[600, 200]]})[0] == 200
    before = (tmp_path / "annotations.json").read_bytes(), session_extras(tmp_path)
    status, doc = client.edit(change)
    assert status == 400 and doc["error"].startswith(f"{field}: ") and expected in doc["error"], doc
    assert ((tmp_path / "annotations.json").read_bytes(), session_extras(tmp_path)) == before


def session_extras(folder: Path) -> bytes | None:
    path = folder / "annotations.json.annotate.json"
    return path.read_bytes() if path.exists() else None


def test_clicks_within_the_margin_are_kept_and_the_file_reads_back(served, tmp_path):
    """A wheel cut off by the image's edge is clicked a little outside it: within 10 % of the image's size it is
    kept, and what the page saved is a file `validate` reads."""
    client, _ = served
    assert client.edit({"op": "add_vehicle", "box2d": [-100, 10, 1300, 400]})[0] == 200
    status, doc = client.edit({"op": "add_click", "vehicle": "1", "kind": "point", "name": "wheel-front-left",
                               "uv": [[-120.0, 410.0]]})
    assert status == 200, doc
    assert validate_main(["validate", str(tmp_path / "annotations.json")]) in (0, 1)


def validate_main(args: list[str]) -> int:
    from click.testing import CliRunner

    from toosicubix.cli import main

    result = CliRunner().invoke(main, args)
    assert result.exception is None or isinstance(result.exception, SystemExit), result.output
    return result.exit_code


def test_a_vehicle_has_at_most_the_clicks_a_file_may_hold(scene, tmp_path):
    """A vehicle with MAX_CLICKS_PER_VEHICLE clicked points (here unnamed ones, read back from the extras file) takes
    no more: a file with one more is one `fit` refuses."""
    out = tmp_path / "annotations.json"
    session = make_session(scene, out)
    session.edit(0, {"revision": 0, "op": "add_vehicle"})
    extras = {"toosicubix_annotate": 1, "images": {"car": {"1": {
        "done": False, "unnamed": [[100.0 + k, 200.0] for k in range(MAX_CLICKS_PER_VEHICLE)]}}}}
    session.extras_path.write_text(json.dumps(extras))
    resumed = make_session(scene, out)
    with pytest.raises(ApiError, match=f"has {MAX_CLICKS_PER_VEHICLE} clicked points") as refused:
        resumed.edit(0, {"revision": resumed.revision, "op": "add_click", "vehicle": "1", "uv": [[50.0, 60.0]]})
    assert refused.value.status == 400


def test_an_image_takes_at_most_max_vehicles(scene, tmp_path, monkeypatch):
    monkeypatch.setattr(session_module, "MAX_VEHICLES_PER_IMAGE", 3)
    session = make_session(scene, tmp_path / "annotations.json")
    for _ in range(3):
        session.edit(0, {"revision": session.revision, "op": "add_vehicle"})
    with pytest.raises(ApiError, match="has 3 vehicles, as many as the page adds"):
        session.edit(0, {"revision": session.revision, "op": "add_vehicle"})


@pytest.mark.parametrize("odd_id", ["²", "٣", "007", "9" * 30])
def test_vehicle_ids_validate_accepts_do_not_break_add_vehicle(scene, tmp_path, odd_id):
    """Issue 34: a vehicle id '²' (which `validate` accepts; str.isdigit passes it, int refuses it) made every
    add_vehicle on its image a 500. Ids of other digits, or too many of them, are left alone."""
    out = tmp_path / "annotations.json"
    session = make_session(scene, out)
    session.edit(0, {"revision": 0, "op": "add_vehicle"})
    document = json.loads(out.read_text())
    document["images"][0]["vehicles"][0]["id"] = odd_id
    out.write_text(json.dumps(document))
    resumed = make_session(scene, out)
    view = resumed.edit(0, {"revision": resumed.revision, "op": "add_vehicle"})
    assert [v["id"] for v in view["vehicles"]] == [odd_id, "1" if odd_id != "007" else "8"]


def test_track_names_of_other_digits_do_not_break_the_view(tmp_path):
    """A track named '²' (or of 40 digits) on a frame: the page orders tracks by their ASCII digits only."""
    paths, cameras = write_sequence(tmp_path, frames=2)
    out = tmp_path / "annotations.json"
    session = Session(paths, out, load_cameras(cameras, [p.stem for p in paths]), load_priors(), sequence="0003")
    session.edit(0, {"revision": 0, "op": "add_vehicle"})
    session.edit(0, {"revision": session.revision, "op": "add_vehicle"})
    document = json.loads(out.read_text())
    document["images"][0]["vehicles"][0]["track"] = "²"
    document["images"][0]["vehicles"][1]["track"] = "1" * 40
    out.write_text(json.dumps(document))
    resumed = Session(paths, out, load_cameras(cameras, [p.stem for p in paths]), load_priors(), sequence="0003")
    view = resumed.image_view(1)
    assert {p["track"] for p in view["predictions"]} == {"²", "1" * 40}


# -- JSON-only, same-origin POSTs ----------------------------------------------------------------------------------

def _raw(client, method: str, path: str, body: bytes = b"", headers: dict | None = None) -> tuple[int, dict]:
    connection = http.client.HTTPConnection(client.host, client.port, timeout=30)
    try:
        connection.request(method, path, body=body, headers=headers or {})
        response = connection.getresponse()
        return response.status, json.loads(response.read())
    finally:
        connection.close()


def test_a_form_post_cannot_reload(served):
    """Issue 34: any web page could make the browser send a plain form post to /api/reload (it bumped the revision
    and dropped the undo history). Every POST now needs a JSON body."""
    client, session = served
    for kind in ("application/x-www-form-urlencoded", "text/plain", "multipart/form-data; boundary=x"):
        status, doc = _raw(client, "POST", "/api/reload", b"a=1", {"Content-Type": kind})
        assert status == 415 and "expected Content-Type application/json" in doc["error"]
    status, doc = _raw(client, "POST", "/api/reload", b"", {})
    assert status == 415
    assert session.revision == 0


@pytest.mark.parametrize(("headers", "expected"), [
    ({"Origin": "http://evil.example"}, "a request from 'http://evil.example'"),
    ({"Origin": "null"}, "a request from 'null'"),
    ({"Origin": "http://localhost:1"}, "may not change the annotations"),
    ({"Sec-Fetch-Site": "cross-site"}, "a cross-site request may not change"),
    ({"Sec-Fetch-Site": "same-site"}, "a same-site request may not change"),
])
def test_posts_from_another_origin_are_refused(served, headers, expected):
    client, session = served
    for path in ("/api/reload", "/api/save", "/api/images/0/edit", "/api/fit"):
        status, doc = _raw(client, "POST", path, b'{"revision": 0, "op": "add_vehicle"}',
                           {"Content-Type": "application/json", **headers})
        assert status == 403 and expected in doc["error"], (path, doc)
    assert session.revision == 0 and not session.out.exists()


def test_posts_from_the_page_itself_pass(served):
    client, _ = served
    origin = f"http://{client.host}:{client.port}"
    status, doc = _raw(client, "POST", "/api/images/0/edit", b'{"revision": 0, "op": "add_vehicle"}',
                       {"Content-Type": "application/json", "Origin": origin, "Sec-Fetch-Site": "same-origin"})
    assert status == 200 and doc["vehicle"] == "1"


@pytest.mark.parametrize(("path", "body", "headers", "status", "expected"), [
    ("/api/reload", b"[" * 5000, {}, 400, "nests arrays and objects 5000 deep"),
    ("/api/images/0/edit", b'{"revision": ' + b"9" * 5000 + b"}", {}, 400, "not JSON this server reads"),
    ("/api/images/0/edit", b'{"revision": 0', {}, 400, "not JSON at line 1 column 15"),
    ("/api/images/0/edit", b"\xff\xfe", {}, 400, "not UTF-8 JSON"),
    ("/api/images/0/edit", b"{}", {"Content-Length": "\u00b2"}, 411, "Content-Length"),
    ("/api/images/0/edit", b"{}", {"Content-Length": "1" * 20}, 411, "Content-Length"),
    ("http://[", b"{}", {}, 400, "a request target this server cannot read: Invalid IPv6 URL"),
])
def test_malformed_requests_get_4xx_not_500(served, path, body, headers, status, expected):
    client, _ = served
    connection = http.client.HTTPConnection(client.host, client.port, timeout=30)
    try:
        connection.putrequest("POST", path, skip_host=True, skip_accept_encoding=True)
        connection.putheader("Host", f"127.0.0.1:{client.port}")
        connection.putheader("Content-Type", "application/json")
        connection.putheader("Content-Length", headers.get("Content-Length", str(len(body))))
        connection.endheaders(body)
        response = connection.getresponse()
        got, doc = response.status, json.loads(response.read())
    finally:
        connection.close()
    assert got == status and expected in doc["error"], doc


# -- stalled connections ---------------------------------------------------------------------------------------------

def _stall(address, count: int, partial: bytes) -> list[socket.socket]:
    out = []
    for _ in range(count):
        s = socket.create_connection(address, timeout=30)
        s.sendall(partial)
        out.append(s)
    return out


def test_stalled_connections_do_not_lock_the_page_out(scene, tmp_path):
    """Issue 34: a few hundred connections that send half a request and wait. At most max_connections are served
    at once; each new one closes the one that has waited longest for its client, so the page's requests are
    answered at once all along."""
    session = make_session(scene, tmp_path / "a.json")
    server = serve_in_thread(session, max_connections=16)
    address = server.server_address[:2]
    client = Client(*address, timeout=30)
    stalled = []
    try:
        for partial in (b"GET /api/session HTTP/1.1\r\nHost: 127.0.0.1\r\n",  # headers never finished
                        b"POST /api/images/0/edit HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
                        b"Content-Length: 100\r\n\r\n{\"revision\": 0"):  # a body never finished
            stalled += _stall(address, 150, partial)
            started = time.monotonic()
            status, doc = client.request("GET", "/api/session")
            assert status == 200 and doc["images"][0]["id"] == "car"
            assert client.edit({"op": "add_vehicle"})[0] == 200
            assert time.monotonic() - started < 5.0  # generous: a hang would be READ_TIMEOUT or more
            assert server.connections <= 16
    finally:
        for s in stalled:
            s.close()
        server.shutdown()
        server.server_close()


def test_a_stalled_body_times_out_with_408(scene, tmp_path):
    session = make_session(scene, tmp_path / "a.json")
    server = serve_in_thread(session, read_timeout=0.5)
    try:
        (s,) = _stall(server.server_address[:2], 1, b"POST /api/images/0/edit HTTP/1.1\r\nHost: 127.0.0.1\r\n"
                      b"Content-Type: application/json\r\nContent-Length: 100\r\n\r\n{")
        s.settimeout(30)
        answer = b""
        while chunk := s.recv(4096):  # the headers and the body may come in two pieces; then closed
            answer += chunk
        assert answer.startswith(b"HTTP/1.1 408") and b"did not arrive within 0.5 s" in answer
        s.close()
        assert Client(*server.server_address[:2]).request("GET", "/api/session")[0] == 200
        assert session.revision == 0
    finally:
        server.shutdown()
        server.server_close()


# -- the time bound on refits (issue 34, item 4) -------------------------------------------------------------------


def test_a_refit_over_the_bound_answers_422_within_it_and_leaves_the_files_as_they_were(scene, tmp_path):
    """The fits run in a process of their own, ended when late. With the bound lowered to 2 ms, a change whose refit
    takes longer (a fresh fit of five named parts: tens of milliseconds) is refused with 422 well within a second,
    nothing is written and the revision stays; the view shows the vehicle as not fitted in time; with the bound as
    shipped, the same change is saved."""
    out = tmp_path / "annotations.json"
    session = make_session(scene, out)
    server = serve_in_thread(session, bound_fits=True)
    try:
        client = Client(*server.server_address[:2])
        assert client.edit({"op": "add_vehicle"})[0] == 200
        named = clicks(NAMED)
        for c in named[:-1]:
            change = {"op": "add_click", "vehicle": "1", "kind": c.kind, "name": c.name, "uv": c.uv}
            assert client.edit(change)[0] == 200
        files = out.read_bytes(), session.extras_path.exists()
        revision = session.revision
        session.fit_seconds = 0.002
        last = {"op": "add_click", "vehicle": "1", "kind": named[-1].kind, "name": named[-1].name, "uv": named[-1].uv}
        started = time.monotonic()
        status, doc = client.edit(last, revision=revision)
        answered = time.monotonic() - started
        assert status == 422, doc
        assert "did not finish within 0.002 s" in doc["error"] and "nothing was changed" in doc["error"]
        assert answered < 1.0, answered
        assert (out.read_bytes(), session.extras_path.exists()) == files
        assert session.revision == revision and len(session.images[0].vehicles[0].parts) == len(named) - 1
        assert server.fitter.killed >= 1  # ended, not waited for
        session.fit_seconds = session_module.FIT_SECONDS
        status, doc = client.edit(last)
        assert status == 200 and doc["vehicles"][0]["fit"]["status"] == "ok", doc
        assert len(json.loads(out.read_text())["images"][0]["vehicles"][0]["parts"]) == len(named)
        assert client.request("POST", "/api/reload", {})[0] == 200  # the fits made before are forgotten
        session.fit_seconds = 0.002
        status, view = client.request("GET", "/api/images/0")  # a view answers, the fit it could not make said so
        assert status == 200 and view["vehicles"][0]["fit"]["error"] == "out_of_time", view["vehicles"][0]["fit"]
        assert "did not finish within 0.002 s" in view["vehicles"][0]["fit"]["error_detail"]
    finally:
        server.shutdown()
        server.server_close()
    assert server.fitter is None  # its processes ended with the server


@pytest.mark.parametrize("value", [0.0, 1e6, -1e6, 1e6 + 1e-3, -1e6 - 1e-3, 10**6, 10**400, float("nan"),
                                   float("inf"), -float("inf"), True, "1", None, [1.0]])
def test_the_page_and_the_file_readers_take_the_same_pixels(value):
    """One rule: a click coordinate the page takes (before its on-the-image check) is one the annotation file's schema
    reads, and a number it refuses is one the schema refuses too. (The schema, in pydantic's lax mode, also reads
    ``true`` and ``"1"`` as 1.0, which the readers' field rules and the page refuse: the page is the stricter.)"""
    from toosicubix.annotations.schema import parse_annotations
    from toosicubix.errors import InputFileError
    from toosicubix.fields import pixel
    from toosicubix.web.request_fields import checked_number

    document = {"toosicubix": 1, "images": [{"id": "a", "camera": {"K": [[700, 0, 600], [0, 700, 180], [0, 0, 1]]},
                                             "vehicles": [{"id": "1", "prototype": "Car", "parts": [
                                                 {"kind": "point", "part": "wheel-front-left", "xy": [value, 1.0]}]}]}]}
    try:
        parse_annotations(document, "file")
        file_reads = True
    except InputFileError:
        file_reads = False
    try:
        checked_number(value, "uv[0][0]", pixel)
        page_takes = True
    except ApiError as exc:
        assert str(exc).startswith("uv[0][0]: expected a pixel coordinate from -1000000 to 1000000, got ")
        page_takes = False
    assert file_reads or not page_takes
    if isinstance(value, int | float) and not isinstance(value, bool):
        assert page_takes == file_reads
