"""The JSON API of ``toosicubix annotate`` against a real server on an ephemeral 127.0.0.1 port."""

from __future__ import annotations

import http.client
import json
import threading

import numpy as np
import pytest

from tests.web.conftest import make_session
from tests.web.synthetic import DIMENSIONS, NAMED, R_CAM_VEHICLE, T_CAM_VEHICLE, UNNAMED, clicks
from toosicubix.annotations.convert import load_images
from toosicubix.annotations.priors_file import load_priors
from toosicubix.errors import InputFileError
from toosicubix.geometry import geodesic_angle
from toosicubix.model import KITTI_GROUND
from toosicubix.web.client import Client
from toosicubix.web.request_fields import ApiError
from toosicubix.web.server import serve_in_thread
from toosicubix.web.session import Session, load_cameras


def _add_vehicle(client) -> str:
    status, doc = client.edit({"op": "add_vehicle"})
    assert status == 200, doc
    return doc["vehicle"]


def _click_named(client, vehicle: str) -> dict:
    for c in clicks(NAMED):
        status, doc = client.edit({"op": "add_click", "vehicle": vehicle, "kind": c.kind, "name": c.name, "uv": c.uv})
        assert status == 200, doc
    return doc


def test_session_lists_images_without_paths(served):
    client, _ = served
    status, doc = client.request("GET", "/api/session")
    assert status == 200
    assert doc["images"] == [{"index": 0, "id": "car", "size": [1240, 375], "vehicles": 0, "done": 0}]
    assert "Car" in doc["prototypes"] and doc["revision"] == 0
    assert "path" not in json.dumps(doc)


def test_clicks_refit_and_draw_the_true_cuboid(served, tmp_path):
    client, _ = served
    vehicle = _add_vehicle(client)
    doc = _click_named(client, vehicle)
    v = doc["vehicles"][0]
    fit = v["fit"]
    assert fit["status"] == "ok", fit
    # Exact clicks on parts at their modelled places: the pose comes back up to the prior's pull on the scale
    # (6 constraints: the clicks fix the shape only partly), so rotation within 1 degree, depth within 10 %.
    assert np.rad2deg(geodesic_angle(np.array(fit["R_cam_vehicle"]), R_CAM_VEHICLE)) < 1.0
    assert abs(fit["t_cam_vehicle"][2] / T_CAM_VEHICLE[2] - 1) < 0.10
    assert len(fit["corners_uv"]) == 8 and fit["front_face"] == [0, 3, 7, 4]
    assert fit["sigma"]["yaw_deg"] > 0 and fit["sigma"]["depth_rel"] > 0
    assert all(p["residuals_px"] is not None for p in v["parts"])
    assert max(abs(r) for p in v["parts"] for row in p["residuals_px"] for r in row) < 1.0
    assert v["targets"], "the page shows the next best parts"
    assert all(t["visible"] and t["inside_image"] for t in v["targets"])
    # The file is written after every change and `fit` reads it.
    images = load_images(tmp_path / "annotations.json")
    assert [p.name for p in images[0].vehicles[0].parts] == [s.name for s in NAMED]


def test_an_unnamed_first_click_asks_and_the_prior_cuboid_names_the_next(scene, tmp_path):
    """Issue 33 item 1: a first click, with nothing to place the vehicle, waits for a name and offers the wheels (the
    parts that can be below the horizon of a camera above the road); once one click is named, the prior cuboid
    names the next ones before any fit exists (here with KITTI's ground block: the synthetic camera is 1.65 m above
    the road), each with its probability and the other names that fit there."""
    image, cameras = scene
    session = Session([image], tmp_path / "a.json", load_cameras(cameras, [image.stem]), load_priors(),
                      ground=KITTI_GROUND)
    server = serve_in_thread(session)
    try:
        client = Client(*server.server_address[:2])
        vehicle = _add_vehicle(client)
        first, second = clicks(NAMED)[:2]  # the front left and rear left wheels
        status, doc = client.edit({"op": "add_click", "vehicle": vehicle, "uv": first.uv})
        assert status == 200 and doc["auto_named"] == []
        waiting = doc["vehicles"][0]["parts"][0]
        assert waiting["name"] is None and doc["vehicles"][0]["unnamed"] == 1
        offered = [c["name"] for c in waiting["choices"]]
        assert set(offered[:4]) == {"wheel-front-left", "wheel-front-right", "wheel-rear-left", "wheel-rear-right"}
        assert sum(c["probability"] for c in waiting["choices"][:4]) > 0.95  # the rest: a few per cent
        status, doc = client.edit({"op": "rename", "vehicle": vehicle, "part": 0, "kind": "point", "name": first.name})
        assert status == 200 and doc["vehicles"][0]["parts"][0]["choices"] is None  # the person's name now
        status, doc = client.edit({"op": "add_click", "vehicle": vehicle, "uv": second.uv})
        (auto,) = doc["auto_named"]
        assert doc["vehicles"][0]["fit"]["status"] == "failed"  # no fit yet: two clicks
        assert (auto["name"], auto["how"]) == (second.name, "prior") and auto["probability"] > 0.5
        assert auto["runner_up"] != second.name
        part = doc["vehicles"][0]["parts"][1]
        assert part["auto"]["name"] == second.name and second.name not in [c["name"] for c in part["choices"]]
    finally:
        server.shutdown()
        server.server_close()


