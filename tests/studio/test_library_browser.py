"""The library panel in real Chromium (Playwright, the apt browser) against a real studio: a character
clicked shows in the scene in its default pose and lists its joints; an arg file opens read-only with
the env config, clip and character it trains, and its clip plays from there (the 3D view stays
uncovered at 1280×720); a dataset lists its clips with weights and shares, missing ones marked, and a
click plays one; an upload is deletable and the same bytes again are the same clip (no `_2` copy), a
focused Delete button keeping its focus while the list changes; a character that does not load and a
clip no character fits stay listed with their reasons.

The server's data folder is made here (a cut-off MJCF, a clip of 10 values per frame, a dataset of one
real clip and one missing), on top of the project's own data; one test reads MimicKit's reference
dataset when MIMICKIT_TEST_DATA is set.
"""

from __future__ import annotations

import pickle
from collections.abc import Iterator
from pathlib import Path

import pytest

from mimickit.util.paths import PROJECT_ROOT
from tests.conftest import DEMO_CLIP
from tests.studio.conftest import CHROMIUM, StudioProcess, new_page, wait_for, write_arg_file
from tests.studio.test_page_browser import scene_frame

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(CHROMIUM is None, reason="no chromium on PATH (apt-get install chromium)"),
]
WAIT_S = 90  # a loaded machine's software-rendered scene can hold the page for seconds
HUMANOID = "data/assets/humanoid/humanoid.xml"
SQUAT = "data/motions/humanoid_demo_squat.pkl"
DEMO_ARGS = PROJECT_ROOT / "args" / "deepmimic_humanoid_demo_ppo_args.txt"


def clip_bytes(width: int, frames: int = 5) -> bytes:
    return pickle.dumps({"loop_mode": 0, "fps": 30, "frames": [[0.0] * width for _ in range(frames)]})


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[StudioProcess]:
    root = tmp_path_factory.mktemp("library_browser")
    data = root / "data"
    (data / "assets" / "broken").mkdir(parents=True)
    (data / "assets" / "broken" / "broken.xml").write_text("<mujoco><worldbody><body name='a'>")  # cut off
    (data / "motions").mkdir()
    (data / "motions" / "odd.pkl").write_bytes(clip_bytes(10))  # no character takes 10 values a frame
    (data / "datasets").mkdir()
    (data / "datasets" / "mix.yaml").write_text(
        f"motions:\n  - file: {SQUAT}\n    weight: 3\n  - file: data/motions/not_there.pkl\n    weight: 1\n"
    )
    runs = root / "runs"
    write_arg_file(runs, "short", rows=4)
    s = StudioProcess(runs, data)
    yield s
    s.stop()


def open_page(browser, server: StudioProcess, width: int, height: int):
    """test_page_browser's page, with this file's longer waits: a server on MimicKit's data scans a few
    hundred clips before the page's first scene state."""
    page = new_page(browser, server.url, width, height)
    page.frame_locator("#scene").locator("canvas").first.wait_for(timeout=WAIT_S * 1000)
    wait_for(lambda: page.locator("#frame-label").inner_text() != "–", WAIT_S, "the scene state on the page")
    page.locator("#library-list .item").first.wait_for(timeout=WAIT_S * 1000)  # the library loaded
    return page


def state(server: StudioProcess) -> dict:
    return server.get("/api/scene/state").json()


def item(page, path: str):
    return page.locator(f'#library-list .item[data-path="{path}"]')


def tab(page, name: str) -> None:
    page.click(f".tabs button[data-tab={name}]")


def show_humanoid(page, server: StudioProcess) -> None:
    tab(page, "characters")
    item(page, HUMANOID).click()
    wait_for(lambda: state(server)["clip"].endswith("/humanoid/humanoid.xml"), WAIT_S, "the character in the scene")


def test_a_character_shows_in_its_default_pose_with_its_joints(browser, server: StudioProcess) -> None:
    page = open_page(browser, server, 1280, 720)
    show_humanoid(page, server)
    s = state(server)
    assert s["char"] == s["clip"] and s["num_frames"] == 1 and not s["playing"]  # one frame: the default pose
    pose = server.get("/api/characters/pose", params={"path": HUMANOID}).json()
    rows = page.locator("#library-detail table.joints tr[data-joint]")
    wait_for(lambda: rows.count() == len(pose["bodies"]), WAIT_S, "one row per body in the joint table")
    assert [r.get_attribute("data-joint") for r in rows.all()] == [b["joint"]["name"] for b in pose["bodies"]]
    abdomen = page.locator('#library-detail tr[data-joint="abdomen"]').inner_text()
    assert "torso" in abdomen and "spherical" in abdomen and "6–8" in abdomen, abdomen  # clip columns 6..8
    assert "28 DoFs" in page.locator("#library-detail").inner_text()
    assert "humanoid.xml in its default pose" in page.locator("#clip-label").inner_text()
    assert page.errors == []
    page.close()


