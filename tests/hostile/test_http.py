"""Hostile HTTP requests against a real `mimickit-studio serve` (a subprocess on free loopback ports):
cross-site requests, DNS rebinding, hostile uploads, bad files in the data folders, a symlinked
replay, diverged checkpoints, and the token on the API and the 3D scene's relay.

`err-...` cases expect a readable 4xx (`{"detail": "one line"}`) or a refused websocket; `ok-...`
cases expect the request accepted. A server that crashes fails every case after it.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import io
import re
import shutil
import socket
import threading
import time
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
import torch
import viser
from websockets.sync.client import connect as ws_connect

from mimickit.anim.motion import load_motion, save_motion
from tests.conftest import DEMO_CLIP
from tests.hostile import http_payloads as P
from tests.studio.conftest import StudioProcess, write_checkpoint_dir

pytestmark = pytest.mark.integration

TOKEN = "hostile-suite-token"
SUBPROTOCOL = f"viser-v{viser.__version__}"
BAD_XML = b"<mujoco><worldbody><body name='x'><geom type='capsule'"
YAML_BOMB = "\n".join(
    [
        'a: &a ["x", "x", "x", "x", "x", "x", "x", "x", "x"]',
        *(f"{n}: &{n} [{', '.join([f'*{p}'] * 9)}]" for p, n in zip("abcdefgh", "bcdefghi", strict=True)),
        "motions: *i",
    ]
)
# Files a user might have in a data folder: each must be one entry with its error, never a failed listing.
BAD_MOTIONS = {
    "truncated": DEMO_CLIP.read_bytes()[:200],
    "code": P.code_pickle(),
    "text": b"this is not a pickle\n",
    "empty": b"",
    "three_d": P.nested_list_bomb(3, 20),
    "heap_view": P.heap_view_frames(),
    "huge_int": P.huge_int_frames(),
}


def case(case_id: str) -> pytest.MarkDecorator:
    """One case under its `err-`/`ok-` id: the suite is counted by its ids."""
    return pytest.mark.parametrize("case", [pytest.param(case_id, id=case_id)])


def one_line(r: httpx.Response) -> str:
    """The response's detail, checked to be one readable line (no traceback)."""
    detail = r.json()["detail"]
    assert isinstance(detail, str) and detail and "\n" not in detail and "Traceback" not in detail, detail
    assert len(detail) < 600, detail
    return detail


def _port(url: str) -> int:
    return int(url.rstrip("/").rsplit(":", 1)[1].split("/")[0])


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("hostile_data")
    (d / "motions").mkdir()
    shutil.copyfile(DEMO_CLIP, d / "motions" / "good.pkl")
    for name, data in BAD_MOTIONS.items():
        (d / "motions" / f"{name}.pkl").write_bytes(data)
    (d / "assets" / "broken").mkdir(parents=True)
    (d / "assets" / "broken" / "broken.xml").write_bytes(BAD_XML)
    (d / "assets" / "broken" / "binary.xml").write_bytes(bytes(range(256)) * 4)
    (d / "args").mkdir()
    (d / "args" / "binary_args.txt").write_bytes(b"\x00\xff\xfe--num_envs\x00\x80" * 50)
    (d / "datasets").mkdir()
    (d / "datasets" / "unclosed.yaml").write_text("motions: [unclosed\n")
    (d / "datasets" / "bomb.yaml").write_text(YAML_BOMB)
    (d / "datasets" / "not_a_list.yaml").write_text("motions: 5\n")
    return d


@pytest.fixture(scope="module")
def srv(tmp_path_factory: pytest.TempPathFactory, data_dir: Path) -> Iterator[StudioProcess]:
    """The loopback studio (no token), on the data folder full of bad files."""
    server = StudioProcess(tmp_path_factory.mktemp("hostile_runs"), data_dir)
    yield server
    server.stop()


@pytest.fixture(scope="module")
def bare(srv: StudioProcess) -> Iterator[httpx.Client]:
    """A client that sends only what a cross-site page could: no X-Studio-Request header."""
    with httpx.Client(base_url=srv.url, timeout=30.0) as c:
        yield c


@pytest.fixture(scope="module")
def tok(tmp_path_factory: pytest.TempPathFactory) -> Iterator[StudioProcess]:
    """A studio bound to every interface, so with a token."""
    server = StudioProcess(tmp_path_factory.mktemp("token_runs"), None, "--host", "0.0.0.0", "--token", TOKEN)
    server.client.close()
    server.url = f"http://127.0.0.1:{_port(server.url)}/"  # the printed URL names the machine
    server.client = httpx.Client(base_url=server.url, timeout=30.0, headers={"X-Studio-Request": "1"})
    yield server
    server.stop()