def test_without_a_ground_block_the_page_asks_when_unsure_offering_the_true_name_first(served):
    """The same second wheel without a ground block (the camera's height only assumed, 1.5 +- 1 m): less than half
    the probability, so the page asks; the true name is the first it offers."""
    client, _ = served
    vehicle = _add_vehicle(client)
    first, second = clicks(NAMED)[:2]
    client.edit({"op": "add_click", "vehicle": vehicle, "kind": "point", "name": first.name, "uv": first.uv})
    status, doc = client.edit({"op": "add_click", "vehicle": vehicle, "uv": second.uv})
    assert status == 200 and doc["auto_named"] == []
    part = doc["vehicles"][0]["parts"][1]
    assert part["name"] is None and part["choices"][0]["name"] == second.name
    assert part["choices"][0]["probability"] < 0.5


def test_unnamed_clicks_are_named_as_they_come(served):
    client, _ = served
    vehicle = _add_vehicle(client)
    doc = _click_named(client, vehicle)
    for c in clicks(UNNAMED):
        status, doc = client.edit({"op": "add_click", "vehicle": vehicle, "uv": c.uv})
        assert status == 200
        (auto,) = doc["auto_named"]
        assert (auto["name"], auto["how"]) == (c.name, "fit") and auto["runner_up"] != c.name
    parts = doc["vehicles"][0]["parts"]
    assert all(p["name"] is not None for p in parts)
    assert doc["vehicles"][0]["fit"]["well_determined"]


def test_a_click_far_from_every_part_of_the_fitted_vehicle_says_so(served):
    """A newcomer's click on the road beside a fitted car was left unnamed with "the page is not sure" while its one
    choice read 100 %: the click was far from every part, which the page did not say. Its choices now carry
    ``far``, which the page's question reads ("far from every part of the fitted vehicle"); a click on a part
    does not."""
    client, _ = served
    vehicle = _add_vehicle(client)
    _click_named(client, vehicle)
    status, doc = client.edit({"op": "add_click", "vehicle": vehicle, "uv": [[40.0, 30.0]]})
    assert status == 200 and not doc["auto_named"]
    waiting = doc["vehicles"][0]["parts"][-1]
    assert waiting["name"] is None and waiting["choices"] and all(c.get("far") for c in waiting["choices"])
    status, doc = client.edit({"op": "add_click", "vehicle": vehicle, "uv": clicks(UNNAMED)[0].uv})
    assert status == 200 and doc["auto_named"]
    *_, still_waiting, named = doc["vehicles"][0]["parts"]
    assert named["name"] == clicks(UNNAMED)[0].name and not any(c.get("far") for c in named.get("choices") or [])
    assert still_waiting["name"] is None and all(c.get("far") for c in still_waiting["choices"])


def test_any_click_can_be_renamed(served, tmp_path):
    """A click named by the person is renamed in place (its place kept), in the file too; a rename to a name another
    click has is refused, naming it."""
    client, _ = served
    vehicle = _add_vehicle(client)
    _click_named(client, vehicle)
    status, doc = client.edit({"op": "rename", "vehicle": vehicle, "part": 0, "kind": "point",
                               "name": "wheel-front-right"})
    assert status == 200
    renamed = load_images(tmp_path / "annotations.json")[0].vehicles[0].parts[0]
    assert renamed.name == "wheel-front-right" and renamed.uv.tolist() == clicks(NAMED)[0].uv
    status, doc = client.edit({"op": "rename", "vehicle": vehicle, "part": 0, "kind": "point",
                               "name": "wheel-rear-left"})
    assert status == 400 and "has a point 'wheel-rear-left' already" in doc["error"]


