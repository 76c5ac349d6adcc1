"""Hostile addresses, ports and paths against a real `mimickit-studio serve` (a subprocess on free
loopback ports): a Ray address that accepts connections and never answers, or one of 100,000 chars;
viser's internal port opened directly (not through the studio's relay); a 6,000-character path on
each path-taking API parameter.

`err-...` cases expect one readable line (`error: ...` from the CLI, `{"detail": ...}` from the API).
"""

from __future__ import annotations

import http.server
import json
import socket
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
import viser
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect as ws_connect

from studio.runs.executors.ray import RayExecutor
from tests.studio.conftest import StudioProcess

pytestmark = pytest.mark.integration

SERVE_DEADLINE_S = 120.0  # a hang, not a speed: the probe gives up after 10 s, the server starts in ~5


def case(case_id: str) -> pytest.MarkDecorator:
    """One case under its `err-`/`ok-` id: the suite is counted by its ids."""
    return pytest.mark.parametrize("case", [pytest.param(case_id, id=case_id)])


@pytest.fixture
def silent_server() -> Iterator[int]:
    """A loopback port that accepts connections and never answers; its port."""
    listener = socket.create_server(("127.0.0.1", 0))
    accepted: list[socket.socket] = []

    def accept() -> None:
        while True:
            try:
                accepted.append(listener.accept()[0])
            except OSError:  # the listener closed: the test is over
                return

    threading.Thread(target=accept, daemon=True).start()
    yield listener.getsockname()[1]
    listener.close()
    for conn in accepted:
        conn.close()


def serve_ray(address: str, runs_dir: Path) -> subprocess.CompletedProcess[str]:
    """`mimickit-studio serve --executor ray --ray-address ADDRESS` run to its end (a hang fails)."""
    pytest.importorskip("ray", reason="the Ray executor needs the ray extra: pip install -e '.[ray]'")
    argv = [sys.executable, "-m", "studio.cli", "serve", "--port", "0", "--viser-port", "0", "--clip", "none"]
    argv += ["--runs-dir", str(runs_dir), "--executor", "ray", "--ray-address", address]
    try:
        return subprocess.run(argv, capture_output=True, text=True, timeout=SERVE_DEADLINE_S)
    except subprocess.TimeoutExpired as e:
        pytest.fail(f"serve --ray-address {address[:100]} still runs after {SERVE_DEADLINE_S:g} s: {e.stderr!r}")


def error_line(done: subprocess.CompletedProcess[str]) -> str:
    """The one `error: ...` line a refused command prints (and nothing else)."""
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1 and lines[0].startswith("error: "), done.stderr[-2000:]
    assert "Traceback" not in done.stderr and not done.stdout.strip(), (done.stdout, done.stderr)
    return lines[0]


@case("err-ray-address-never-answers")
@pytest.mark.parametrize("scheme", ["", "http://"])
def test_ray_address_that_never_answers(case: str, scheme: str, silent_server: int, tmp_path: Path) -> None:
    address = f"{scheme}127.0.0.1:{silent_server}"
    line = error_line(serve_ray(address, tmp_path))
    assert f"127.0.0.1:{silent_server}" in line and "no answer" in line, line


@case("err-ray-address-100000-chars")
def test_ray_address_too_long(case: str, tmp_path: Path) -> None:
    address = "http://" + "a" * 100_000 + ":8265"
    line = error_line(serve_ray(address, tmp_path))
    assert "too long" in line and len(line) < 300, line


@pytest.fixture
def stalling_dashboard() -> Iterator[str]:
    """A Ray dashboard that answers its version, then never answers a job request."""
    ray = pytest.importorskip("ray")
    release = threading.Event()

    class Handler(http.server.BaseHTTPRequestHandler):
        def do_GET(self) -> None:  # noqa: N802 - http.server's name
            if self.path != "/api/version":
                release.wait(60)
                return
            body = json.dumps({"version": "4", "ray_version": ray.__version__, "ray_commit": "x"}).encode()
            self.send_response(200)
            self.send_header("Content-Type", "application/json")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *_: object) -> None:
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    server.daemon_threads = True
    threading.Thread(target=server.serve_forever, daemon=True).start()
    yield f"http://127.0.0.1:{server.server_address[1]}"
    release.set()
    server.shutdown()