# ------------------------------------------------------------------ cross-site requests, DNS rebinding
def _origin(srv: StudioProcess) -> str:
    return srv.url.rstrip("/")


def _host(srv: StudioProcess) -> str:
    return srv.url.split("//", 1)[1].rstrip("/")


CROSS_SITE = [
    pytest.param("POST", "/api/runs/1/stop", {"Content-Type": "text/plain"}, b"x", id="err-cross-site-stop-text-plain"),
    pytest.param(
        "POST", "/api/runs/1/resume", {"Content-Type": "text/plain"}, b"{}", id="err-cross-site-resume-text-plain"
    ),
    pytest.param(
        "POST",
        "/api/runs",
        {"Content-Type": "application/x-www-form-urlencoded"},
        b"arg_file=x",
        id="err-cross-site-launch-form-urlencoded",
    ),
    pytest.param(
        "POST",
        "/api/motions/upload?filename=f.pkl",
        {"Content-Type": "multipart/form-data; boundary=xx"},
        b"--xx\r\nContent-Disposition: form-data; name=f; filename=f.pkl\r\n\r\n"
        + DEMO_CLIP.read_bytes()
        + b"\r\n--xx--",
        id="err-cross-site-upload-multipart-form",
    ),
    pytest.param(
        "POST",
        "/api/motions/upload?filename=f.pkl",
        {"Content-Type": "application/octet-stream"},
        DEMO_CLIP.read_bytes(),
        id="err-upload-octet-stream-without-header",
    ),
    pytest.param("POST", "/api/motions/upload?filename=f.pkl", {}, b"", id="err-upload-no-content-type-no-header"),
    pytest.param("DELETE", "/api/runs/1", {}, None, id="err-cross-site-delete-run"),
    pytest.param("POST", "/api/scene/play", {}, None, id="err-cross-site-scene-play-no-body"),
    pytest.param(
        "POST", "/api/scene/load_clip", {"Content-Type": "text/plain"}, b'{"path": "x"}', id="err-json-as-text-plain"
    ),
]


@pytest.mark.parametrize(("method", "path", "headers", "body"), CROSS_SITE)
def test_cross_site_requests_are_refused(bare: httpx.Client, method: str, path: str, headers: dict, body: Any) -> None:
    r = bare.request(method, path, headers=headers, content=body)
    assert r.status_code == 403, r.text
    assert "X-Studio-Request" in one_line(r)


BAD_ORIGINS = [
    pytest.param("http://evil.example", {"Content-Type": "application/json"}, id="err-origin-other-site-json"),
    pytest.param("http://evil.example", {"X-Studio-Request": "1"}, id="err-origin-other-site-custom-header"),
    pytest.param("null", {"Content-Type": "application/json"}, id="err-origin-null"),
    pytest.param("http://127.0.0.1:1", {"Content-Type": "application/json"}, id="err-origin-other-port"),
    pytest.param("http://localhost.evil.example", {"X-Studio-Request": "1"}, id="err-origin-lookalike-name"),
]


@pytest.mark.parametrize(("origin", "headers"), BAD_ORIGINS)
def test_a_foreign_origin_is_refused(bare: httpx.Client, origin: str, headers: dict) -> None:
    r = bare.post("/api/scene/pause", headers={**headers, "Origin": origin}, content=b"{}")
    assert r.status_code == 403, r.text
    assert "Origin" in one_line(r)


BAD_HOSTS = [
    pytest.param("GET", "/api/health", "attacker.example", id="err-host-rebinding-get-health"),
    pytest.param("GET", "/api/runs", "attacker.example:8000", id="err-host-rebinding-read-runs"),
    pytest.param("POST", "/api/scene/pause", "attacker.example", id="err-host-rebinding-post"),
    pytest.param("GET", "/", "attacker.example", id="err-host-rebinding-page"),
    pytest.param("GET", "/scene/", "attacker.example", id="err-host-rebinding-scene"),
    pytest.param("GET", "/api/health", "10.1.2.3", id="err-host-other-ip-on-loopback"),
    pytest.param("GET", "/api/health", "", id="err-host-empty"),
    pytest.param("GET", "/api/health", "localhost.attacker.example", id="err-host-lookalike"),
]


@pytest.mark.parametrize(("method", "path", "host"), BAD_HOSTS)
def test_a_foreign_host_header_is_refused(srv: StudioProcess, method: str, path: str, host: str) -> None:
    r = srv.client.request(method, path, headers={"Host": host, "Content-Type": "application/json"}, content=b"{}")
    assert r.status_code == 403, r.text
    assert "Host" in one_line(r) and "--allowed-hosts" in one_line(r)


