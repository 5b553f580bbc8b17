"""Measure the dashboard in headless chromium against `isorig serve` and print the figures (docs/dashboard.md).

    .venv/bin/python -m tests.e2e.bench_dashboard [--seconds 10] [--json]

1. Redraws per second of the live view (all plots: 10 channels at 1 kHz, x-y loop) while one test streams at
   speed 1, 3D view off; the mean and worst time of one redraw.
2. Page load to first live frame: a page opened while a test runs; from navigation start to the first redraw
   that shows live samples (performance.now()).
3. The same page with the 3D view on: dashboard redraws per second and the 3D view's animation frames per second
   (requestAnimationFrame inside the viewer iframe; headless chromium renders WebGL in software).
Not a test: nothing is asserted. Chromium runs with the same flags as the e2e tests.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from playwright.sync_api import sync_playwright

from .harness import Server, launch, sine_test

RAF_COUNTER = """() => {
  const w = document.querySelector('#viewer-box iframe').contentWindow;
  w.__frames = 0;
  const tick = () => { w.__frames++; w.requestAnimationFrame(tick); };
  w.requestAnimationFrame(tick);
}"""


def measure(page, seconds: float, viewer: bool = False) -> dict:
    m0 = page.evaluate("() => ({...window.__isorig})")
    v0 = page.evaluate("() => document.querySelector('#viewer-box iframe').contentWindow.__frames") if viewer else 0
    t0 = time.monotonic()
    time.sleep(seconds)
    m1 = page.evaluate("() => ({...window.__isorig})")
    v1 = page.evaluate("() => document.querySelector('#viewer-box iframe').contentWindow.__frames") if viewer else 0
    dt = time.monotonic() - t0
    redraws = m1["redraws"] - m0["redraws"]
    out = {
        "seconds": round(dt, 2),
        "animation_frames_per_s": round((m1["frames"] - m0["frames"]) / dt, 1),
        "redraws_per_s": round(redraws / dt, 1),
        "redraw_ms_mean": round((m1["drawMsTotal"] - m0["drawMsTotal"]) / max(1, redraws), 2),
        "redraw_ms_max_so_far": round(m1["drawMsMax"], 1),
        "samples_per_s": round((m1["samples"] - m0["samples"]) / dt, 0),
    }
    if viewer:
        out["viewer_frames_per_s"] = round((v1 - v0) / dt, 1)
    return out


def run(seconds: float, width: int, height: int) -> dict:
    results = {"viewport": f"{width}x{height}"}
    with tempfile.TemporaryDirectory() as tmp, sync_playwright() as p:
        browser = launch(p)
        for viewer in (False, True):
            srv = Server(Path(tmp) / f"viewer{int(viewer)}", viewer=viewer).start()
            try:
                cycles = int((seconds + 20) * 0.5) + 2
                test_id = srv.start_test(sine_test(cycles=cycles, speed=1.0))
                srv.wait_status(test_id, {"running"}, timeout_s=20)
                time.sleep(1.0)
                page = browser.new_page(viewport={"width": width, "height": height})
                t_nav = time.monotonic()
                page.goto(srv.url + ("/?viewer=on" if viewer else "/"))
                page.wait_for_function("window.__isorig && window.__isorig.firstLiveFrameMs !== null", timeout=30000)
                wall_ms = (time.monotonic() - t_nav) * 1000
                first = page.evaluate("window.__isorig.firstLiveFrameMs")
                key = "viewer_on" if viewer else "viewer_off"
                if viewer:
                    page.frame_locator("#viewer-box iframe").locator("canvas").first.wait_for(timeout=30000)
                    page.evaluate(RAF_COUNTER)
                    time.sleep(8.0)  # viser's first seconds compile shaders (software WebGL): not steady state
                time.sleep(1.0)
                results[key] = {
                    "first_live_frame_ms": round(first, 0),
                    "first_live_frame_wall_ms": round(wall_ms, 0),
                    **measure(page, seconds, viewer),
                }
                page.close()
                srv.call("POST", f"/api/tests/{test_id}/abort", token=True)
            finally:
                srv.stop()
        browser.close()
    return results


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="measuring window per case (s)")
    ap.add_argument("--width", type=int, default=1500)
    ap.add_argument("--height", type=int, default=1700, help="tall enough to show every panel, 3D view included")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    res = run(args.seconds, args.width, args.height)
    if args.json:
        print(json.dumps(res, indent=2))
        return
    print(f"headless chromium, viewport {res['viewport']}, one test streaming at speed 1 (1 kHz, 10 channels)")
    for key, label in (("viewer_off", "3D view off"), ("viewer_on", "3D view on")):
        r = res[key]
        line = (f"{label:12s}: first live frame {r['first_live_frame_ms']:.0f} ms after navigation start; "
                f"{r['redraws_per_s']} redraws/s of {r['animation_frames_per_s']} animation frames/s; "
                f"redraw {r['redraw_ms_mean']} ms mean, {r['redraw_ms_max_so_far']} ms worst; "
                f"{r['samples_per_s']:.0f} samples/s received")
        if "viewer_frames_per_s" in r:
            line += f"; 3D view {r['viewer_frames_per_s']} frames/s"
        print(line)


if __name__ == "__main__":
    main()