@case("err-ray-dashboard-stops-answering")
def test_ray_dashboard_that_stops_answering_is_an_error_not_a_hang(case: str, stalling_dashboard: str) -> None:
    """After the first probe, each request of Ray's client has a timeout too: the run manager's thread
    reports the error and goes on polling, where it used to wait for good."""
    requests = pytest.importorskip("requests")  # Ray's HTTP client, installed with it
    executor = RayExecutor(stalling_dashboard, stop_timeout_s=5.0, request_timeout_s=1.0)
    with pytest.raises(requests.exceptions.Timeout):
        executor.status("raysubmit_never_answered")


# ------------------------------------------------------------------ over-long paths
LONG = "/" + "/".join(["a" * 200] * 30)  # 6,030 characters: over PATH_MAX, no name over NAME_MAX
LONG_NAME = "a" * 6000  # one name over NAME_MAX
CKPT = "data/models/deepmimic_humanoid_demo_model.pt"
CLIP = "data/motions/humanoid_demo_squat.pkl"
ARGS = "args/deepmimic_humanoid_demo_ppo_args.txt"
# (method, route, query or body with the long path, the other keys it needs to reach that one)
PATH_PARAMS = [
    *(("GET", "/api/checkpoints/inspect", k, {"path": CKPT}) for k in ("env_config", "engine_config", "char")),
    ("GET", "/api/checkpoints/inspect", "path", {}),
    ("GET", "/api/characters/pose", "path", {}),
    ("GET", "/api/configs/file", "path", {}),
    ("DELETE", "/api/motions/upload", "path", {}),
    ("POST", "/api/runs", "arg_file", {}),
    ("POST", "/api/runs", "motion_file", {"arg_file": ARGS}),
    ("POST", "/api/sweeps", "arg_file", {}),
    ("POST", "/api/sweeps", "dataset", {"arg_file": ARGS}),
    ("POST", "/api/scene/load_clip", "path", {"play": False}),
    ("POST", "/api/scene/load_clip", "char", {"path": CLIP, "play": False}),
    ("POST", "/api/scene/show_character", "path", {}),
    ("POST", "/api/scene/load_rollout", "checkpoint", {"play": False}),
    *(
        ("POST", "/api/scene/load_rollout", k, {"checkpoint": CKPT, "play": False})
        for k in ("env_config", "agent_config", "engine_config", "b_checkpoint")
    ),
    ("POST", "/api/scene/export_replay", "path", {}),
    ("POST", "/api/scene/export_replay", "char", {"path": CLIP}),
    ("POST", "/api/evals", "checkpoint", {}),
    *(("POST", "/api/evals", k, {"checkpoint": CKPT}) for k in ("arg_file", "motion_file")),
    ("POST", "/api/videos", "clip", {}),
    ("POST", "/api/videos", "char", {"clip": CLIP}),
    ("POST", "/api/videos", "checkpoint", {}),
    *(("POST", "/api/videos", k, {"checkpoint": CKPT}) for k in ("env_config", "agent_config", "engine_config")),
]


@pytest.fixture(scope="module")
def srv(tmp_path_factory: pytest.TempPathFactory) -> Iterator[StudioProcess]:
    server = StudioProcess(tmp_path_factory.mktemp("paths_runs"), None, "--clip", "none")
    yield server
    server.stop()


def refused_in_one_line(r: httpx.Response) -> str:
    """A 4xx whose detail is one short line, on a connection the server keeps open."""
    assert 400 <= r.status_code < 500, (r.status_code, r.text[:300])
    detail = r.json()["detail"]
    assert isinstance(detail, str) and "\n" not in detail and len(detail) < 300, detail[:300]
    assert r.headers.get("connection", "").lower() != "close", r.headers
    return detail


@pytest.mark.parametrize(
    "method,route,key,others",
    [pytest.param(*p, id=f"err-6000-char-path-{p[1].removeprefix('/api/')}-{p[2]}") for p in PATH_PARAMS],
)
def test_long_path_on_each_path_parameter(
    srv: StudioProcess, method: str, route: str, key: str, others: dict[str, object]
) -> None:
    given = {**others, key: LONG}
    if method in ("GET", "DELETE"):
        r = srv.client.request(method, route, params=given)
    else:
        r = srv.client.request(method, route, json=given)
    detail = refused_in_one_line(r)
    assert "too long" in detail and "6,030 chars" in detail, detail
    assert srv.client.get("/api/health").status_code == 200  # the same connection goes on


