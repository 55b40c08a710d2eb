"""The HTTP JSON interface of ``toosicubix annotate``, and the static page.

Web layer: the standard library's :class:`http.server.ThreadingHTTPServer`. The page is local and used by one
person (a few requests a second, each a few milliseconds of fitting), so an ASGI stack would add dependencies
and a server process model for nothing; every route is a short function over :class:`.session.Session`.

Routes (every answer is JSON except the page, its files and the images; errors are ``{"error": message}`` with a
4xx status):

- ``GET /`` the page; ``GET /static/<name>`` its files (only those shipped in ``static/``)
- ``GET /images/<index>`` the image with that index on the command line (never a path from the client)
- ``GET /api/session`` images (ids, sizes), prototypes, vocabulary, thresholds, revision
- ``GET /api/images/<index>`` its vehicles, clicks, fits, cuboids, sigmas, targets; on a frame of a sequence also
  its sequence and frame, each vehicle's track, and the predictions of the tracks carried to it
- ``POST /api/images/<index>/edit`` one change, ``{"revision": r, "op": ..., ...}`` (:meth:`.Session.edit`);
  409 when ``revision`` is stale or the file changed on disk
- ``POST /api/fit`` fit a vehicle given in the body without storing it:
  ``{"image": index, "vehicle": <vehicle of the annotation file v1>}``
- ``POST /api/save`` write the file now; ``POST /api/reload`` read it again
"""

from __future__ import annotations

import json
import mimetypes
import re
import threading
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from typing import Any
from urllib.parse import urlsplit

from toosicubix.errors import InputFileError
from toosicubix.web.request_fields import ApiError
from toosicubix.web.session import Session

#: Largest request body, bytes.
MAX_BODY = 1 << 20


def static_files() -> dict[str, bytes]:
    """The page's files by name, read once from the package (nothing else is ever served from disk but the
    given images)."""
    folder = resources.files("toosicubix.web") / "static"
    return {entry.name: entry.read_bytes() for entry in folder.iterdir()
            if entry.is_file() and not entry.name.startswith(".")}


class AnnotateServer(ThreadingHTTPServer):
    """A threading HTTP server that carries the session and the page's files."""

    daemon_threads = True

    def __init__(self, address: tuple[str, int], session: Session):
        self.session = session
        self.static = static_files()
        self.loopback = address[0] in ("127.0.0.1", "localhost", "::1")
        super().__init__(address, Handler)

    @property
    def url(self) -> str:
        host, port = self.server_address[:2]
        return f"http://{host}:{port}/"


_IMAGE = re.compile(r"^/images/(\d{1,9})$")
_API_IMAGE = re.compile(r"^/api/images/(\d{1,9})$")
_API_EDIT = re.compile(r"^/api/images/(\d{1,9})/edit$")
_STATIC = re.compile(r"^/static/([A-Za-z0-9_-]+\.[a-z]+)$")