GOOD = [
    pytest.param("GET", "/api/health", {"Host": "localhost:{port}"}, None, 200, id="ok-host-localhost"),
    pytest.param("GET", "/api/health", {"Host": "[::1]:{port}"}, None, 200, id="ok-host-ipv6-loopback"),
    pytest.param("GET", "/api/health", {"Host": "LOCALHOST."}, None, 200, id="ok-host-case-and-trailing-dot"),
    pytest.param(
        "POST",
        "/api/scene/configure",
        {"Content-Type": "application/json", "Origin": "{origin}"},
        b'{"loop": true}',
        200,
        id="ok-same-origin-json-post",
    ),
    pytest.param(
        "POST",
        "/api/scene/configure",
        {"Content-Type": "application/json; charset=utf-8"},
        b'{"speed": 1}',
        200,
        id="ok-json-with-charset-no-origin",
    ),
    pytest.param("POST", "/api/scene/pause", {"X-Studio-Request": "1"}, None, 200, id="ok-custom-header-no-body"),
    pytest.param(
        "POST", "/api/scene/pause", {"X-Studio-Request": "1", "Origin": "{origin}"}, None, 200, id="ok-page-post"
    ),
    pytest.param("GET", "/api/motions", {"Origin": "http://evil.example"}, None, 200, id="ok-get-needs-no-header"),
    pytest.param("GET", "/", {}, None, 200, id="ok-page-loads"),
]


@pytest.mark.parametrize(("method", "path", "headers", "body", "status"), GOOD)
def test_same_origin_requests_are_accepted(
    srv: StudioProcess, bare: httpx.Client, method: str, path: str, headers: dict, body: Any, status: int
) -> None:
    headers = {k: v.format(port=_port(srv.url), origin=_origin(srv)) for k, v in headers.items()}
    r = bare.request(method, path, headers=headers, content=body)
    assert r.status_code == status, r.text


@case("ok-page-sends-the-guard-header")
def test_ok_page_sends_the_guard_header(case: str, srv: StudioProcess) -> None:
    """The dashboard's script sends X-Studio-Request with every API call (it is same-origin)."""
    assert '"X-Studio-Request": "1"' in srv.get("/web/api.js").text


def _upgrade_status(port: int, path: str, headers: dict[str, str]) -> str:
    """The status line a websocket upgrade gets (raw, so that any Host and Origin can be sent)."""
    lines = [f"GET {path} HTTP/1.1", "Upgrade: websocket", "Connection: Upgrade"]
    lines += ["Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==", "Sec-WebSocket-Version: 13"]
    lines += [f"Sec-WebSocket-Protocol: {SUBPROTOCOL}", *(f"{k}: {v}" for k, v in headers.items())]
    with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
        s.sendall(("\r\n".join(lines) + "\r\n\r\n").encode())
        return s.recv(200).decode("latin-1").split("\r\n", 1)[0]


@pytest.mark.parametrize(
    "headers",
    [
        pytest.param({"Host": "127.0.0.1:{port}", "Origin": "http://evil.example"}, id="err-websocket-foreign-origin"),
        pytest.param({"Host": "attacker.example:{port}"}, id="err-websocket-rebinding-host"),
    ],
)
def test_scene_websocket_checks_host_and_origin(srv: StudioProcess, headers: dict[str, str]) -> None:
    port = _port(srv.url)
    assert " 403 " in _upgrade_status(port, "/scene", {k: v.format(port=port) for k, v in headers.items()})


@case("ok-scene-websocket-same-origin")
def test_ok_scene_websocket_same_origin(case: str, srv: StudioProcess) -> None:
    port = _port(srv.url)
    with ws_connect(
        f"ws://127.0.0.1:{port}/scene", subprotocols=[SUBPROTOCOL], origin=f"http://127.0.0.1:{port}", open_timeout=20
    ) as ws:
        assert ws.subprotocol == SUBPROTOCOL
        assert isinstance(ws.recv(timeout=20), bytes)  # viser's first scene messages, relayed


