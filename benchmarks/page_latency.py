"""Click-to-visible-change latency of the studio's page in headless Chromium (software WebGL, as CI and
most laptops without a GPU driver in a container draw): the player's Play/Pause and Step buttons are
clicked at their screen position (`page.mouse.click`, no Playwright actionability checks in between)
while the clip plays in the 3D view, and the page itself times each click from the input event's
timestamp (`event.timeStamp`: when Chromium took the input, so the time the event waited behind the 3D
view's frames counts) to the first animation frame after the control changed (the button's text, the
frame label).

    python benchmarks/page_latency.py --clicks 10 --qualities auto,full,quarter   # starts its own studio
    python benchmarks/page_latency.py --url http://127.0.0.1:8000/ --clicks 10

`benchmarks/studio_bench.py --page-clicks N` runs the same measurement inside its own (and during
`--train-cmd`).
"""

from __future__ import annotations

import argparse
import shutil
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from playwright.sync_api import sync_playwright

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu"]  # as tests/studio/conftest.py launches it
VIEWPORT = {"width": 1280, "height": 720}
FIRST_FRAME_TIMEOUT_MS = 120_000

# Installed in the page: a click on a watched control starts a timer at the input's timestamp; the
# first DOM change of that control ends it at the next animation frame (the one that paints it).
PROBE = """
(() => {
  const watched = { play: () => document.getElementById('play').textContent,
                    step: () => document.getElementById('frame-label').textContent };
  window.__latency = [];
  let pending = null;
  document.addEventListener('click', (ev) => {
    const id = ev.target && ev.target.id;
    if (id in watched) pending = { id, t0: ev.timeStamp, before: watched[id]() };
  }, true);
  const check = () => {
    if (!pending || watched[pending.id]() === pending.before) return;
    const p = pending; pending = null;
    requestAnimationFrame(() => window.__latency.push({ id: p.id, ms: performance.now() - p.t0 }));
  };
  new MutationObserver(check).observe(document, { subtree: true, childList: true, characterData: true });
})();
"""


def _centre(page: Any, selector: str) -> tuple[float, float]:
    box = page.locator(selector).bounding_box()
    return box["x"] + box["width"] / 2, box["y"] + box["height"] / 2


def _wait_for_clip(page: Any) -> None:
    """Until the scene's canvas is drawn and the clip is playing (its frame label moves)."""
    page.wait_for_selector("#scene", timeout=FIRST_FRAME_TIMEOUT_MS)
    page.frame_locator("#scene").locator("canvas").first.wait_for(timeout=FIRST_FRAME_TIMEOUT_MS)
    page.wait_for_function("document.getElementById('play').textContent === 'Pause'", timeout=FIRST_FRAME_TIMEOUT_MS)


def _open(browser: Any, url: str, quality: str) -> Any:
    page = browser.new_page(viewport=VIEWPORT)
    page.add_init_script(f"localStorage.setItem('studio-scene-quality', {quality!r});")
    page.add_init_script(PROBE)
    page.goto(url)
    _wait_for_clip(page)
    time.sleep(2.0)  # the scene's first frames (and the page's first plots) drawn
    return page


def _click_round(page: Any, clicks: int, gap_s: float) -> tuple[list[dict[str, Any]], list[float]]:
    """`clicks` Pause/Play pairs (every other pause with a Step between) while the clip plays: the
    page's latency rows and the 3D view's drawn frames per second sampled between clicks."""
    play, step = _centre(page, "#play"), _centre(page, "#step")
    page.evaluate("window.__latency = []")
    fps = []
    for i in range(clicks):
        fps.append(float(page.inner_text("#scene-fps").split()[1]))  # "3D 12 fps", while it plays
        page.mouse.click(*play)
        time.sleep(gap_s)
        if i % 2:
            page.mouse.click(*step)
            time.sleep(gap_s)
        page.mouse.click(*play)
        time.sleep(gap_s)
    page.wait_for_timeout(1500)  # the last clicks' frames
    return page.evaluate("window.__latency"), fps


def click_latency(
    base: str, clicks: int, qualities: list[str], rounds: int = 2, token: str = "", gap_s: float = 0.4
) -> dict[str, dict[str, Any]]:
    """Per 3D-view quality (the page's setting): the click-to-visible latencies (ms) per control and
    the 3D view's frames per second, `rounds` rounds of `clicks` pairs each, the qualities interleaved
    so that a load change on the machine touches them alike."""
    if CHROMIUM is None:
        raise SystemExit("no chromium on PATH (apt-get install chromium)")
    url = base + (f"?token={token}" if token else "")
    out = {q: {"latency_ms": {}, "expected": {"play": 0, "step": 0}, "fps": []} for q in qualities}
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        for _ in range(rounds):
            for q in qualities:
                page = _open(browser, url, q)
                rows, fps = _click_round(page, clicks, gap_s)
                out[q]["software_gl"] = page.evaluate("document.getElementById('scene-quality').title")
                page.close()
                for r in rows:
                    out[q]["latency_ms"].setdefault(r["id"], []).append(float(r["ms"]))
                out[q]["expected"]["play"] += 2 * clicks
                out[q]["expected"]["step"] += clicks // 2
                out[q]["fps"] += fps
        browser.close()
    return out


def summary(result: dict[str, Any]) -> dict[str, dict[str, float]]:
    """p50/p99/max (ms) and the count seen against the count clicked, per control."""
    out = {}
    for k, n in result["expected"].items():
        v = np.array(result["latency_ms"].get(k, []))
        out[k] = {
            "seen": len(v),
            "clicked": n,
            "p50": float(np.percentile(v, 50)) if len(v) else float("nan"),
            "p99": float(np.percentile(v, 99)) if len(v) else float("nan"),
            "max": float(v.max()) if len(v) else float("nan"),
        }
    return out


def print_summary(title: str, results: dict[str, dict[str, Any]]) -> None:
    print(f"{title} (Chromium {VIEWPORT['width']}x{VIEWPORT['height']}, the 3D view visible, the clip playing):")
    for q, result in results.items():
        fps = np.median(result["fps"]) if result["fps"] else float("nan")
        print(f"  3D view {q} (3D view drew a median {fps:.0f} fps; {result.get('software_gl', '')}):")
        for k, s in summary(result).items():
            print(f"    {k:5s} {s['seen']}/{s['clicked']} changes seen  p50 {s['p50']:.0f} ms  p99 {s['p99']:.0f} ms  "
                  f"max {s['max']:.0f} ms")  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--url", help="a running studio (loopback); default: start one")
    ap.add_argument("--clicks", type=int, default=40)
    ap.add_argument("--token", default="")
    ap.add_argument("--qualities", default="auto,full", help="the page's 3D view settings to compare")
    ap.add_argument("--rounds", type=int, default=2)
    args = ap.parse_args()
    qualities = args.qualities.split(",")
    if args.url:
        base = args.url.rstrip("/") + "/"
        print_summary("click to visible change", click_latency(base, args.clicks, qualities, args.rounds, args.token))
        return
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from benchmarks.studio_server import studio_server

    with studio_server(argparse.Namespace(url=None, data_dir=None, server_pid=None)) as (base, _):
        print_summary("click to visible change", click_latency(base, args.clicks, qualities, args.rounds))


if __name__ == "__main__":
    main()
