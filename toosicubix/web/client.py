"""A small client of the annotate API (tests, benchmarks, scripts): JSON in, ``(status, JSON or bytes)`` out."""

from __future__ import annotations

import http.client
import json
from typing import Any


class Client:
    """Requests to one annotate server at ``host:port``; one connection per request."""

    def __init__(self, host: str, port: int, timeout: float = 60.0):
        self.host, self.port, self.timeout = host, port, timeout

    def request(self, method: str, path: str, body: Any = None, raw: bytes | None = None) -> tuple[int, Any]:
        """Send ``body`` as JSON (or ``raw`` bytes); the status and the decoded JSON answer (bytes otherwise)."""
        connection = http.client.HTTPConnection(self.host, self.port, timeout=self.timeout)
        try:
            data = raw if raw is not None else (None if body is None else json.dumps(body).encode())
            headers = {"Content-Type": "application/json"} if data is not None else {}
            connection.request(method, path, body=data, headers=headers)
            response = connection.getresponse()
            payload = response.read()
        finally:
            connection.close()
        if response.getheader("Content-Type", "").startswith("application/json"):
            return response.status, json.loads(payload)
        return response.status, payload

    def edit(self, change: dict[str, Any], revision: int | None = None, image: int = 0) -> tuple[int, Any]:
        """One change to an image (``POST /api/images/<image>/edit``), on ``revision`` or the current one."""
        if revision is None:
            revision = self.request("GET", "/api/session")[1]["revision"]
        return self.request("POST", f"/api/images/{image}/edit", {"revision": revision, **change})
