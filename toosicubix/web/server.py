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

Every POST changes state, so every POST must come from the page itself: a JSON body (``Content-Type:
application/json``, else 415: a web page of another site cannot send that without a CORS preflight, which this server
never grants), addressed to a loopback name when the server listens on one (else 403: DNS rebinding), and, when the
browser says where it comes from (``Origin``, ``Sec-Fetch-Site``), from this server's own origin (else 403).

Each request's fits are bounded too (:attr:`AnnotateServer.fitter`, :meth:`.Session.use_fitter`): computed in a process
of their own, ended when they are not done within the session's bound (an edit or a preview then gets 422 and nothing
changes).

Connections are bounded: each read or write waits at most :data:`READ_TIMEOUT` seconds for the client, and at most
:data:`MAX_CONNECTIONS` connections are served at once (one thread each); a new connection beyond them closes the
one that has waited longest for its client's bytes (a stalled or idle connection: never one the server is answering),
so hundreds of stalled connections cannot lock the page out.
"""

from __future__ import annotations

import json
import mimetypes
import os
import re
import shutil
import socket
import sys
import threading
import time
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from typing import Any
from urllib.parse import urlsplit

from toosicubix.errors import InputFileError
from toosicubix.jsonfile import MAX_JSON_DEPTH, json_nesting
from toosicubix.web.request_fields import ApiError
from toosicubix.web.session import FIT_MODULES, Session
from toosicubix.web.worker import DeadlineWorker

#: Largest request body, bytes.
MAX_BODY = 1 << 20
#: Seconds a connection's read or write may wait for the client (a request's line, headers and body arrive in
#: milliseconds from the page; an idle keep-alive connection is closed after this long and the browser opens another).
READ_TIMEOUT = 10.0
#: Connections served at once, one thread each.
MAX_CONNECTIONS = 64
#: Seconds a new connection waits for a place when all :data:`MAX_CONNECTIONS` are being answered (none waits for its
#: client, so none can be closed for it) before it is answered 503.
QUEUE_WAIT = 2.0


def static_files() -> dict[str, bytes]:
    """The page's files by name, read once from the package (nothing else is ever served from disk but the
    given images)."""
    folder = resources.files("toosicubix.web") / "static"
    return {entry.name: entry.read_bytes() for entry in folder.iterdir()
            if entry.is_file() and not entry.name.startswith(".")}


class AnnotateServer(ThreadingHTTPServer):
    """A threading HTTP server that carries the session and the page's files, and bounds its connections (see the
    module's description): ``read_timeout`` seconds per read or write, at most ``max_connections`` at once."""

    daemon_threads = True
    request_queue_size = 128

    def __init__(self, address: tuple[str, int], session: Session, read_timeout: float = READ_TIMEOUT,
                 max_connections: int = MAX_CONNECTIONS, bound_fits: bool = True):
        self.session = session
        #: The process the session's fits are computed in, each request's within the session's bound (started here
        #: when ``bound_fits``, ended by :meth:`server_close`).
        self.fitter: DeadlineWorker | None = None
        self.static = static_files()
        self.loopback = address[0] in ("127.0.0.1", "localhost", "::1")
        self.read_timeout, self.max_connections = read_timeout, max_connections
        #: The connections being served: since when each has been waiting for its client (None: being answered).
        self._waiting: dict[socket.socket, float | None] = {}
        self._places = threading.Condition()
        super().__init__(address, Handler)
        if bound_fits:
            self.fitter = DeadlineWorker(FIT_MODULES).start()
            session.use_fitter(self.fitter)

    def server_close(self) -> None:
        super().server_close()
        if self.fitter is not None:
            self.session.use_fitter(None)
            self.fitter.close()
            self.fitter = None

    @property
    def url(self) -> str:
        host, port = self.server_address[:2]
        return f"http://{host}:{port}/"

    @property
    def connections(self) -> int:
        """How many connections are being served now."""
        with self._places:
            return len(self._waiting)

    def waiting(self, connection: socket.socket, waiting: bool) -> None:
        """Say that ``connection`` waits for its client's bytes now (True) or is being answered (False)."""
        with self._places:
            if connection in self._waiting:
                self._waiting[connection] = time.monotonic() if waiting else None

    def process_request(self, request: Any, client_address: Any) -> None:
        """Serve ``request`` in a thread of its own once there is a place for it: at most ``max_connections`` at
        once; when they are all taken, the one that has waited longest for its client is closed, and when every
        one is being answered, the new one waits up to :data:`QUEUE_WAIT` seconds for a place, else gets 503."""
        with self._places:
            deadline = time.monotonic() + QUEUE_WAIT
            while len(self._waiting) >= self.max_connections:
                idle = [(since, c) for c, since in self._waiting.items() if since is not None]
                if idle:
                    stalled = min(idle, key=lambda pair: pair[0])[1]
                    del self._waiting[stalled]
                    try:  # its thread's read returns at once (end of stream) and the thread ends
                        stalled.shutdown(socket.SHUT_RDWR)
                    except OSError:
                        pass
                    continue
                if not self._places.wait(deadline - time.monotonic()):
                    self._refuse_busy(request)
                    return
            self._waiting[request] = time.monotonic()
        super().process_request(request, client_address)

    def _refuse_busy(self, request: socket.socket) -> None:
        body = json.dumps({"error": f"the server is answering {self.max_connections} requests already; try again",
                           "status": 503}).encode()
        try:
            request.settimeout(0.5)
            request.sendall(b"HTTP/1.1 503 Service Unavailable\r\nContent-Type: application/json\r\n"
                            b"Connection: close\r\nContent-Length: " + str(len(body)).encode() + b"\r\n\r\n" + body)
        except OSError:
            pass
        self.shutdown_request(request)

    def shutdown_request(self, request: Any) -> None:
        with self._places:
            if self._waiting.pop(request, "gone") != "gone":
                self._places.notify()
        super().shutdown_request(request)

    def handle_error(self, request: Any, client_address: Any) -> None:
        """A connection the client reset or closed, or one closed for another: nothing to report. Anything else
        is a bug, reported as the standard library does."""
        if isinstance(sys.exc_info()[1], OSError):
            return
        super().handle_error(request, client_address)