def test_a_name_another_click_holds_is_swapped_in_one_undoable_edit(served, tmp_path):
    """Issue 33 follow-up, friction 2: two clicks given each other's names are put right in one edit, ``rename`` with
    ``swap`` (the other click takes this one's old name), which one undo takes back; the file holds each edit. A
    pair's name is not swapped onto one click, and without ``swap`` the refusal says how to swap."""
    client, _ = served
    vehicle = _add_vehicle(client)
    _click_named(client, vehicle)
    original = [p.name for p in load_images(tmp_path / "annotations.json")[0].vehicles[0].parts]
    status, doc = client.edit({"op": "rename", "vehicle": vehicle, "part": 0, "kind": "point",
                               "name": "wheel-rear-left"})
    assert status == 400 and "part 1" in doc["error"] and '"swap": true' in doc["error"]
    status, doc = client.edit({"op": "rename", "vehicle": vehicle, "part": 0, "kind": "point",
                               "name": "wheel-rear-left", "swap": True})
    assert status == 200 and doc["swapped_with"] == 1
    parts = doc["vehicles"][0]["parts"]
    assert [p["name"] for p in parts[:2]] == ["wheel-rear-left", "wheel-front-left"]
    assert [p["uv"] for p in parts[:2]] == [c.uv for c in clicks(NAMED)[:2]]  # the names moved, not the clicks
    saved = load_images(tmp_path / "annotations.json")[0].vehicles[0].parts
    assert [p.name for p in saved] == ["wheel-rear-left", "wheel-front-left", *original[2:]]
    status, doc = client.edit({"op": "undo"})
    assert status == 200 and [p["name"] for p in doc["vehicles"][0]["parts"]] == original
    assert [p.name for p in load_images(tmp_path / "annotations.json")[0].vehicles[0].parts] == original
    status, doc = client.edit({"op": "rename", "vehicle": vehicle, "part": 0, "kind": "symmetry", "name": "front",
                               "swap": True})
    assert status == 400 and doc["error"].startswith("swap: 'front' is a symmetry of 2 click(s)")
    status, doc = client.edit({"op": "rename", "vehicle": vehicle, "part": 0, "kind": "point",
                               "name": "wheel-rear-left", "swap": "yes"})
    assert status == 400 and doc["error"] == "swap: expected true or false, got 'yes'"


def test_an_unnamed_click_takes_a_held_name_and_the_holder_waits_for_one(served):
    """Naming a waiting click with a name another click holds, with ``swap``: the holder gives it up and waits for a
    name (or the page names it again, never with the name it gave)."""
    client, _ = served
    vehicle = _add_vehicle(client)
    first, second = clicks(NAMED)[:2]
    client.edit({"op": "add_click", "vehicle": vehicle, "uv": second.uv})
    status, doc = client.edit({"op": "add_click", "vehicle": vehicle, "kind": "point", "name": first.name,
                               "uv": first.uv})
    assert doc["vehicles"][0]["parts"][0]["name"] is None  # the page is not sure of it (see above)
    status, doc = client.edit({"op": "rename", "vehicle": vehicle, "part": 0, "kind": "point", "name": first.name,
                               "swap": True})
    assert status == 200 and doc["swapped_with"] == 1
    waiting, holder = doc["vehicles"][0]["parts"]
    assert waiting["name"] == first.name and waiting["auto"] is None
    assert holder["name"] is None or (holder["auto"] is not None and holder["name"] != first.name)


def test_auto_name_changed_to_runner_up(served):
    client, _ = served
    vehicle = _add_vehicle(client)
    _click_named(client, vehicle)
    status, doc = client.edit({"op": "add_click", "vehicle": vehicle, "uv": clicks(UNNAMED)[0].uv})
    (auto,) = doc["auto_named"]
    status, doc = client.edit({"op": "rename", "vehicle": vehicle, "part": auto["part"], "kind": "point",
                               "name": auto["runner_up"]})
    assert status == 200
    part = doc["vehicles"][0]["parts"][auto["part"]]
    assert part["name"] == auto["runner_up"] and part["auto"] is None


def test_undo_move_delete_and_done(served, tmp_path):
    client, _ = served
    vehicle = _add_vehicle(client)
    doc = _click_named(client, vehicle)
    n = len(doc["vehicles"][0]["parts"])
    status, doc = client.edit({"op": "undo"})
    assert status == 200 and len(doc["vehicles"][0]["parts"]) == n - 1
    status, doc = client.edit({"op": "move_click", "vehicle": vehicle, "part": 0, "click": 0, "uv": [600.5, 300.25]})
    assert status == 200 and doc["vehicles"][0]["parts"][0]["uv"] == [[600.5, 300.25]]
    status, doc = client.edit({"op": "delete_click", "vehicle": vehicle, "part": 0})
    assert status == 200 and len(doc["vehicles"][0]["parts"]) == n - 2
    status, doc = client.edit({"op": "set_vehicle", "vehicle": vehicle, "done": True, "box2d": [500, 150, 900, 330]})
    assert status == 200 and doc["vehicles"][0]["done"] and doc["vehicles"][0]["box2d"] == [500, 150, 900, 330]
    saved = load_images(tmp_path / "annotations.json")[0].vehicles[0]
    assert len(saved.parts) == n - 2 and saved.box2d.tolist() == [500, 150, 900, 330]
    first = clicks(NAMED)[0].uv
    for _ in range(3):  # takes back the box and done, the delete, the move (an undo is not itself undone)
        status, doc = client.edit({"op": "undo"})
        assert status == 200
    v = doc["vehicles"][0]
    assert len(v["parts"]) == n - 1 and v["parts"][0]["uv"] == first and not v["done"] and v["box2d"] is None


