"""The ``page`` target of ``benchmarks/fuzz.py`` (issue 34, item 2): mutated requests to the JSON API of a live
``toosicubix annotate`` server on 127.0.0.1.

One server per worker, started by :meth:`PageTarget.prepare` as the command a person runs (``toosicubix annotate``
on the synthetic sequence of ``tests/web/synthetic.py``, its 11 frames, ``--sequence``, so track fits, predictions
and their confirmations are reached too), its fits bounded as shipped. Each case is one request built from the state
the server last answered (its revision, the vehicles, parts and predictions of an image): an edit of each op with
real clicks of the synthetic vehicle (and, on a fifth of the vehicles added, pedestrians named by COCO's keypoints,
which the page offers that prototype), a preview (``/api/fit``), a save, a reload, a view; most of them then mutated
(a value anywhere in the body replaced by a hostile one, :data:`fuzz_targets.HOSTILE`, a key dropped or added, a
number scaled far out, the revision made stale), or sent malformed (not JSON, not UTF-8, nested deep, another
content type or origin). The client waits at most :data:`CLIENT_TIMEOUT` seconds and sends at most
:data:`MAX_BODY` bytes.

What is measured, per request: a 500 (a traceback on the server: ``tracebacks``), an answer later than
:data:`ANSWER_BOUND` or none (``hangs``), a non-finite value in the annotation file or its extras file after it
(``non_finite``); the server's peak memory (``VmHWM`` of the server, plus the largest resident fitting or estimating
process beside it, sampled after each request). Every :data:`VALIDATE_EVERY` requests and at the end, ``toosicubix
validate`` must read the file (exit 0 or 1: ``unreadable`` otherwise); at the end, the server must answer
``GET /api/session`` within the bound and be alive, and its stderr hold no traceback.
"""

from __future__ import annotations

import copy
import http.client
import json
import os
import random
import re
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from fuzz_targets import HOSTILE, TARGETS, Target, nodes, set_at

# A pedestrian's keypoints, which the page offers a vehicle of that prototype (a fifth of the added ones).
from toosicubix.parts.road_users import COCO_PERSON_KEYPOINTS as PERSON

REPO = Path(__file__).resolve().parents[1]

#: The issue's bound: every request answered within a second.
ANSWER_BOUND = 1.0
#: Seconds the client waits for an answer before it counts the request as unanswered.
CLIENT_TIMEOUT = 5.0
#: The largest body the fuzz sends, bytes (the server takes at most 1 MiB).
MAX_BODY = 256 * 1024
#: Requests between two ``toosicubix validate`` runs on the annotation file.
VALIDATE_EVERY = 250
SEQUENCE = "0001"


def _server_memory_mb(pid: int) -> tuple[float, float]:
    """The server's peak resident memory (VmHWM) and the largest resident memory of its child processes now, MB."""
    def status(p: int, key: str) -> float:
        try:
            for line in Path(f"/proc/{p}/status").read_text().splitlines():
                if line.startswith(key):
                    return int(line.split()[1]) / 1024
        except OSError:
            pass
        return 0.0

    children = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid:
                children.append(int(entry.name))
    return status(pid, "VmHWM"), max((status(c, "VmHWM") for c in children), default=0.0)


