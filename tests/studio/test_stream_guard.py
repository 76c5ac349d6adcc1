"""`GET /api/stream` passes the same guards as every `/api` route (on the app built in-process, no
scene): the Host check, and off loopback the token, which an EventSource can only send as `?token=`."""

from __future__ import annotations

from pathlib import Path

from fastapi.testclient import TestClient

from studio.app import create_app
from studio.settings import Settings


def client(tmp_path: Path, **kw: object) -> TestClient:
    settings = Settings(runs_dir=tmp_path / "runs", start_viser=False, **kw)
    return TestClient(create_app(settings), base_url="http://127.0.0.1:8000")


def test_stream_needs_the_token_off_loopback(tmp_path: Path) -> None:
    with client(tmp_path, host="0.0.0.0", token="s3cret") as c:
        assert c.get("/api/stream").status_code == 401
        assert c.get("/api/stream?token=wrong").status_code == 401
        # With the token the request reaches the route: here its query check answers (400), not the guard.
        r = c.get("/api/stream?token=s3cret&topics=nope")
        assert r.status_code == 400 and "unknown topic 'nope'" in r.json()["detail"]


def test_stream_refuses_a_foreign_host(tmp_path: Path) -> None:
    with client(tmp_path) as c:
        r = c.get("/api/stream", headers={"Host": "evil.example:8000"})
        assert r.status_code == 403 and "not a name of this server" in r.json()["detail"]