# ------------------------------------------------------------------ uploads
HOSTILE_UPLOADS = [
    pytest.param(P.heap_view_frames(), id="err-upload-heap-view-64x34-over-34-floats"),
    pytest.param(P.heap_view_frames(rows=2), id="err-upload-heap-view-2x34-over-34-floats"),
    pytest.param(P.offset_fps(10**6), id="err-upload-tensor-offset-past-storage"),
    pytest.param(P.huge_count_frames(), id="err-upload-tensor-huge-element-count"),
    pytest.param(P.nested_list_bomb(3, 100), id="err-upload-nested-list-bomb-3-levels"),
    pytest.param(P.nested_list_bomb(4, 60), id="err-upload-nested-list-bomb-4-levels"),
    pytest.param(P.many_frames(), id="err-upload-2000000-frames"),
    pytest.param(P.huge_int_frames(), id="err-upload-frames-10-pow-400"),
    pytest.param(P.binbytes8_length(), id="err-upload-binbytes8-huge-length"),
    pytest.param(P.binunicode8_length(), id="err-upload-binunicode8-huge-length"),
    pytest.param(P.memo_get_unset(), id="err-upload-memo-get-never-put"),
    pytest.param(P.code_pickle(), id="err-upload-code-pickle"),
    pytest.param(b"", id="err-upload-empty"),
    pytest.param(b"hello, not a pickle", id="err-upload-text"),
    pytest.param(P.clip(fps=float("nan")), id="err-upload-fps-nan"),
    pytest.param(P.clip(fps=1e-300), id="err-upload-fps-1e-300"),
    pytest.param(P.clip(frames=[[0.0] * 34, [0.0] * 10]), id="err-upload-ragged-frames"),
    pytest.param(P.clip(loop_mode="wrap"), id="err-upload-loop-mode-string"),
]


@pytest.mark.parametrize("body", HOSTILE_UPLOADS)
def test_hostile_uploads_are_refused(srv: StudioProcess, body: bytes) -> None:
    name = f"hostile_{hashlib.sha1(body).hexdigest()[:12]}"
    r = srv.post(f"/api/motions/upload?filename={name}.pkl", content=body)
    assert r.status_code in (400, 413), r.text
    one_line(r)
    assert not list((srv.runs_dir / "uploads").glob(f"{name}*"))
    assert srv.get("/api/health").status_code == 200  # still serving


@pytest.mark.parametrize(
    ("filename", "stem"),
    [
        pytest.param("a" * 251 + ".pkl", "a" * 100, id="ok-upload-name-251-chars"),
        pytest.param("b" * 4000, "b" * 100, id="ok-upload-name-4000-chars"),
        pytest.param("../../etc/passwd", "passwd", id="ok-upload-name-traversal-kept-inside"),
        pytest.param("squat (final) ☃ v2.pkl", "squat_final_v2", id="ok-upload-name-odd-characters"),
        pytest.param("....pkl", "clip", id="ok-upload-name-only-dots"),
        pytest.param("x\\y\\z.pkl", "z", id="ok-upload-name-backslashes"),
        pytest.param("nul\x00byte.pkl", "nul_byte", id="ok-upload-name-nul-byte"),
    ],
)
def test_upload_names_become_safe_names(srv: StudioProcess, filename: str, stem: str, tmp_path: Path) -> None:
    # Bytes of their own per case: uploads are deduplicated by content (the same bytes return the first file).
    demo = load_motion(DEMO_CLIP)
    clip = tmp_path / "clip.pkl"
    save_motion(clip, dataclasses.replace(demo, fps=demo.fps + zlib.crc32(filename.encode()) % 1000 / 100))
    r = srv.post("/api/motions/upload", content=clip.read_bytes(), params={"filename": filename})
    assert r.status_code == 201, r.text
    saved = Path(r.json()["path"])
    assert saved.parent.resolve() == (srv.runs_dir / "uploads").resolve() and saved.is_file()
    assert re.fullmatch(rf"{re.escape(stem)}(_\d+)?\.pkl", saved.name), saved.name


@case("err-upload-too-large")
def test_err_upload_too_large(case: str, srv: StudioProcess) -> None:
    r = srv.post("/api/motions/upload?filename=big.pkl", content=b"\x80" * (64 * 1024 * 1024 + 10))
    assert r.status_code == 413
    assert "at most" in one_line(r)


@case("err-upload-without-a-filename")
def test_err_upload_without_a_filename(case: str, srv: StudioProcess) -> None:
    r = srv.post("/api/motions/upload", content=DEMO_CLIP.read_bytes())
    assert r.status_code == 422 and "filename" in r.text