class PageTarget(Target):
    """Mutated requests against one live ``annotate`` server per worker (see the module's description)."""

    name = "page"

    # -- the server ------------------------------------------------------------------------------------------------

    def prepare(self, work: Path) -> None:
        sys.path.insert(0, str(REPO))
        from tests.web.synthetic import NAMED, UNNAMED, clicks, sequence_pose, write_sequence

        super().prepare(work)
        frames, cameras = write_sequence(work)
        self.frames = len(frames)
        #: Per frame, the synthetic vehicle's parts as (kind, name, uv) where they are on that frame.
        self.parts = [[(c.kind, c.name, c.uv) for c in clicks([*NAMED, *UNNAMED], *sequence_pose(f))]
                      for f in range(len(frames))]
        self.out = work / "annotations.json"
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            self.port = s.getsockname()[1]
        self.stderr_path = work / "server.stderr"
        env = {**os.environ, "PYTHONPATH": str(REPO)}
        with open(self.stderr_path, "wb") as stderr:  # the server's own copy stays open
            self.server = subprocess.Popen(
                [sys.executable, "-m", "toosicubix", "annotate", *map(str, frames), "--cameras", str(cameras),
                 "--sequence", SEQUENCE, "-o", str(self.out), "--host", "127.0.0.1", "--port", str(self.port)],
                stdout=subprocess.DEVNULL, stderr=stderr, env=env, cwd=work)
        deadline = time.monotonic() + 120
        while True:
            try:
                status, doc, _ = self.request("GET", "/api/session")
                if status == 200:
                    break
            except OSError:
                pass
            if self.server.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"the annotate server did not start: {self.stderr_path.read_text()[-500:]}")
            time.sleep(0.2)
        self.revision = doc["revision"]
        self.views: dict[int, dict[str, Any]] = {}
        self.requests = 0
        self.peak_server_mb = self.peak_children_mb = 0.0

    def request(self, method: str, path: str, body: bytes | None = None,
                headers: dict[str, str] | None = None) -> tuple[int, Any, float]:
        """One request on its own connection: status, the JSON answer (or None), seconds to the whole answer."""
        connection = http.client.HTTPConnection("127.0.0.1", self.port, timeout=CLIENT_TIMEOUT)
        started = time.monotonic()
        try:
            connection.request(method, path, body=body, headers=headers or {})
            response = connection.getresponse()
            payload = response.read()
        finally:
            connection.close()
        seconds = time.monotonic() - started
        try:
            doc = json.loads(payload) if response.getheader("Content-Type", "").startswith("application/json") \
                else None
        except ValueError:
            doc = None
        return response.status, doc, seconds

    # -- the requests ----------------------------------------------------------------------------------------------

    def _view(self, index: int) -> dict[str, Any]:
        return self.views.get(index) or {"vehicles": [], "predictions": [], "dismissed": [], "size": [1240, 375]}

    def _valid(self, rng: random.Random) -> tuple[str, str, str, Any]:
        """A request the page could send: (its kind, method, path, JSON body or None)."""
        index = rng.randrange(self.frames)
        view = self._view(index)
        vehicles = view["vehicles"]
        v = rng.choice(vehicles) if vehicles else None
        parts = self.parts[index]
        edit = f"/api/images/{index}/edit"
        roll = rng.random()
        if roll < 0.06:
            return "view", "GET", rng.choice([f"/api/images/{index}", "/api/session", f"/images/{index}"]), None
        if roll < 0.08:
            return "save", "POST", "/api/save", {"revision": self.revision}
        if roll < 0.09:
            return "reload", "POST", "/api/reload", {}
        if roll < 0.15:
            chosen = rng.sample(parts, rng.randint(1, len(parts)))
            vehicle = {"id": "p", "prototype": "Car", "parts": [
                {"kind": k, "part": n, **({"xy": uv[0]} if len(uv) == 1 else {"xy": uv})} for k, n, uv in chosen]}
            return "preview", "POST", "/api/fit", {"image": index, "vehicle": vehicle}
        change: dict[str, Any]
        person = v is not None and v.get("prototype") == "Pedestrian"  # clicked on its class's keypoints
        if v is None or roll < 0.22:
            change = {"op": "add_vehicle"}
            if rng.random() < 0.2:
                change["prototype"] = "Pedestrian"
            if rng.random() < 0.5:
                x, y = rng.uniform(0, 1000), rng.uniform(0, 300)
                change["box2d"] = [x, y, x + rng.uniform(5, 240), y + rng.uniform(5, 75)]
            if view["predictions"] and rng.random() < 0.3:
                change["track"] = rng.choice(view["predictions"])["track"]
        elif roll < 0.55 and person:
            change = {"op": "add_click", "vehicle": v["id"], "kind": "keypoint", "name": rng.choice(PERSON),
                      "uv": [[rng.uniform(500, 700), rng.uniform(150, 350)]]}
        elif roll < 0.55:
            kind, name, uv = rng.choice(parts)
            change = {"op": "add_click", "vehicle": v["id"], "uv": [[x + rng.gauss(0, 1), y + rng.gauss(0, 1)]
                                                                    for x, y in uv]}
            if rng.random() < 0.8:
                change.update(kind=kind, name=name)
            elif len(uv) > 1:
                change["uv"] = change["uv"][:1]
            if rng.random() < 0.05:
                change.update(kind="length", name="plate-rear", uv=[[600.0, 300.0], [640.0, 300.0]],
                              known=[0.52, 0.01])
        elif roll < 0.62 and v["parts"]:
            part = rng.randrange(len(v["parts"]))
            change = {"op": "move_click", "vehicle": v["id"], "part": part, "click": 0,
                      "uv": [x + rng.gauss(0, 3) for x in v["parts"][part]["uv"][0]]}
        elif roll < 0.67 and v["parts"]:
            kind, name, _ = ("keypoint", rng.choice(PERSON), None) if person else rng.choice(parts)
            change = {"op": "rename", "vehicle": v["id"], "part": rng.randrange(len(v["parts"])), "kind": kind,
                      "name": name}
        elif roll < 0.71 and v["parts"]:
            change = {"op": "delete_click", "vehicle": v["id"], "part": rng.randrange(len(v["parts"]))}
        elif roll < 0.76:
            change = {"op": "set_vehicle", "vehicle": v["id"]}
            change[rng.choice(["box2d", "done", "prototype"])] = rng.choice(
                [[100.0, 100.0, 300.0, 200.0], True, False, "Car", "Pedestrian", None])
        elif roll < 0.79:
            change = {"op": "swap_sides", "vehicle": v["id"]}
        elif roll < 0.83:
            change = {"op": "undo"}
        elif roll < 0.90 and (view["predictions"] or view["dismissed"]):
            if view["dismissed"] and rng.random() < 0.3:
                change = {"op": "restore_prediction", "track": rng.choice(view["dismissed"])}
            else:
                change = {"op": rng.choice(["confirm_prediction", "dismiss_prediction"]),
                          "track": rng.choice(view["predictions"])["track"]}
        elif roll < 0.92:
            change = {"op": "delete_vehicle", "vehicle": v["id"]}
        else:
            change = {"op": "add_click", "vehicle": v["id"], "uv": [[rng.uniform(0, 1240), rng.uniform(0, 375)]]}
        return change["op"], "POST", edit, {"revision": self.revision, **change}

    @staticmethod
    def _mutate(body: Any, rng: random.Random) -> tuple[Any, str]:
        """``body`` with one mutation, and its name."""
        body = copy.deepcopy(body)
        spots = nodes(body)
        path, node = rng.choice(spots)
        roll = rng.random()
        if roll < 0.45:
            value = rng.choice(HOSTILE)
            return set_at(body, path, value), f"hostile {type(value).__name__}"
        if roll < 0.65:
            numbers = [(p, n) for p, n in spots if isinstance(n, int | float) and not isinstance(n, bool)]
            if numbers:
                path, node = rng.choice(numbers)
                factor = rng.choice([1e3, 1e6, 1e9, -1, -1e6, 1e300, 0, 10])
                return set_at(body, path, node * factor if factor else 0), "number scaled"
        if roll < 0.78 and isinstance(node, dict) and node:
            del node[rng.choice(list(node))]
            return body, "key dropped"
        if roll < 0.88 and isinstance(node, dict):
            node[rng.choice(["extra", "op", "vehicle", "uv", "known", "track", "part", "image"])] = rng.choice(HOSTILE)
            return body, "key added"
        if roll < 0.94:
            return set_at(body, path, [node]), "wrapped in a list"
        if isinstance(body, dict) and "revision" in body:
            body["revision"] = body["revision"] - rng.randint(1, 3)
            return body, "stale revision"
        return set_at(body, path, None), "null"

    def _encode(self, body: Any) -> bytes:
        text = json.dumps(body)  # NaN and Infinity written as such: the server's JSON reader takes them
        return text.replace('"__HUGE__"', "9" * 5000).encode("utf-8", "surrogatepass")

    def _malformed(self, rng: random.Random, body: bytes) -> tuple[str, bytes, dict[str, str]]:
        headers = {"Content-Type": "application/json"}
        roll = rng.randrange(7)
        if roll == 0:
            return "cut short", body[:rng.randrange(max(len(body), 1))], headers
        if roll == 1:
            return "not UTF-8", body + b"\xff\xfe", headers
        if roll == 2:
            depth = rng.choice([50, 200, 5000])
            return "nested deep", b"[" * depth + b"]" * depth, headers
        if roll == 3:
            return "text/plain", body, {"Content-Type": "text/plain"}
        if roll == 4:
            return "other origin", body, {**headers, "Origin": "http://evil.example", "Sec-Fetch-Site": "cross-site"}
        if roll == 5:
            return "garbage", bytes(rng.randrange(256) for _ in range(rng.randrange(1, 200))), headers
        return "big", b'{"revision": 0, "op": "add_click", "pad": "' + b"a" * (MAX_BODY - 64) + b'"}', headers

    # -- a case ------------------------------------------------------------------------------------------------------

    def run_case(self, index: int, seed: int, folder: Path, timeout: float, run) -> list[dict[str, Any]]:
        rng = self.rng(index, seed)
        kind, method, path, body = self._valid(rng)
        headers = {"Content-Type": "application/json"} if body is not None else {}
        raw = None if body is None else self._encode(body)
        mutation = "valid"
        if body is not None:
            roll = rng.random()
            if roll < 0.6:
                mutated, mutation = self._mutate(body, rng)
                raw = self._encode(mutated)
            elif roll < 0.7:
                mutation, raw, headers = self._malformed(rng, raw)
        raw = None if raw is None else raw[:MAX_BODY]
        (folder / "request.json").write_bytes(f"{method} {path}\n".encode() + (raw or b"")[:20000])
        records = [self._send(kind, mutation, method, path, raw, headers)]
        self.requests += 1
        if self.requests % VALIDATE_EVERY == 0:
            records.append(self._validate())
        return records

    def _send(self, kind: str, mutation: str, method: str, path: str, raw: bytes | None,
              headers: dict[str, str]) -> dict[str, Any]:
        record: dict[str, Any] = {"command": f"{method} {re.sub(r'/[0-9]+', '/N', path)}",
                                  "kind": f"{kind}: {mutation}", "hang": False, "seconds": 0.0}
        try:
            status, doc, seconds = self.request(method, path, raw, headers)
        except TimeoutError:
            record.update(hang=f"no answer within {CLIENT_TIMEOUT:g} s", seconds=CLIENT_TIMEOUT)
            status, doc = None, None
        except OSError as exc:
            record["harness_error"] = f"{type(exc).__name__}: {exc}"
            status, doc = None, None
        else:
            record.update(status=status, seconds=seconds)
            if seconds > ANSWER_BOUND:
                record["hang"] = f"answered {status} after {seconds:.2f} s (bound {ANSWER_BOUND:g} s)"
            if status >= 500 and status != 503:
                record["traceback"] = f"{status}: {str((doc or {}).get('error'))[:160]}"
        if isinstance(doc, dict):
            if isinstance(doc.get("revision"), int):
                self.revision = doc["revision"]
            if status == 200 and isinstance(doc.get("vehicles"), list) and isinstance(doc.get("index"), int):
                self.views[doc["index"]] = doc
        if status == 409:  # stale: the page takes the current revision
            try:
                status2, session, _ = self.request("GET", "/api/session")
                if status2 == 200:
                    self.revision = session["revision"]
            except OSError:
                pass
        if method == "POST":
            from fuzz import non_finite_in

            for written in (self.out, self.out.with_name(self.out.name + ".annotate.json")):
                if written.exists():
                    found = non_finite_in(written)
                    if found:
                        record["non_finite"] = f"{written.name}: {found}"
        server_mb, child_mb = _server_memory_mb(self.server.pid)
        self.peak_server_mb = max(self.peak_server_mb, server_mb)
        self.peak_children_mb = max(self.peak_children_mb, child_mb)
        record["max_rss_mb"] = server_mb + child_mb
        if self.server.poll() is not None:
            record["signal"] = f"the server ended (exit {self.server.returncode})"
        return record

    def _validate(self) -> dict[str, Any]:
        """``toosicubix validate`` on the annotation file: it must read it (exit 0 or 1; none written yet: 0)."""
        started = time.monotonic()
        if not self.out.exists():
            return {"command": "validate the file", "kind": "check", "hang": False, "max_rss_mb": 0.0,
                    "seconds": 0.0, "status": "no file yet"}
        done = subprocess.run([sys.executable, "-m", "toosicubix", "validate", str(self.out)], capture_output=True,
                              text=True, env={**os.environ, "PYTHONPATH": str(REPO)}, timeout=120)
        record = {"command": "validate the file", "kind": "check", "hang": False, "max_rss_mb": 0.0,
                  "seconds": time.monotonic() - started, "status": f"exit {done.returncode}"}
        if done.returncode not in (0, 1):
            record["unreadable"] = f"exit {done.returncode}: {(done.stderr or done.stdout)[-300:]}"
        return record

    def finish(self) -> list[dict[str, Any]]:
        """After the last case: the file still read by ``validate``, the server answering within the bound and
        alive, no traceback in its stderr; then the server is stopped."""
        records = [self._validate()]
        record: dict[str, Any] = {"command": "GET /api/session after the run", "kind": "check", "hang": False,
                                  "max_rss_mb": self.peak_server_mb + self.peak_children_mb, "seconds": 0.0}
        try:
            status, _, seconds = self.request("GET", "/api/session")
            record.update(seconds=seconds, status=status)
            if status != 200 or seconds > ANSWER_BOUND:
                record["hang"] = f"answered {status} after {seconds:.2f} s"
        except OSError as exc:
            record["hang"] = f"no answer: {exc}"
        if self.server.poll() is not None:
            record["signal"] = f"the server ended (exit {self.server.returncode})"
        records.append(record)
        self.server.terminate()
        try:
            self.server.wait(10)
        except subprocess.TimeoutExpired:
            self.server.kill()
        stderr = self.stderr_path.read_text(errors="replace")
        if "Traceback" in stderr:
            records.append({"command": "server stderr", "kind": "check", "hang": False, "max_rss_mb": 0.0,
                            "seconds": 0.0, "traceback": stderr[stderr.index("Traceback"):][:300]})
        self.summary = {"requests": self.requests, "peak_server_mb": round(self.peak_server_mb),
                        "peak_fitting_process_mb": round(self.peak_children_mb)}
        return records


TARGETS[PageTarget.name] = PageTarget


def main(argv: list[str] | None = None) -> int:
    """``python benchmarks/fuzz_page.py [fuzz.py's options]``: ``benchmarks/fuzz.py --targets page``."""
    import fuzz

    return fuzz.main_(["--targets", "page", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":
    sys.exit(main())