def test_an_arg_file_opens_read_only_with_what_it_trains(browser, server: StudioProcess) -> None:
    page = open_page(browser, server, 1280, 720)
    show_humanoid(page, server)  # so that the clip it trains starting to play is seen
    tab(page, "configs")
    page.fill("#filter", DEMO_ARGS.stem)
    item(page, str(DEMO_ARGS)).click()
    text = page.locator("#library-detail pre.config-text")
    text.wait_for(timeout=WAIT_S * 1000)
    assert text.inner_text().strip() == DEMO_ARGS.read_text().strip()
    assert text.evaluate("e => !e.isContentEditable")  # read-only: text, no editor
    trains = {r.get_attribute("data-trains"): r.inner_text() for r in page.locator("[data-trains]").all()}
    assert "data/envs/deepmimic_humanoid_env.yaml" in trains["env config"]
    assert SQUAT in trains["clip"] and "from the env config" in trains["clip"]
    assert HUMANOID in trains["character"]
    # The pane lies in the library's column: the middle of the 3D view is still the scene's canvas.
    box, lib = page.locator("#scene").bounding_box(), page.locator("#library").bounding_box()
    pane = page.locator("#library-detail").bounding_box()
    assert pane["x"] >= lib["x"] and pane["x"] + pane["width"] <= lib["x"] + lib["width"] + 0.5
    assert pane["y"] + pane["height"] <= lib["y"] + lib["height"] + 0.5
    centre = [box["x"] + box["width"] / 2, box["y"] + box["height"] / 2]
    assert page.evaluate("([x, y]) => document.elementFromPoint(x, y).id", centre) == "scene"
    hit = scene_frame(page).evaluate(
        "([x, y]) => document.elementFromPoint(x, y).tagName", [box["width"] / 2, box["height"] / 2]
    )
    assert hit == "CANVAS"
    page.click("[data-trains=clip] button[data-action=play-clip]")
    wait_for(lambda: (s := state(server))["clip"].endswith(SQUAT.split("/")[-1]) and s["playing"], WAIT_S, "the clip")
    # The env config opens from there, with what it trains too.
    page.click("[data-trains='env config'] button[data-action=open-env]")
    wait_for(lambda: "deepmimic_humanoid_env" in page.locator("#detail-title").inner_text(), WAIT_S, "the env yaml")
    page.locator("#library-detail [data-trains=clip]").wait_for(timeout=WAIT_S * 1000)
    page.click("#detail-close")
    page.locator("#library-detail").wait_for(state="hidden")
    assert page.errors == []
    page.close()


def test_the_launch_form_offers_the_clips_its_arg_files_character_plays(browser, server: StudioProcess) -> None:
    page = open_page(browser, server, 1280, 720)
    page.click("#launch-box summary")
    assert page.locator("#arg-file").input_value().endswith("deepmimic_humanoid_demo_ppo_args.txt")  # the default
    clips = page.locator("#motion-file")
    wait_for(lambda: clips.get_attribute("data-frame-dim") == "34", WAIT_S, "the humanoid's clips", page=page)
    offered = clips.locator("option").evaluate_all("os => os.map(o => o.value)")
    assert SQUAT in offered and "data/motions/odd.pkl" not in offered  # 10 values a frame: no humanoid clip
    assert "data/datasets/mix.yaml" in offered  # datasets stay: their clips are checked at the start
    page.close()


def test_a_dataset_lists_its_clips_and_weights_and_a_click_plays_one(browser, server: StudioProcess) -> None:
    page = open_page(browser, server, 1280, 720)
    show_humanoid(page, server)
    tab(page, "datasets")
    mix = item(page, "data/datasets/mix.yaml")
    assert "2 clips · 1 missing" in mix.inner_text()
    mix.click()
    rows = page.locator("#library-detail table.dataset tr.clip")
    wait_for(lambda: rows.count() == 2, WAIT_S, "the dataset's two clips")
    squat, missing = rows.nth(0).inner_text(), rows.nth(1)
    assert "humanoid_demo_squat.pkl" in squat and "3" in squat and "75.0 %" in squat, squat
    assert "missing" in missing.get_attribute("class") and "25.0 %" in missing.inner_text()
    assert missing.inner_text().startswith("✗") and "missing:" in missing.get_attribute("title")
    missing.click()  # a missing clip plays nothing
    rows.nth(0).click()
    wait_for(lambda: (s := state(server))["clip"].endswith("humanoid_demo_squat.pkl") and s["playing"], WAIT_S, "clip")
    assert page.errors == []
    page.close()