@case("ok-health-answered-while-a-bomb-parses")
def test_ok_health_answered_while_a_bomb_parses(case: str, srv: StudioProcess) -> None:
    """While the server parses a nested-list bomb, other requests are still answered."""
    done = threading.Event()
    result: list[int] = []

    def upload() -> None:
        with httpx.Client(base_url=srv.url, timeout=120.0, headers={"X-Studio-Request": "1"}) as c:
            result.append(
                c.post("/api/motions/upload?filename=bomb.pkl", content=P.nested_list_bomb(4, 90)).status_code
            )
        done.set()

    t = threading.Thread(target=upload)
    t.start()
    answered = 0
    with httpx.Client(base_url=srv.url, timeout=5.0) as c:
        while not done.is_set():
            assert c.get("/api/health").status_code == 200
            answered += 1
    t.join()
    assert result == [400]
    assert answered >= 1


# ------------------------------------------------------------------ library listings with bad files
@pytest.mark.parametrize("name", [pytest.param(n, id=f"ok-motions-listed-with-bad-{n}") for n in BAD_MOTIONS])
def test_a_bad_clip_is_one_entry(srv: StudioProcess, name: str) -> None:
    r = srv.get("/api/motions")
    assert r.status_code == 200, r.text
    clips = {m["path"]: m for m in r.json()}
    entry = clips[f"data/motions/{name}.pkl"]
    assert entry["error"] and "\n" not in entry["error"] and len(entry["error"]) <= 300
    good = clips["data/motions/good.pkl"]
    assert good["num_frames"] == 91 and "error" not in good


@pytest.mark.parametrize(
    "name",
    [
        pytest.param("broken", id="ok-characters-listed-with-bad-xml"),
        pytest.param("binary", id="ok-characters-listed-with-binary-xml"),
    ],
)
def test_a_bad_character_is_one_entry(srv: StudioProcess, name: str) -> None:
    r = srv.get("/api/characters")
    assert r.status_code == 200, r.text
    chars = {c["path"]: c for c in r.json()}
    assert chars[f"data/assets/broken/{name}.xml"]["error"]
    assert chars["data/assets/humanoid/humanoid.xml"]["dof_size"] == 28


@case("ok-configs-listed-with-a-binary-arg-file")
def test_ok_configs_listed_with_a_binary_arg_file(case: str, srv: StudioProcess, data_dir: Path) -> None:
    r = srv.get("/api/configs")
    assert r.status_code == 200, r.text
    args = {a["name"]: a for a in r.json()["arg_files"]}
    assert args["binary_args"]["error"] and "\n" not in args["binary_args"]["error"]
    assert any(a.get("args") for a in args.values())  # the project's own arg files are still there


@pytest.mark.parametrize(
    "name",
    [
        pytest.param("unclosed", id="ok-datasets-listed-with-bad-yaml"),
        pytest.param("bomb", id="ok-datasets-listed-with-alias-bomb"),
        pytest.param("not_a_list", id="ok-datasets-listed-with-wrong-shape"),
    ],
)
def test_a_bad_dataset_is_one_entry(srv: StudioProcess, name: str) -> None:
    r = srv.get("/api/configs")
    assert r.status_code == 200, r.text
    datasets = {d["name"]: d for d in r.json()["datasets"]}
    assert datasets[name]["error"] and len(datasets[name]["error"]) <= 300


@pytest.mark.parametrize("name", [pytest.param(n, id=f"err-load-clip-bad-{n}") for n in ("truncated", "code", "empty")])
def test_loading_a_bad_clip_is_one_line(srv: StudioProcess, name: str) -> None:
    r = srv.post(
        "/api/scene/load_clip", {"path": f"data/motions/{name}.pkl", "char": "data/assets/humanoid/humanoid.xml"}
    )
    assert r.status_code == 400, r.text
    one_line(r)


@case("err-load-clip-malformed-json")
def test_err_load_clip_malformed_json(case: str, srv: StudioProcess) -> None:
    r = srv.client.post("/api/scene/load_clip", content=b'{"path": ', headers={"Content-Type": "application/json"})
    assert r.status_code == 422


BAD_BODIES = [
    pytest.param("/api/scene/step", {"frame": 2}, "did you mean 'frames'?", id="err-scene-step-typo"),
    pytest.param("/api/scene/configure", {"sped": 2.0}, "did you mean 'speed'?", id="err-configure-typo"),
    pytest.param("/api/scene/configure", {"speed": "fast"}, "speed:", id="err-configure-speed-not-a-number"),
    pytest.param("/api/scene/seek", {"frame": "x"}, "frame:", id="err-seek-frame-not-an-integer"),
    pytest.param("/api/scene/load_clip", {"pth": "x.pkl"}, "unknown key 'pth'", id="err-load-clip-typo"),
    pytest.param("/api/scene/load_rollout", {"run": 1}, "unknown key 'run'", id="err-load-rollout-typo"),
    pytest.param("/api/scene/export_replay", {"folow": True}, "unknown key 'folow'", id="err-export-replay-typo"),
]