def test_resume_an_existing_file(served, scene, tmp_path):
    client, _ = served
    vehicle = _add_vehicle(client)
    _click_named(client, vehicle)
    before = (tmp_path / "annotations.json").read_text()
    resumed = make_session(scene, tmp_path / "annotations.json")
    view = resumed.image_view(0)
    assert [p["name"] for p in view["vehicles"][0]["parts"]] == [s.name for s in NAMED]
    assert view["vehicles"][0]["fit"]["status"] == "ok"
    resumed.edit(0, {"revision": 0, "op": "add_click", "vehicle": vehicle, "uv": clicks(UNNAMED)[0].uv})
    after = load_images(tmp_path / "annotations.json")[0].vehicles[0]
    assert len(after.parts) == len(NAMED) + 1 and before != (tmp_path / "annotations.json").read_text()


def test_stale_revision_is_refused_and_nothing_is_lost(served, tmp_path):
    client, _ = served
    vehicle = _add_vehicle(client)
    revision = client.request("GET", "/api/session")[1]["revision"]
    a, b = clicks(NAMED)[:2]
    status, _ = client.edit({"op": "add_click", "vehicle": vehicle, "kind": a.kind, "name": a.name, "uv": a.uv},
                            revision)
    assert status == 200
    status, doc = client.edit({"op": "add_click", "vehicle": vehicle, "kind": b.kind, "name": b.name, "uv": b.uv},
                              revision)
    assert status == 409 and "stale revision" in doc["error"]
    status, doc = client.edit({"op": "add_click", "vehicle": vehicle, "kind": b.kind, "name": b.name, "uv": b.uv})
    assert status == 200
    saved = load_images(tmp_path / "annotations.json")[0].vehicles[0]
    assert [p.name for p in saved.parts] == [a.name, b.name]


def test_concurrent_pages_never_lose_a_click(served, tmp_path):
    """Eight pages add a click each at once, re-applying it after a 409 as the page does."""
    client, _ = served
    vehicle = _add_vehicle(client)
    rng = np.random.default_rng(0)
    points = rng.uniform([100, 100], [1100, 300], (8, 2)).round(2).tolist()
    errors = []

    def page(uv):
        for _ in range(50):
            status, doc = client.edit({"op": "add_click", "vehicle": vehicle, "uv": [uv]})
            if status == 200:
                return
            if status != 409:
                errors.append(doc)
                return
        errors.append("gave up")

    threads = [threading.Thread(target=page, args=(uv,)) for uv in points]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    view = client.request("GET", "/api/images/0")[1]
    assert sorted(p["uv"][0] for p in view["vehicles"][0]["parts"]) == sorted(points)


def test_file_changed_by_another_program_is_refused(served, scene, tmp_path):
    client, _ = served
    vehicle = _add_vehicle(client)
    other = make_session(scene, tmp_path / "annotations.json")  # a second `toosicubix annotate` on the file
    c = clicks(NAMED)[0]
    other.edit(0, {"revision": 0, "op": "add_click", "vehicle": vehicle, "kind": c.kind, "name": c.name,
                   "uv": c.uv})
    status, doc = client.edit({"op": "add_vehicle"})
    assert status == 409 and "changed on disk by another program" in doc["error"]
    assert len(load_images(tmp_path / "annotations.json")[0].vehicles[0].parts) == 1  # the other's click kept
    status, doc = client.request("POST", "/api/reload", {})
    assert status == 200
    view = client.request("GET", "/api/images/0")[1]
    assert [p["name"] for p in view["vehicles"][0]["parts"]] == [c.name]


def test_fit_endpoint_fits_without_storing(served):
    client, _ = served
    parts = [{"kind": "point", "part": c.name, "xy": c.uv[0]} if c.kind == "point" else
             {"kind": "symmetry", "face": c.name, "left": c.uv[0], "right": c.uv[1]} for c in clicks(NAMED)]
    status, doc = client.request("POST", "/api/fit", {"image": 0, "vehicle": {"id": "9", "prototype": "Car",
                                                                            "parts": parts}})
    assert status == 200 and doc["fit"]["status"] == "ok"
    assert np.allclose(doc["fit"]["dimensions"], DIMENSIONS, rtol=0.1)
    assert client.request("GET", "/api/images/0")[1]["vehicles"] == []
    status, doc = client.request("POST", "/api/fit", {"image": 0, "vehicle": {"id": "9", "prototype": "Car",
                                                                            "parts": [{"kind": "point"}]}})
    assert status == 400 and "vehicle.parts[0]" in doc["error"]


