"""A served session on an ephemeral 127.0.0.1 port, and a small JSON client."""

from __future__ import annotations

import http.client
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.web.synthetic import write_scene
from toosicubix.priors.table import load_priors
from toosicubix.web.server import AnnotateServer, serve_in_thread
from toosicubix.web.session import Session, load_cameras


class Client:
    """Requests to one server; answers are (status, decoded JSON or bytes)."""

    def __init__(self, server: AnnotateServer):
        self.host, self.port = server.server_address[:2]

    def request(self, method: str, path: str, body: Any = None, raw: bytes | None = None) -> tuple[int, Any]:
        connection = http.client.HTTPConnection(self.host, self.port, timeout=30)
        data = raw if raw is not None else (None if body is None else json.dumps(body).encode())
        headers = {"Content-Type": "application/json"} if data is not None else {}
        connection.request(method, path, body=data, headers=headers)
        response = connection.getresponse()
        payload = response.read()
        connection.close()
        if response.getheader("Content-Type", "").startswith("application/json"):
            return response.status, json.loads(payload)
        return response.status, payload

    def edit(self, change: dict[str, Any], revision: int | None = None, image: int = 0) -> tuple[int, Any]:
        if revision is None:
            revision = self.request("GET", "/api/session")[1]["revision"]
        return self.request("POST", f"/api/images/{image}/edit", {"revision": revision, **change})


@pytest.fixture
def scene(tmp_path: Path) -> tuple[Path, Path]:
    return write_scene(tmp_path)


def make_session(scene: tuple[Path, Path], out: Path) -> Session:
    image, cameras = scene
    return Session([image], out, load_cameras(cameras, [image.stem]), load_priors())


@pytest.fixture
def served(scene: tuple[Path, Path], tmp_path: Path) -> Iterator[tuple[Client, Session]]:
    session = make_session(scene, tmp_path / "annotations.json")
    server = serve_in_thread(session)
    try:
        yield Client(server), session
    finally:
        server.shutdown()
        server.server_close()