@pytest.mark.parametrize(("path", "body", "says"), BAD_BODIES)
def test_a_bad_scene_body_is_one_line(srv: StudioProcess, path: str, body: dict, says: str) -> None:
    """Scene commands refuse unknown keys and wrong types by name, in one line (not pydantic's list)."""
    r = srv.post(path, body)
    assert r.status_code == 422, r.text
    assert says in one_line(r)


@case("err-checkpoints-inspect-without-path")
def test_err_inspect_without_a_path_is_one_line(case: str, srv: StudioProcess) -> None:
    r = srv.client.get("/api/checkpoints/inspect")
    assert r.status_code == 422
    assert "path" in one_line(r)


# ------------------------------------------------------------------ replays
@case("err-replay-symlink-out-of-the-folder")
def test_err_replay_symlink_out_of_the_folder(case: str, srv: StudioProcess, tmp_path: Path) -> None:
    secret = tmp_path / "secret.html"
    secret.write_text("<p>secret</p>")
    (srv.runs_dir / "replays").mkdir(exist_ok=True)
    (srv.runs_dir / "replays" / "escape.html").symlink_to(secret)
    r = srv.get("/api/scene/replays/escape.html")
    assert r.status_code in (403, 404) and "secret" not in r.text
    one_line(r)


@case("ok-replay-inside-the-folder")
def test_ok_replay_inside_the_folder(case: str, srv: StudioProcess) -> None:
    (srv.runs_dir / "replays").mkdir(exist_ok=True)
    (srv.runs_dir / "replays" / "mine.html").write_text("<p>replay</p>")
    r = srv.get("/api/scene/replays/mine.html")
    assert r.status_code == 200 and "replay" in r.text


@pytest.mark.parametrize(
    "name",
    [
        pytest.param("..%2F..%2Fetc%2Fpasswd", id="err-replay-encoded-traversal"),
        pytest.param("x.txt", id="err-replay-not-html"),
    ],
)
def test_replay_names_are_checked(srv: StudioProcess, name: str) -> None:
    r = srv.get(f"/api/scene/replays/{name}")
    assert r.status_code == 404


# ------------------------------------------------------------------ checkpoints
@pytest.fixture(scope="module")
def checkpoints(srv: StudioProcess) -> dict[str, Path]:
    """A sound checkpoint, one with a NaN weight, and unreadable ones, beside the demo configs."""
    good = write_checkpoint_dir(srv.runs_dir / "ckpt-good")
    state = torch.load(good, weights_only=True)
    out = {"good": good}
    for name, change in (
        ("nan", lambda s: s["_model._actor_layers.0.weight"].view(-1).__setitem__(0, float("nan"))),
        ("inf", lambda s: s["_a_norm._mean"].view(-1).__setitem__(0, float("inf"))),
        ("bad_train_state", lambda s: s.__setitem__("_train_state", "not a mapping")),
    ):
        folder = srv.runs_dir / f"ckpt-{name}"
        write_checkpoint_dir(folder, save_model=False)
        changed = {k: v.clone() if isinstance(v, torch.Tensor) else v for k, v in state.items()}
        change(changed)
        torch.save(changed, folder / "model.pt")
        out[name] = folder / "model.pt"
    (srv.runs_dir / "ckpt-text").mkdir()
    (srv.runs_dir / "ckpt-text" / "model.pt").write_text("not a checkpoint")
    out["text"] = srv.runs_dir / "ckpt-text" / "model.pt"
    return out


@pytest.mark.parametrize(
    "name",
    [pytest.param("nan", id="ok-inspect-flags-nan-weights"), pytest.param("inf", id="ok-inspect-flags-inf-normaliser")],
)
def test_inspection_flags_nonfinite_weights(srv: StudioProcess, checkpoints: dict[str, Path], name: str) -> None:
    r = srv.get("/api/checkpoints/inspect", params={"path": str(checkpoints[name])})
    assert r.status_code == 200, r.text
    info = r.json()
    assert info["nonfinite"] and "non-finite" in info["nonfinite_message"]


@case("ok-inspect-sound-checkpoint-not-flagged")
def test_ok_inspect_sound_checkpoint_not_flagged(case: str, srv: StudioProcess, checkpoints: dict[str, Path]) -> None:
    info = srv.get("/api/checkpoints/inspect", params={"path": str(checkpoints["good"])}).json()
    assert info["nonfinite"] == [] and info["nonfinite_message"] is None