def test_save_endpoint(served, tmp_path):
    client, _ = served
    status, doc = client.request("POST", "/api/save", {"revision": 0})
    assert status == 200 and doc["saved"]
    assert load_images(tmp_path / "annotations.json")[0].id == "car"


@pytest.mark.parametrize(("change", "status", "message"), [
    ({"op": "fly"}, 400, "op: expected one of"),
    ({"op": "add_click", "vehicle": "1", "uv": [[1, 2]], "kind": "point", "name": "wheel-middle"}, 400,
     "name: expected a point name"),
    ({"op": "add_click", "vehicle": "1", "uv": [[1, "a"]]}, 400,
     "uv[0][1]: expected a pixel coordinate from -1000000 to 1000000, got 'a'"),
    ({"op": "add_click", "vehicle": "1", "kind": "symmetry", "name": "rear", "uv": [[1, 2]]}, 400,
     "uv: expected 2 pixels"),
    ({"op": "add_click", "vehicle": "7", "uv": [[1, 2]]}, 400, "vehicle: no vehicle '7'"),
    ({"op": "add_vehicle", "prototype": "Spaceship"}, 400, "prototype: unknown 'Spaceship'"),
    ({"op": "add_vehicle", "box2d": [10, 10, 5, 20]}, 400, "box2d: expected x1 < x2"),
    ({"op": "delete_click", "vehicle": "1", "part": 3}, 400, "part: expected an index"),
])
def test_bad_changes_get_400_with_a_message(served, change, status, message):
    client, _ = served
    _add_vehicle(client)
    got, doc = client.edit(change)
    assert got == status and message in doc["error"], doc


def test_bad_requests(served):
    client, _ = served
    status, doc = client.request("POST", "/api/images/0/edit", raw=b"{not json")
    assert status == 400 and "not JSON at line 1 column 2" in doc["error"]
    status, doc = client.request("POST", "/api/images/0/edit", {"op": "undo"})
    assert status == 400 and "revision" in doc["error"]
    status, doc = client.request("POST", "/api/images/5/edit", {"revision": 0, "op": "undo"})
    assert status == 404 and "no image 5" in doc["error"]
    status, doc = client.request("POST", "/api/images/0/edit", {"revision": 0, "op": "undo"})
    assert status == 400 and "nothing to undo" in doc["error"]
    status, doc = client.request("POST", "/api/nothing", {})
    assert status == 404


@pytest.mark.parametrize("path", [
    "/images/../annotations.json", "/images/0/../../etc/passwd", "/static/../session.py", "/static/..%2fserver.py",
    "/%2e%2e/%2e%2e/etc/passwd", "/images/%2e%2e%2fcars.json", "/images/1", "/images/-1", "/static/app.js.map",
    "//etc/passwd",
])
def test_paths_outside_the_images_are_refused(served, path):
    client, _ = served
    status, doc = client.request("GET", path)
    assert status == 404 and "error" in doc


def test_serves_the_page_its_files_and_the_image(served, scene):
    client, _ = served
    status, body = client.request("GET", "/")
    assert status == 200 and b"<canvas" in body
    for name in ("app.js", "style.css"):
        assert client.request("GET", f"/static/{name}")[0] == 200
    status, body = client.request("GET", "/images/0")
    assert status == 200 and body == scene[0].read_bytes()


def test_binds_loopback_by_default(scene, tmp_path):
    server = serve_in_thread(make_session(scene, tmp_path / "a.json"))
    try:
        assert server.server_address[0] == "127.0.0.1"
    finally:
        server.shutdown()
        server.server_close()


def test_ground_block_for_new_images_is_used_and_saved(scene, tmp_path):
    """With KITTI's ground the vehicle stands on the road: the contact adds to the size prior on its scale, so the
    depth sigma falls below the size prior's alone (0.079 against 0.101 of the depth; before the axle prior, rule 29,
    these five clicks left the depth all but undetermined without a road), and the block goes into the file for
    `fit`."""
    image, cameras = scene
    views = {}
    for name, ground in (("prior", None), ("ground", KITTI_GROUND)):
        session = Session([image], tmp_path / f"{name}.json", load_cameras(cameras, ["car"]), load_priors(),
                          ground=ground)
        session.edit(0, {"revision": 0, "op": "add_vehicle"})
        for c in clicks(NAMED):
            views[name] = session.edit(0, {"revision": session.revision, "op": "add_click", "vehicle": "1",
                                           "kind": c.kind, "name": c.name, "uv": c.uv})["vehicles"][0]["fit"]
    assert views["ground"]["sigma"]["depth_rel"] < 0.85 * views["prior"]["sigma"]["depth_rel"]
    saved = load_images(tmp_path / "ground.json")[0]
    assert saved.ground is not None and saved.ground.camera_height == 1.65
    assert load_images(tmp_path / "prior.json")[0].ground is None