class Handler(BaseHTTPRequestHandler):
    server: AnnotateServer
    protocol_version = "HTTP/1.1"

    def log_message(self, format: str, *args: Any) -> None:  # quiet: the terminal shows only the address
        pass

    # -- answers ----------------------------------------------------------------------------------------------

    def _send(self, status: int, body: bytes, content_type: str) -> None:
        self.send_response(status)
        self.send_header("Content-Type", content_type)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.send_header("X-Content-Type-Options", "nosniff")
        if status >= 400:  # a refused request's body may be unread: never read the next request from it
            self.send_header("Connection", "close")
            self.close_connection = True
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(body)

    def _json(self, status: int, doc: Any) -> None:
        self._send(status, json.dumps(doc, allow_nan=False).encode("utf-8"), "application/json")

    def _error(self, status: int, message: str) -> None:
        self._json(status, {"error": message, "status": status})

    def _body(self) -> Any:
        kind = (self.headers.get("Content-Type") or "").split(";")[0].strip().lower()
        if kind != "application/json":
            # A web page of another site can send a form or text/plain POST here without asking; it cannot send
            # application/json without a CORS preflight, which this server never grants.
            raise ApiError(f"expected Content-Type application/json, got {kind or 'none'!r:.60}",
                           HTTPStatus.UNSUPPORTED_MEDIA_TYPE)
        length = self.headers.get("Content-Length")
        if length is None or not length.isdigit():
            raise ApiError("expected a JSON body with a Content-Length", HTTPStatus.LENGTH_REQUIRED)
        if int(length) > MAX_BODY:
            raise ApiError(f"request body of {length} bytes; at most {MAX_BODY}", HTTPStatus.REQUEST_ENTITY_TOO_LARGE)
        raw = self.rfile.read(int(length))
        try:
            return json.loads(raw.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            where = f" at line {exc.lineno} column {exc.colno}" if isinstance(exc, json.JSONDecodeError) else ""
            raise ApiError(f"request body is not JSON{where}: {getattr(exc, 'msg', exc)}") from None

    def _check_host(self) -> None:
        """On a loopback address, only requests addressed to a loopback name: a site that points its own name
        at 127.0.0.1 (DNS rebinding) is refused."""
        if not self.server.loopback:
            return
        host = (self.headers.get("Host") or "").rsplit(":", 1)[0].strip("[]").lower()
        if host not in ("127.0.0.1", "localhost", "::1"):
            raise ApiError(f"requests must be addressed to 127.0.0.1 or localhost, not {host!r:.60}",
                           HTTPStatus.FORBIDDEN)

    def _handle(self, route) -> None:
        try:
            self._check_host()
            route()
        except ApiError as exc:
            self._error(exc.status, str(exc))
        except InputFileError as exc:
            self._error(HTTPStatus.BAD_REQUEST, str(exc))
        except (BrokenPipeError, ConnectionResetError):
            self.close_connection = True
        except Exception as exc:  # a bug: say so to the page rather than drop the connection
            self._error(HTTPStatus.INTERNAL_SERVER_ERROR, f"internal error: {type(exc).__name__}: {exc}")

    # -- routes -----------------------------------------------------------------------------------------------

    def do_GET(self) -> None:
        self._handle(self._get)

    do_HEAD = do_GET

    def do_POST(self) -> None:
        self._handle(self._post)

    def _get(self) -> None:
        path = urlsplit(self.path).path
        session = self.server.session
        if path in ("/", "/index.html"):
            self._send(HTTPStatus.OK, self.server.static["index.html"], "text/html; charset=utf-8")
        elif m := _STATIC.match(path):
            body = self.server.static.get(m.group(1))
            if body is None:
                raise ApiError(f"no static file {m.group(1)!r}", HTTPStatus.NOT_FOUND)
            kind = mimetypes.guess_type(m.group(1))[0] or "application/octet-stream"
            self._send(HTTPStatus.OK, body, kind + ("; charset=utf-8" if kind.startswith("text/") or
                                                    kind.endswith("javascript") else ""))
        elif m := _IMAGE.match(path):
            image = session.image(int(m.group(1)))
            try:
                body = image.path.read_bytes()
            except OSError as exc:
                raise ApiError(f"cannot read image {image.id}: {exc.strerror or exc}", HTTPStatus.NOT_FOUND) from None
            self._send(HTTPStatus.OK, body, mimetypes.guess_type(image.path.name)[0] or "application/octet-stream")
        elif path == "/api/session":
            self._json(HTTPStatus.OK, session.summary())
        elif m := _API_IMAGE.match(path):
            self._json(HTTPStatus.OK, session.image_view(int(m.group(1))))
        else:
            raise ApiError(f"no such page or file: {path[:200]} (the server serves only the page, its files and "
                           "the images given on the command line, by index)", HTTPStatus.NOT_FOUND)

    def _post(self) -> None:
        path = urlsplit(self.path).path
        session = self.server.session
        if m := _API_EDIT.match(path):
            self._json(HTTPStatus.OK, session.edit(int(m.group(1)), self._body()))
        elif path == "/api/fit":
            self._json(HTTPStatus.OK, session.preview(self._body()))
        elif path == "/api/save":
            self._json(HTTPStatus.OK, session.save(self._body()))
        elif path == "/api/reload":
            self._body()  # read (and checked as every POST's): the next request on the connection starts after it
            self._json(HTTPStatus.OK, session.reload())
        else:
            raise ApiError(f"no such API: POST {path[:200]}", HTTPStatus.NOT_FOUND)


def serve(session: Session, host: str = "127.0.0.1", port: int = 0) -> AnnotateServer:
    """A server bound to ``host:port`` (0: any free port), not yet serving: call ``serve_forever``."""
    return AnnotateServer((host, port), session)


def serve_in_thread(session: Session, host: str = "127.0.0.1", port: int = 0) -> AnnotateServer:
    """A server answering from a daemon thread (tests, benchmarks); ``shutdown()`` and ``server_close()`` end it."""
    server = serve(session, host, port)
    threading.Thread(target=server.serve_forever, name="toosicubix-annotate", daemon=True).start()
    return server
