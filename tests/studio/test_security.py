"""Access token off loopback, path confinement and upload limits, on the app built in-process."""

from __future__ import annotations

from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from studio.app import create_app
from studio.security import HostPolicy, PathError, confine
from studio.settings import Settings, is_loopback
from tests.conftest import DEMO_CLIP


def make_client(tmp_path: Path, **kw: object) -> TestClient:
    settings = Settings(runs_dir=tmp_path / "runs", start_viser=False, **kw)
    return TestClient(create_app(settings), base_url="http://127.0.0.1:8000", headers={"X-Studio-Request": "1"})


def test_loopback_needs_no_token(tmp_path: Path) -> None:
    with make_client(tmp_path) as client:
        assert client.get("/api/health").status_code == 200


def test_token_required_off_loopback(tmp_path: Path) -> None:
    with make_client(tmp_path, host="0.0.0.0", token="s3cret") as client:
        assert client.get("/api/health").status_code == 401
        assert client.get("/api/runs").status_code == 401
        assert client.get("/api/health", headers={"X-Studio-Token": "wrong"}).status_code == 401
        assert client.get("/api/health", headers={"X-Studio-Token": "s3cret"}).status_code == 200
        assert client.get("/api/health", headers={"Authorization": "Bearer s3cret"}).status_code == 200
        assert client.get("/api/health?token=s3cret").json()["token_required"] is True
        assert client.get("/").status_code == 200  # the page itself holds no data


def test_non_loopback_without_token_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="requires a token"):
        create_app(Settings(host="192.168.1.5", runs_dir=tmp_path, start_viser=False))


@pytest.mark.parametrize(
    ("host", "loopback"),
    [
        ("127.0.0.1", True),
        ("localhost", True),
        ("::1", True),
        ("0.0.0.0", False),
        ("10.0.0.2", False),
        ("example.org", False),
    ],
)
def test_is_loopback(host: str, loopback: bool) -> None:
    assert is_loopback(host) is loopback


def test_confine(tmp_path: Path) -> None:
    root = tmp_path / "data"
    (root / "motions").mkdir(parents=True)
    clip = root / "motions" / "a.pkl"
    clip.write_bytes(b"x")
    (tmp_path / "secret.pkl").write_bytes(b"x")
    (root / "motions" / "link.pkl").symlink_to(tmp_path / "secret.pkl")
    assert confine("data/motions/a.pkl", [root]) == clip
    assert confine("motions/a.pkl", [root]) == clip
    assert confine(str(clip), [root]) == clip
    for bad, status in [
        ("../secret.pkl", 403),
        ("data/../secret.pkl", 403),
        (str(tmp_path / "secret.pkl"), 403),
        ("data/motions/link.pkl", 403),
        ("", 400),
        ("data/motions/none.pkl", 404),
    ]:
        with pytest.raises(PathError) as e:
            confine(bad, [root])
        assert e.value.status == status, bad


def test_upload_size_limit(tmp_path: Path) -> None:
    settings = Settings(runs_dir=tmp_path / "runs", start_viser=False, upload_limit_bytes=1000)
    with TestClient(create_app(settings), base_url="http://127.0.0.1:8000") as client:
        r = client.post(
            "/api/motions/upload?filename=big.pkl", content=DEMO_CLIP.read_bytes(), headers={"X-Studio-Request": "1"}
        )
        assert r.status_code == 413
        assert not (tmp_path / "runs" / "uploads").exists() or not any((tmp_path / "runs" / "uploads").iterdir())


def test_scene_commands_without_a_scene_say_so(tmp_path: Path) -> None:
    with make_client(tmp_path) as client:
        r = client.get("/api/scene/state")
        assert r.status_code == 503 and "3D scene" in r.json()["detail"]


@pytest.mark.parametrize(
    ("bound", "extra", "host", "allowed"),
    [
        ("127.0.0.1", [], "127.0.0.1:8000", True),
        ("127.0.0.1", [], "localhost", True),
        ("127.0.0.1", [], "[::1]:8000", True),
        ("127.0.0.1", [], "evil.example:8000", False),
        ("127.0.0.1", [], "10.0.0.5", False),
        ("127.0.0.1", ["studio.lan"], "Studio.LAN:8000", True),
        ("127.0.0.1", ["*"], "anything.example", True),
        ("0.0.0.0", [], "192.168.1.20:8000", True),  # an IP literal: no DNS name to rebind
        ("0.0.0.0", [], "evil.example", False),
        ("192.168.1.5", [], "192.168.1.5:80", True),
        ("192.168.1.5", [], "127.0.0.1", False),
    ],
)
def test_host_policy(bound: str, extra: list[str], host: str, allowed: bool) -> None:
    assert HostPolicy(bound, extra).allows(host) is allowed


def test_allowed_hosts_reach_the_app(tmp_path: Path) -> None:
    settings = Settings(runs_dir=tmp_path / "runs", start_viser=False, allowed_hosts=["studio.lan"])
    with TestClient(create_app(settings), base_url="http://studio.lan:8000") as client:
        assert client.get("/api/health").status_code == 200
        r = client.get("/api/health", headers={"Host": "other.lan"})
        assert r.status_code == 403 and "studio.lan" in r.json()["detail"]


def test_cli_refuses_a_token_that_needs_escaping(capsys: pytest.CaptureFixture[str]) -> None:
    from studio.cli import main

    assert main(["serve", "--host", "0.0.0.0", "--token", "a;b c", "--port", "0", "--clip", "none"]) == 2
    assert "--token may hold only" in capsys.readouterr().err