def test_cross_site_requests_are_refused(served):
    """Another site's page can make the browser send a text/plain POST or use a name that points at 127.0.0.1;
    neither gets through."""
    client, _ = served
    connection = http.client.HTTPConnection(client.host, client.port, timeout=30)
    connection.request("POST", "/api/images/0/edit", body=b'{"revision": 0, "op": "add_vehicle"}',
                       headers={"Content-Type": "text/plain"})
    response = connection.getresponse()
    assert response.status == 415 and "application/json" in json.loads(response.read())["error"]
    connection.close()
    connection = http.client.HTTPConnection(client.host, client.port, timeout=30)
    connection.request("GET", "/api/session", headers={"Host": "evil.example:8017"})
    response = connection.getresponse()
    assert response.status == 403 and "evil.example" in json.loads(response.read())["error"]
    connection.close()
    assert client.request("GET", "/api/images/0")[1]["vehicles"] == []


def test_unnamed_clicks_and_done_marks_survive_a_restart(served, scene, tmp_path):
    """The annotation file v1 holds named parts only; the rest goes to the file beside it and comes back."""
    client, session = served
    vehicle = _add_vehicle(client)
    waiting = clicks(UNNAMED)[0].uv
    client.edit({"op": "add_click", "vehicle": vehicle, "uv": waiting})
    client.edit({"op": "set_vehicle", "vehicle": vehicle, "done": True})
    assert session.extras_path.exists()
    assert load_images(tmp_path / "annotations.json")[0].vehicles[0].parts == ()
    resumed = make_session(scene, tmp_path / "annotations.json").image_view(0)["vehicles"][0]
    assert resumed["done"] and resumed["unnamed"] == 1 and resumed["parts"][0]["uv"] == waiting
    client.edit({"op": "delete_click", "vehicle": vehicle, "part": 0})
    client.edit({"op": "set_vehicle", "vehicle": vehicle, "done": False})
    assert not session.extras_path.exists()  # nothing left that the annotation file cannot hold


def test_broken_session_file_names_itself(served, scene, tmp_path):
    client, session = served
    _add_vehicle(client)
    session.extras_path.write_text('{"toosicubix_annotate": 2}')
    with pytest.raises(InputFileError, match=r"annotations.json.annotate.json: \$.toosicubix_annotate: expected 1"):
        make_session(scene, tmp_path / "annotations.json")


def test_cameras_file_of_the_importers_is_read_too(tmp_path):
    # The same --cameras file as `import coco|cvat|label-studio`: the first glob on the file name wins.
    K = [[700.0, 0.0, 320.0], [0.0, 700.0, 240.0], [0.0, 0.0, 1.0]]
    path = tmp_path / "cameras.json"
    path.write_text(json.dumps({"cameras": [{"match": "*Camera_5*", "K": K}, {"match": "*", "K": [
        [500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]]}]}))
    cameras = load_cameras(path, ["a", "b"], ["a_Camera_5.jpg", "b_Camera_6.jpg"])
    assert cameras["a"].K[0, 0] == 700.0 and cameras["b"].K[0, 0] == 500.0
    path.write_text(json.dumps({"cameras": [{"match": "*Camera_5*", "K": K}]}))
    with pytest.raises(InputFileError, match="no camera for image 'b'"):
        load_cameras(path, ["a", "b"], ["a_Camera_5.jpg", "b_Camera_6.jpg"])


def test_edits_are_checked_with_the_schemas_own_field_bounds(scene, tmp_path):
    """A click, box or known length the annotation file's schema would refuse is refused by the page (400), so the
    page never saves a file that `fit`, `validate` or `annotate` itself would not read back."""
    from toosicubix.annotations.schema import MAX_METRES, MAX_PIXEL, MIN_SIGMA_METRES

    image, cameras = scene
    session = Session([image], tmp_path / "a.json", load_cameras(cameras, ["car"]), load_priors())
    session.edit(0, {"revision": 0, "op": "add_vehicle"})
    revision = session.revision
    bad = [
        ({"op": "add_click", "vehicle": "1", "kind": "point", "name": "wheel-front-left", "uv": [[2 * MAX_PIXEL, 1.0]]},
         "pixel coordinate from -1000000 to 1000000"),
        ({"op": "set_vehicle", "vehicle": "1", "box2d": [0, 0, 1e308, 1e308]},
         "pixel coordinate from -1000000 to 1000000"),
        ({"op": "add_click", "vehicle": "1", "kind": "length", "name": "plate-rear", "uv": [[10.0, 10.0], [20.0, 10.0]],
          "known": [2 * MAX_METRES, 0.01]}, "size in metres"),
        ({"op": "add_click", "vehicle": "1", "kind": "length", "name": "plate-rear", "uv": [[10.0, 10.0], [20.0, 10.0]],
          "known": [0.5, MIN_SIGMA_METRES / 10]}, "sigma in metres"),
    ]
    for edit, expected in bad:
        with pytest.raises(ApiError, match=expected) as refused:
            session.edit(0, {"revision": revision, **edit})
        assert refused.value.status == 400
    assert session.revision == revision  # nothing changed