_IMAGE = re.compile(r"^/images/([0-9]{1,9})$")
_API_IMAGE = re.compile(r"^/api/images/([0-9]{1,9})$")
_API_EDIT = re.compile(r"^/api/images/([0-9]{1,9})/edit$")
_STATIC = re.compile(r"^/static/([A-Za-z0-9_-]+\.[a-z]+)$")
#: A Content-Length the server reads: ASCII digits (``str.isdigit`` passes '²', which ``int`` refuses).
_LENGTH = re.compile(r"^[0-9]{1,12}$")


class Handler(BaseHTTPRequestHandler):
    server: AnnotateServer
    protocol_version = "HTTP/1.1"

    def log_message(self, format: str, *args: Any) -> None:  # quiet: the terminal shows only the address
        pass

    def setup(self) -> None:
        self.timeout = self.server.read_timeout  # every read and write of the connection (StreamRequestHandler)
        super().setup()

    def handle_one_request(self) -> None:
        self.server.waiting(self.connection, True)  # for the request line and headers
        super().handle_one_request()

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
        """The request's JSON body, read whole (at most :data:`MAX_BODY` bytes) and parsed (nested at most
        :data:`~toosicubix.jsonfile.MAX_JSON_DEPTH` deep)."""
        kind = (self.headers.get("Content-Type") or "").split(";")[0].strip().lower()
        if kind != "application/json":
            # A web page of another site can send a form or text/plain POST here without asking; it cannot send
            # application/json without a CORS preflight, which this server never grants.
            raise ApiError(f"expected Content-Type application/json, got {kind or 'none'!r:.60}",
                           HTTPStatus.UNSUPPORTED_MEDIA_TYPE)
        length = (self.headers.get("Content-Length") or "").strip()
        if not _LENGTH.match(length):
            raise ApiError("expected a JSON body with a Content-Length", HTTPStatus.LENGTH_REQUIRED)
        if int(length) > MAX_BODY:
            raise ApiError(f"request body of {length} bytes; at most {MAX_BODY}", HTTPStatus.REQUEST_ENTITY_TOO_LARGE)
        self.server.waiting(self.connection, True)
        raw = self.rfile.read(int(length))
        self.server.waiting(self.connection, False)
        if len(raw) < int(length):
            raise ApiError(f"request body of {len(raw)} bytes, not the {length} its Content-Length says")
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise ApiError(f"request body is not UTF-8 JSON: {exc.reason} at byte {exc.start}") from None
        depth, line = json_nesting(text)
        if depth > MAX_JSON_DEPTH:
            raise ApiError(f"request body nests arrays and objects {depth} deep (first at line {line}); at most "
                           f"{MAX_JSON_DEPTH}")
        try:
            return json.loads(text)
        except json.JSONDecodeError as exc:
            raise ApiError(f"request body is not JSON at line {exc.lineno} column {exc.colno}: {exc.msg}") from None
        except ValueError as exc:  # an integer beyond Python's conversion limit (4,300 digits)
            raise ApiError(f"request body is not JSON this server reads: {exc}") from None

    def _check_origin(self) -> None:
        """A state-changing request comes from this server's own page: when the browser names where the request
        comes from (``Origin``; ``Sec-Fetch-Site``), it must be this server's origin (403 otherwise). Scripts
        and tools that name none pass."""
        origin = self.headers.get("Origin")
        host = self.headers.get("Host") or ""
        if origin is not None and origin.lower() != f"http://{host}".lower():
            raise ApiError(f"a request from {origin!r:.80} (another site, or a page with no origin) may not change "
                           f"the annotations: only the page served here (http://{host:.80}) may",
                           HTTPStatus.FORBIDDEN)
        site = self.headers.get("Sec-Fetch-Site")
        if site is not None and site.lower() not in ("same-origin", "none"):
            raise ApiError(f"a {site:.40} request may not change the annotations: only the page served here may",
                           HTTPStatus.FORBIDDEN)

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
        self.server.waiting(self.connection, False)
        try:
            try:
                self._check_host()
                route()
            except ApiError as exc:
                self._error(exc.status, str(exc))
            except InputFileError as exc:
                self._error(HTTPStatus.BAD_REQUEST, str(exc))
            except TimeoutError:  # the client stopped sending its body (or reading the answer)
                self._error(HTTPStatus.REQUEST_TIMEOUT,
                            f"the request did not arrive within {self.server.read_timeout:g} s")
            except ConnectionError:
                raise
            except Exception as exc:  # a bug: say so to the page rather than drop the connection
                self._error(HTTPStatus.INTERNAL_SERVER_ERROR, f"internal error: {type(exc).__name__}: {exc}")
        except OSError:  # the connection is gone (reset, closed, timed out, or closed for another): nothing to answer
            self.close_connection = True

    # -- routes -----------------------------------------------------------------------------------------------

    def do_GET(self) -> None:
        self._handle(self._get)

    do_HEAD = do_GET

    def do_POST(self) -> None:
        self._handle(self._post)

    def _path(self) -> str:
        try:
            return urlsplit(self.path).path
        except ValueError as exc:  # e.g. '//[' (an IPv6 host never closed)
            raise ApiError(f"a request target this server cannot read: {exc}") from None

    def _get(self) -> None:
        path = self._path()
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
            self._send_image(session.image(int(m.group(1))).path)
        elif path == "/api/session":
            self._json(HTTPStatus.OK, session.summary())
        elif m := _API_IMAGE.match(path):
            self._json(HTTPStatus.OK, session.image_view(int(m.group(1))))
        else:
            raise ApiError(f"no such page or file: {path[:200]} (the server serves only the page, its files and "
                           "the images given on the command line, by index)", HTTPStatus.NOT_FOUND)

    def _send_image(self, path) -> None:
        """The image file, copied to the connection in pieces (never read whole into memory)."""
        try:
            handle = open(path, "rb")
        except OSError as exc:
            raise ApiError(f"cannot read image {path.stem}: {exc.strerror or exc}", HTTPStatus.NOT_FOUND) from None
        with handle:
            self.send_response(HTTPStatus.OK)
            self.send_header("Content-Type", mimetypes.guess_type(path.name)[0] or "application/octet-stream")
            self.send_header("Content-Length", str(os.fstat(handle.fileno()).st_size))
            self.send_header("Cache-Control", "no-store")
            self.send_header("X-Content-Type-Options", "nosniff")
            self.end_headers()
            if self.command != "HEAD":
                shutil.copyfileobj(handle, self.wfile, 1 << 16)

    def _post(self) -> None:
        path = self._path()
        session = self.server.session
        if not (_API_EDIT.match(path) or path in ("/api/fit", "/api/save", "/api/reload")):
            raise ApiError(f"no such API: POST {path[:200]}", HTTPStatus.NOT_FOUND)
        self._check_origin()
        body = self._body()  # read whole, whatever the route: the next request on the connection starts after it
        if m := _API_EDIT.match(path):
            self._json(HTTPStatus.OK, session.edit(int(m.group(1)), body))
        elif path == "/api/fit":
            self._json(HTTPStatus.OK, session.preview(body))
        elif path == "/api/save":
            self._json(HTTPStatus.OK, session.save(body))
        else:
            self._json(HTTPStatus.OK, session.reload())


def serve(session: Session, host: str = "127.0.0.1", port: int = 0, **bounds: Any) -> AnnotateServer:
    """A server bound to ``host:port`` (0: any free port), not yet serving: call ``serve_forever``. ``bounds``:
    ``read_timeout``, ``max_connections``, ``bound_fits`` (default True: the fits in a process of their own, each
    request's within the session's bound; :class:`AnnotateServer`)."""
    return AnnotateServer((host, port), session, **bounds)


def serve_in_thread(session: Session, host: str = "127.0.0.1", port: int = 0, bound_fits: bool = False,
                    **bounds: Any) -> AnnotateServer:
    """A server answering from a daemon thread (tests, benchmarks); ``shutdown()`` and ``server_close()`` end it.
    Its fits are computed in the serving process, unbounded, unless ``bound_fits`` (starting the fitting processes takes
    a second or two)."""
    server = serve(session, host, port, bound_fits=bound_fits, **bounds)
    threading.Thread(target=server.serve_forever, name="toosicubix-annotate", daemon=True).start()
    return server