JOINED_TOO_LONG = "/".join(["b" * 254] * 17)[:4095]  # under the limit, over PATH_MAX once under a folder


@pytest.mark.parametrize(
    "method,route,key,others",
    [
        pytest.param(*p, id=f"err-4095-char-path-{p[1].removeprefix('/api/')}-{p[2]}")
        for p in PATH_PARAMS
        if p[1] in ("/api/scene/load_clip", "/api/checkpoints/inspect", "/api/videos") and p[2] in ("path", "clip")
    ],
)
def test_path_too_long_once_joined_to_a_folder(
    srv: StudioProcess, method: str, route: str, key: str, others: dict[str, object]
) -> None:
    """The file system's own refusal (ENAMETOOLONG) is one line too, not a 500."""
    given = {**others, key: JOINED_TOO_LONG}
    r = srv.client.request(method, route, **({"params": given} if method == "GET" else {"json": given}))
    assert "not a usable path" in refused_in_one_line(r)
    assert srv.client.get("/api/health").status_code == 200


@case("err-6000-char-name-in-swept-config")
def test_long_path_as_a_swept_config(case: str, srv: StudioProcess) -> None:
    r = srv.client.post("/api/sweeps", json={"arg_file": ARGS, "values": {"env_config": [LONG]}})
    assert "too long" in refused_in_one_line(r)


@case("err-6000-char-replay-name")
def test_long_replay_name(case: str, srv: StudioProcess) -> None:
    refused_in_one_line(srv.client.get(f"/api/scene/replays/{LONG_NAME}"))


# ------------------------------------------------------------------ viser's internal port
SUBPROTOCOL = f"viser-v{viser.__version__}"


def viser_port(srv: StudioProcess) -> int:
    return srv.get("/api/health").json()["viser_port"]


@pytest.mark.parametrize(
    "host, headers",
    [
        pytest.param("evil.example", {"Origin": "http://evil.example"}, id="err-viser-port-foreign-origin-and-host"),
        pytest.param("127.0.0.1", {"Origin": "http://127.0.0.1:1"}, id="err-viser-port-browser-origin"),
        pytest.param("127.0.0.1", {}, id="err-viser-port-no-secret"),
        pytest.param("127.0.0.1", {"X-Studio-Relay": "a-guess"}, id="err-viser-port-wrong-secret"),
    ],
)
def test_viser_port_refuses_a_direct_websocket(srv: StudioProcess, host: str, headers: dict[str, str]) -> None:
    """A page or program on this machine opening viser's port itself gets no scene and no commands."""
    port = viser_port(srv)
    sock = socket.create_connection(("127.0.0.1", port), timeout=10)  # the URL's host is only the Host header
    with (
        pytest.raises(InvalidStatus) as refused,
        ws_connect(
            f"ws://{host}:{port}/", sock=sock, subprotocols=[SUBPROTOCOL], additional_headers=headers, open_timeout=10
        ) as ws,
    ):
        pytest.fail(f"viser's port streamed to a direct client: {len(ws.recv(timeout=10))} bytes")
    assert refused.value.response.status_code == 403


@case("err-viser-port-direct-http")
def test_viser_port_refuses_a_direct_http_request(case: str, srv: StudioProcess) -> None:
    assert httpx.get(f"http://127.0.0.1:{viser_port(srv)}/", timeout=10).status_code == 403


@case("ok-scene-relay-streams")
def test_the_relay_still_serves_and_streams_the_scene(case: str, srv: StudioProcess) -> None:
    page = srv.get("/scene/")
    assert page.status_code == 200 and b"<html" in page.content[:1000].lower()
    url = srv.url.replace("http://", "ws://") + "scene"
    with ws_connect(url, subprotocols=[SUBPROTOCOL], open_timeout=10) as ws:
        assert ws.subprotocol == SUBPROTOCOL
        assert len(ws.recv(timeout=30)) > 0  # the scene's first messages