@pytest.mark.parametrize(
    "name", [pytest.param("nan", id="err-rollout-nan-weights"), pytest.param("inf", id="err-rollout-inf-normaliser")]
)
def test_rollout_refuses_nonfinite_weights(srv: StudioProcess, checkpoints: dict[str, Path], name: str) -> None:
    r = srv.post("/api/scene/load_rollout", {"checkpoint": str(checkpoints[name])})
    assert r.status_code == 400, r.text
    assert "non-finite" in one_line(r)
    assert srv.get("/api/scene/state").json()["mode"] == "clip"


@pytest.mark.parametrize(
    "name",
    [
        pytest.param("text", id="err-inspect-not-a-checkpoint"),
        pytest.param("bad_train_state", id="err-inspect-train-state-wrong-type"),
    ],
)
def test_unreadable_checkpoints_are_one_line(srv: StudioProcess, checkpoints: dict[str, Path], name: str) -> None:
    r = srv.get("/api/checkpoints/inspect", params={"path": str(checkpoints[name])})
    assert r.status_code == 400, r.text
    one_line(r)
    r = srv.post("/api/scene/load_rollout", {"checkpoint": str(checkpoints[name])})
    assert r.status_code == 400, r.text
    one_line(r)


# ------------------------------------------------------------------ the token: API and scene relay
@pytest.mark.parametrize(
    ("path", "headers", "status"),
    [
        pytest.param("/api/health", {}, 401, id="err-token-api-missing"),
        pytest.param("/api/health", {"X-Studio-Token": "wrong"}, 401, id="err-token-api-wrong"),
        pytest.param("/api/runs", {"Authorization": "Bearer wrong"}, 401, id="err-token-api-wrong-bearer"),
        pytest.param(
            "/api/health", {"Cookie": "mimickit_studio_{port}=" + TOKEN}, 401, id="err-token-cookie-not-for-api"
        ),
        pytest.param("/scene/", {}, 401, id="err-token-scene-page-missing"),
        pytest.param("/scene/", {"Cookie": "mimickit_studio_1=" + TOKEN}, 401, id="err-token-scene-other-ports-cookie"),
        pytest.param("/api/health", {"X-Studio-Token": TOKEN}, 200, id="ok-token-api-header"),
        pytest.param("/api/health", {"Authorization": "Bearer " + TOKEN}, 200, id="ok-token-api-bearer"),
        pytest.param("/api/health?token=" + TOKEN, {}, 200, id="ok-token-api-query"),
        pytest.param("/scene/", {"Cookie": "mimickit_studio_{port}=" + TOKEN}, 200, id="ok-token-scene-cookie"),
        pytest.param("/", {}, 200, id="ok-token-page-itself-open"),
    ],
)
def test_token_guards_api_and_scene(tok: StudioProcess, path: str, headers: dict, status: int) -> None:
    port = _port(tok.url)
    with httpx.Client(base_url=tok.url, timeout=30.0) as c:
        r = c.get(path, headers={k: v.format(port=port) for k, v in headers.items()})
    assert r.status_code == status, r.text
    if status == 401:
        assert "token" in one_line(r)


@case("ok-token-scene-page-sets-its-cookie")
def test_ok_token_scene_page_sets_its_cookie(case: str, tok: StudioProcess) -> None:
    r = tok.get(f"/scene/?token={TOKEN}")
    assert r.status_code == 200 and '<div id="root">' in r.text
    cookie = r.headers["set-cookie"]
    assert (
        cookie.startswith(f"mimickit_studio_{_port(tok.url)}=") and "HttpOnly" in cookie and "SameSite=Strict" in cookie
    )


@pytest.mark.parametrize(
    ("headers", "ok"),
    [
        pytest.param({}, False, id="err-token-scene-websocket-missing"),
        pytest.param({"Cookie": "mimickit_studio_{port}=wrong"}, False, id="err-token-scene-websocket-wrong"),
        pytest.param({"Cookie": "mimickit_studio_{port}=" + TOKEN}, True, id="ok-token-scene-websocket-cookie"),
        pytest.param({"X-Studio-Token": TOKEN}, True, id="ok-token-scene-websocket-header"),
    ],
)
def test_token_guards_the_scene_websocket(tok: StudioProcess, headers: dict, ok: bool) -> None:
    port = _port(tok.url)
    headers = {k: v.format(port=port) for k, v in headers.items()}
    if not ok:
        assert " 403 " in _upgrade_status(port, "/scene", {"Host": f"127.0.0.1:{port}", **headers})
        return
    with ws_connect(
        f"ws://127.0.0.1:{port}/scene", subprotocols=[SUBPROTOCOL], additional_headers=headers, open_timeout=20
    ) as ws:
        assert isinstance(ws.recv(timeout=20), bytes)