def test_the_reference_datasets_list_their_clips(browser, test_data: Path, tmp_path: Path) -> None:
    (tmp_path / "runs").mkdir()
    server = StudioProcess(tmp_path / "runs", test_data)
    try:
        page = open_page(browser, server, 1280, 720)
        api = {d["path"]: d for d in server.get("/api/configs").json()["datasets"]}
        walk_run = api["data/datasets/dataset_humanoid_locomotion.yaml"]
        tab(page, "datasets")
        item(page, walk_run["path"]).click()
        rows = page.locator("#library-detail table.dataset tr.clip")
        wait_for(lambda: rows.count() == len(walk_run["motions"]), WAIT_S, "one row per clip of the dataset")
        assert page.locator("#library-detail table.dataset tr.missing").count() == walk_run["missing"]
        first = next(i for i, c in enumerate(walk_run["motions"]) if c["exists"])
        rows.nth(first).click()
        name = walk_run["motions"][first]["file"].split("/")[-1]
        wait_for(lambda: state(server)["clip"].endswith(name), WAIT_S, f"{name} in the scene")
        assert page.errors == []
        page.close()
    finally:
        server.stop()


def test_uploads_are_the_same_clip_again_and_deletable(browser, server: StudioProcess, tmp_path: Path) -> None:
    page = open_page(browser, server, 1280, 720)
    page.on("dialog", lambda d: d.accept())  # the "delete this clip?" confirmation
    uploads = server.runs_dir / "uploads"
    mine = tmp_path / "mine.pkl"
    mine.write_bytes(DEMO_CLIP.read_bytes())
    page.set_input_files("#upload", str(mine))
    first = item(page, str(uploads / "mine.pkl"))
    first.wait_for(timeout=WAIT_S * 1000)
    assert "uploaded mine.pkl" in page.locator("#library-status").inner_text()
    # The same bytes under another name: the upload already there, no copy.
    again = tmp_path / "again.pkl"
    again.write_bytes(DEMO_CLIP.read_bytes())
    page.set_input_files("#upload", str(again))
    wait_for(lambda: "same clip as mine.pkl" in page.locator("#library-status").inner_text(), WAIT_S, "the duplicate")
    assert sorted(p.name for p in uploads.glob("*.pkl")) == ["mine.pkl"]
    assert page.locator("#library-list .item[data-path$='.pkl']").filter(has_text="again").count() == 0
    # A focused Delete button keeps its focus while another upload changes the list around it.
    first.locator("button[data-action=delete]").focus()
    other = tmp_path / "other.pkl"
    other.write_bytes(clip_bytes(34))
    page.set_input_files("#upload", str(other))
    item(page, str(uploads / "other.pkl")).wait_for(timeout=WAIT_S * 1000)
    assert page.evaluate("document.activeElement.closest('.item').dataset.path") == str(uploads / "mine.pkl")
    first.locator("button[data-action=delete]").click()
    first.wait_for(state="detached", timeout=WAIT_S * 1000)
    assert sorted(p.name for p in uploads.glob("*.pkl")) == ["other.pkl"]
    assert "deleted mine.pkl" in page.locator("#library-status").inner_text()
    assert item(page, SQUAT).locator("button[data-action=delete]").count() == 0  # a data folder's clip stays
    item(page, str(uploads / "other.pkl")).locator("button[data-action=delete]").click()
    item(page, str(uploads / "other.pkl")).wait_for(state="detached", timeout=WAIT_S * 1000)
    assert page.errors == []
    page.close()


def test_files_that_fail_to_load_are_listed_with_their_reasons(browser, server: StudioProcess) -> None:
    page = open_page(browser, server, 1280, 720)
    chars = {c["path"]: c for c in server.get("/api/characters").json()}
    tab(page, "characters")
    broken = item(page, "data/assets/broken/broken.xml")
    assert "broken" in broken.get_attribute("class")
    assert chars["data/assets/broken/broken.xml"]["error"] in broken.inner_text()
    tab(page, "clips")
    odd = item(page, "data/motions/odd.pkl")
    assert "no character fits" in odd.inner_text()
    tried = {li.get_attribute("data-character"): li.inner_text() for li in odd.locator("li").all()}
    assert "did not load" in tried["data/assets/broken/broken.xml"]
    assert "28 DoFs: takes 34 values per frame" in tried[HUMANOID]
    assert "no character fits 10 values per frame" in odd.get_attribute("title")
    assert page.errors == []
    page.close()