def _mirrored_clicks() -> list:
    """The synthetic vehicle's clicks named with its left and right swapped (the image's left taken for its own):
    ``-left`` and ``-right`` exchanged, a pair's two clicks in the other order."""
    out = []
    for c in clicks([*NAMED, *UNNAMED]):
        if c.kind == "symmetry":
            out.append(type(c)(c.kind, c.name, c.uv[::-1]))
        else:
            other = c.name.replace("left", "@").replace("right", "left").replace("@", "right")
            out.append(type(c)(c.kind, other, c.uv))
    return out


def test_swapped_sides_show_the_likely_cause_and_s_swaps_them_back(served, tmp_path):
    """Issue 33 item 2: clicks named with left and right swapped give a fit no person could have clicked; the view
    says so and that left and right look swapped; swap_sides renames them (pairs' clicks exchanged) in one edit,
    after which the fit is the true one; undo takes the swap back in one step."""
    client, _ = served
    vehicle = _add_vehicle(client)
    for c in _mirrored_clicks():
        status, doc = client.edit({"op": "add_click", "vehicle": vehicle, "kind": c.kind, "name": c.name, "uv": c.uv})
        assert status == 200, doc
    status, doc = client.edit({"op": "add_click", "vehicle": vehicle, "uv": [[20.0, 20.0]]})  # an unnamed click
    assert status == 200, doc
    fit = doc["vehicles"][0]["fit"]
    assert fit["status"] == "ok" and fit["implausible"] is not None and fit["likely_cause"] == "swapped"
    assert any(w.startswith("left and right look swapped") for w in fit["warnings"])
    status, doc = client.edit({"op": "swap_sides", "vehicle": vehicle})
    sided = [c for c in _mirrored_clicks() if c.kind == "symmetry" or "left" in c.name or "right" in c.name]
    assert status == 200 and doc["swapped"] == len(sided) == 7  # all but the front badge
    v = doc["vehicles"][0]
    assert v["fit"]["implausible"] is None and v["fit"]["likely_cause"] is None
    # Exact clicks on the modelled parts: the rotation comes back within a degree (the test above's bound).
    assert np.rad2deg(geodesic_angle(np.array(v["fit"]["R_cam_vehicle"]), R_CAM_VEHICLE)) < 1.0
    truth = clicks([*NAMED, *UNNAMED])
    assert [(p["name"], p["uv"]) for p in v["parts"][:-1]] == [(c.name, c.uv) for c in truth]
    assert v["parts"][-1]["name"] is None  # unnamed clicks stay as they are
    saved = load_images(tmp_path / "annotations.json")[0].vehicles[0].parts
    assert [p.name for p in saved] == [c.name for c in truth]
    status, doc = client.edit({"op": "undo"})
    assert [p["name"] for p in doc["vehicles"][0]["parts"][:-1]] == [c.name for c in _mirrored_clicks()]
    assert doc["vehicles"][0]["fit"]["likely_cause"] == "swapped"


def test_front_and_rear_wheels_swapped_show_their_likely_cause(served):
    """Rule 29: a car seen from its side with its front and rear wheels named the other way round is implausible (the
    front axle behind the rear one), and the page's likely cause is 'axles' (its banner: the wheels on the wrong
    axles, rename them); rightly named, the same clicks fit plausibly."""
    from tests.scenes import random_scene

    scene = random_scene(np.random.default_rng(1), "side")  # the scenes' camera is the synthetic image's
    client, _ = served
    swapped = {"wheel-front-right": "wheel-rear-right", "wheel-rear-right": "wheel-front-right"}
    for names in (swapped, {}):
        vehicle = _add_vehicle(client)
        for p in scene.parts:
            status, doc = client.edit({"op": "add_click", "vehicle": vehicle, "kind": p.kind,
                                       "name": names.get(p.name, p.name), "uv": p.uv.tolist()})
            assert status == 200, doc
        fit = next(v for v in doc["vehicles"] if v["id"] == vehicle)["fit"]
        if names:
            assert fit["status"] == "ok" and fit["likely_cause"] == "axles"
            assert fit["implausible"] == "the front axle comes out behind the rear one: front and rear wheels look " \
                                         "swapped"
        else:
            assert fit["status"] == "ok" and fit["implausible"] is None and fit["likely_cause"] is None


