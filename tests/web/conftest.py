"""A served session on an ephemeral 127.0.0.1 port, with a client."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from tests.web.synthetic import write_scene
from toosicubix.annotations.priors_file import load_priors
from toosicubix.web.client import Client
from toosicubix.web.server import serve_in_thread
from toosicubix.web.session import Session, load_cameras


@pytest.fixture
def scene(tmp_path: Path) -> tuple[Path, Path]:
    return write_scene(tmp_path)


def make_session(scene: tuple[Path, Path], out: Path) -> Session:
    image, cameras = scene
    return Session([image], out, load_cameras(cameras, [image.stem]), load_priors())


@contextmanager
def serving(session: Session) -> Iterator[Client]:
    """``session`` served on an ephemeral 127.0.0.1 port for the block, and a client of it."""
    server = serve_in_thread(session)
    try:
        yield Client(*server.server_address[:2])
    finally:
        server.shutdown()
        server.server_close()


@pytest.fixture
def served(scene: tuple[Path, Path], tmp_path: Path) -> Iterator[tuple[Client, Session]]:
    session = make_session(scene, tmp_path / "annotations.json")
    with serving(session) as client:
        yield client, session
