"""Issue 34 on the annotate page: nothing a person did is lost or locked away, nothing crashes, nothing spins.

Two servers on one file, edits the file's readers would refuse, cross-site and malformed requests, stalled
connections, ids and images that used to crash the page, and the time bound on refits."""

from __future__ import annotations

import json

from tests.web.conftest import make_session, serving
from tests.web.synthetic import NAMED, UNNAMED, clicks

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