def test_swap_needs_named_clicks(served):
    client, _ = served
    vehicle = _add_vehicle(client)
    status, doc = client.edit({"op": "swap_sides", "vehicle": vehicle})
    assert status == 400 and doc["error"] == f"vehicle {vehicle} has no named click to swap"


def test_road_users_are_drawn_in_their_class_s_colours_as_render_draws_them(served):
    """Issue 35: each class in its own palette on the page too; a pedestrian or a cyclist takes its class's colour in
    the order the class's objects come (as render does), a car none (the page draws it in its track's colour)."""
    from toosicubix.vocabulary import CLASSES

    client, _ = served
    for prototype in ("Car", "Pedestrian", "Pedestrian", "Cyclist"):
        status, doc = client.edit({"op": "add_vehicle", "prototype": prototype})
        assert status == 200, doc
    colours = [(v["prototype"], v["colour"]) for v in doc["vehicles"]]
    assert colours == [("Car", None), ("Pedestrian", CLASSES["Pedestrian"].palette[0]),
                       ("Pedestrian", CLASSES["Pedestrian"].palette[1]), ("Cyclist", CLASSES["Cyclist"].palette[0])]
    status, view = client.request("GET", "/api/images/0")
    assert status == 200 and [v["colour"] for v in view["vehicles"]] == [c for _, c in colours]
    # A preview (POST /api/fit) carries the colour as an image's views do: its class's first.
    status, doc = client.request("POST", "/api/fit", {"image": 0, "vehicle": {"id": "p", "prototype": "Cyclist"}})
    assert status == 200 and doc["colour"] == CLASSES["Cyclist"].palette[0]
    status, doc = client.request("POST", "/api/fit", {"image": 0, "vehicle": {"id": "c", "prototype": "Car"}})
    assert status == 200 and doc["colour"] is None


def test_a_pedestrian_is_clicked_on_its_class_keypoints_without_a_mapping(served, tmp_path):
    """A road user with keypoints of its own (COCO's 17 for a pedestrian) is clicked on them on the page, with no
    --mapping: the session lists each such prototype's keypoints, a click named one takes its class's typical place,
    a name the class has not is refused naming the class's keypoints, the clicks fit the person, the file keeps them
    as `fit` reads them, and left and right swap by name."""
    from tests.web.synthetic import CAMERA
    from toosicubix.geometry import R_cam_vehicle_from_ypr
    from toosicubix.vocabulary import CLASSES

    client, _ = served
    status, session = client.request("GET", "/api/session")
    assert status == 200 and session["class_keypoints"]["Pedestrian"][:3] == ["nose", "left_eye", "right_eye"]
    assert "Car" not in session["class_keypoints"]
    status, doc = client.edit({"op": "add_vehicle", "prototype": "Pedestrian"})
    assert status == 200, doc
    person = doc["vehicle"]
    status, doc = client.edit({"op": "add_click", "vehicle": person, "kind": "keypoint", "name": "wheel",
                               "uv": [[600.0, 200.0]]})
    assert status == 400 and doc["error"].startswith("name: keypoint 'wheel' is not a keypoint of a Pedestrian "
                                                     "(its keypoints: nose, left_eye,")
    # A person 1.75 m tall, 9 m ahead, facing the camera's left: every keypoint at its class's typical place.
    keypoints = CLASSES["Pedestrian"].keypoints
    dims, R, t = np.array([0.8, 0.66, 1.75]), R_cam_vehicle_from_ypr(0.4), np.array([0.5, 1.65, 9.0])
    for name, k in keypoints.items():
        uv = CAMERA.project((R @ (np.array(k.at) * dims) + t)[None])[0]
        status, doc = client.edit({"op": "add_click", "vehicle": person, "kind": "keypoint", "name": name,
                                   "uv": [uv.tolist()]})
        assert status == 200, doc
    fit = doc["vehicles"][0]["fit"]
    assert fit["status"] == "ok", fit
    # Exact clicks at the typical places: the pose comes back within the prior's pull on the scale.
    assert np.rad2deg(geodesic_angle(np.array(fit["R_cam_vehicle"]), R)) < 1.0
    assert abs(fit["t_cam_vehicle"][2] / t[2] - 1) < 0.05
    (saved,) = load_images(tmp_path / "annotations.json")[0].vehicles
    assert [(p.kind, p.name) for p in saved.parts] == [("keypoint", n) for n in keypoints]
    assert list(saved.parts[1].at) == list(keypoints["left_eye"].at)
    status, doc = client.edit({"op": "swap_sides", "vehicle": person})
    assert status == 200 and doc["swapped"] == 16 and doc["unpaired"] == []  # every keypoint but the nose
    names = [p["name"] for p in doc["vehicles"][0]["parts"]]
    assert names[:3] == ["nose", "right_eye", "left_eye"]