def _outside_address() -> str | None:
    """This machine's address on a non-loopback interface (no packet is sent), if it has one."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.connect(("10.255.255.255", 1))
            ip = s.getsockname()[0]
        except OSError:
            return None
    return None if ip.startswith("127.") else ip


@case("err-viser-port-not-reachable-off-loopback")
def test_err_viser_port_not_reachable_off_loopback(case: str, tok: StudioProcess) -> None:
    ip = _outside_address()
    if ip is None:
        pytest.skip("no non-loopback interface on this machine")
    viser_port = tok.get("/api/health", headers={"X-Studio-Token": TOKEN}).json()["viser_port"]
    with socket.create_connection((ip, _port(tok.url)), timeout=5):
        pass  # the studio's own port is reachable there (bound to 0.0.0.0) ...
    with pytest.raises(OSError):
        socket.create_connection((ip, viser_port), timeout=5).close()  # ... viser's is not


@contextlib.contextmanager
def chromium_page() -> Iterator[Any]:
    """A page of real Chromium (Playwright, the apt browser); skips where there is none."""
    sync_api = pytest.importorskip("playwright.sync_api")
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        pytest.skip("no chromium on PATH")
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium, headless=True, args=["--no-sandbox", "--disable-gpu"])
        try:
            yield browser.new_page(viewport={"width": 1200, "height": 800})
        finally:
            browser.close()


@pytest.mark.browser
@case("ok-scene-renders-through-the-token-relay")
def test_ok_scene_renders_through_the_token_relay(case: str, tok: StudioProcess) -> None:
    """Real Chromium opens the dashboard with its token: the scene's iframe is the relay and draws."""
    image = pytest.importorskip("PIL.Image")
    with chromium_page() as page:
        page.goto(f"{tok.url}?token={TOKEN}")
        page.frame_locator("#scene").locator("canvas").first.wait_for(timeout=60_000)
        assert page.locator("#scene").get_attribute("src").startswith("/scene/")
        deadline = time.monotonic() + 60
        spread = 0.0
        while time.monotonic() < deadline and spread < 10:  # software WebGL: the first frames take a while
            time.sleep(2)
            box = page.locator("#scene").bounding_box()  # page.screenshot: no wait for a "stable" element
            png = page.screenshot(clip=box, timeout=60_000)
            spread = float(np.asarray(image.open(io.BytesIO(png)).convert("L"), dtype=np.float32).std())
    assert spread >= 10, "the scene's canvas stayed blank through the relay"


@pytest.mark.browser
@case("ok-page-shows-a-bad-clip-as-one-line")
def test_ok_page_shows_a_bad_clip_as_one_line(case: str, srv: StudioProcess) -> None:
    """The library panel lists the data folder with its bad clips: each one row with its error."""
    with chromium_page() as page:
        page.goto(srv.url)
        page.fill("#filter", "truncated")
        row = page.locator("#library-list .item.broken")
        row.wait_for(timeout=30_000)
        text = row.locator(".meta.error").inner_text()
        assert "truncated.pkl" in text and "\n" not in text.strip()
        page.fill("#filter", "good.pkl")
        page.locator("#library-list .item:not(.broken)").first.wait_for(timeout=10_000)


# ------------------------------------------------------------------ crashers (last: they killed the server before)
CRASHERS = [
    pytest.param(P.stride_fps(2**40), id="err-upload-fps-stride-2-pow-40"),
    pytest.param(P.stride_fps(-1), id="err-upload-fps-negative-stride"),
    pytest.param(P.stride_fps(-(2**40)), id="err-upload-fps-huge-negative-stride"),
]


@pytest.mark.parametrize("body", CRASHERS)
def test_stride_pickles_neither_crash_nor_leak(srv: StudioProcess, body: bytes) -> None:
    r = srv.post("/api/motions/upload?filename=stride.pkl", content=body)
    assert r.status_code == 400, r.text
    one_line(r)
    (srv.runs_dir / "hostile").mkdir(exist_ok=True)
    clip = srv.runs_dir / "hostile" / "stride.pkl"
    clip.write_bytes(body)
    r = srv.post("/api/scene/load_clip", {"path": str(clip), "char": "data/assets/humanoid/humanoid.xml"})
    assert r.status_code == 400, r.text
    one_line(r)
    assert srv.get("/api/health").status_code == 200
