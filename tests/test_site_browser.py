"""The rendered leaderboard in a real headless Chromium (Debian's chromium, `make browser`).

Four submissions go through the real ``leaderboard submit`` (re-scored by the benchmark), the
site is rendered and served by ``leaderboard.serve`` on a free localhost port, and playwright
drives the browser: the page loads, clicking column headers sorts the rows in the order the
known metrics dictate (ascending, then descending), every image decodes, the console stays
free of errors, and no request leaves the local server.
"""

from __future__ import annotations

import re
import threading

import pytest
from playwright.sync_api import sync_playwright

from leaderboard import cli
from leaderboard.serve import make_server
from test_leaderboard import CLASSES, make_dataset, write_predictions, write_results

CHROMIUM = "/usr/bin/chromium"
ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
# name -> (simple offset, complex offset, ms per mesh); same offsets for every class, so
# Simple MSE = s^2, Complex MSE = c^2, Variation MSE = (s - c)^2 exactly.
MODELS = {"zeta-net": (1.0, 2.0, 3.0), "alpha-net": (3.0, 1.0, 0.2), "mid-net": (2.0, 2.5, 40.0)}


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    root = tmp_path_factory.mktemp("site")
    data = make_dataset(root / "data")
    entries = root / "entries"
    for name, (s, c, ms) in MODELS.items():
        pred = write_predictions(root / f"{name}.h5", data, offsets={k: (s, c) for k in CLASSES})
        cli.main(
            [
                "submit",
                str(write_results(root / f"{name}.json", data, pred, name=name, ms_per_mesh=ms)),
                "--predictions",
                str(pred),
                "--data",
                str(data),
                "--entries",
                str(entries),
                "--unregistered",
            ]
        )
    flat = write_predictions(root / "flat.h5", data, collapse=True)
    cli.main(
        [
            "submit",
            str(write_results(root / "flat.json", data, flat, name="flat-net", ms_per_mesh=0.01)),
            "--predictions",
            str(flat),
            "--data",
            str(data),
            "--entries",
            str(entries),
            "--link",
            "https://example.org/flat",
            "--unregistered",
        ]
    )
    cli.main(["simulator", "--data", str(data), "--entries", str(entries), "--ms-per-mesh", "120"])
    cli.main(["render", "--out", str(root / "site"), "--entries", str(entries)])
    server = make_server(root / "site", port=0)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{server.server_port}/"
    server.shutdown()
    server.server_close()


def _names(page) -> list[str]:
    """Model rows in page order (the harness's reference rows sort with them, left out here)."""
    names = page.eval_on_selector_all(
        "table.board tbody tr", "rows => rows.map(r => r.cells[1].firstChild.textContent)"
    )
    return [n for n in names if not n.startswith("reference: ")]


def test_page_sorts_renders_images_and_stays_local(site):
    errors, requests = [], []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        try:
            page = browser.new_page()
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda exc: errors.append(str(exc)))
            page.on("requestfailed", lambda r: errors.append(f"failed: {r.url}"))
            page.on("request", lambda r: requests.append(r.url))
            response = page.goto(site, wait_until="load")
            assert response.status == 200
            assert page.title() == "Basic Shapes leaderboard"

            # rendered order: Complex MSE ascending (alpha 1, zeta 4, mid 6.25, then collapsed flat)
            assert _names(page) == ["alpha-net", "zeta-net", "mid-net", "flat-net"]
            flagged = page.eval_on_selector_all("table.board tr.collapsed", "r => r.length")
            assert flagged == 1

            header = page.locator("table.board thead th", has_text="Simple MSE")
            header.locator("button").click()
            assert header.get_attribute("aria-sort") == "ascending"
            assert _names(page) == ["zeta-net", "mid-net", "alpha-net", "flat-net"]
            header.locator("button").click()
            assert header.get_attribute("aria-sort") == "descending"
            assert _names(page) == ["flat-net", "alpha-net", "mid-net", "zeta-net"]

            page.locator("table.board thead th", has_text="ms / mesh").locator("button").click()
            assert _names(page) == ["flat-net", "alpha-net", "zeta-net", "mid-net"]
            page.locator("table.board thead th", has_text="Model").locator("button").click()
            assert _names(page) == ["alpha-net", "flat-net", "mid-net", "zeta-net"]
            assert header.get_attribute("aria-sort") is None

            per_class = page.locator(
                "table.per-class thead th",  # not "OOD Variation MSE"
                has_text=re.compile(r"^Variation MSE"),
            )
            per_class.locator("button").click()
            values = page.eval_on_selector_all(
                "table.per-class tbody tr",
                "rows => rows.map(r => parseFloat(r.cells[4].dataset.value))",
            )
            assert len(values) == 4 * len(CLASSES) and values == sorted(values)

            images = page.evaluate(
                "Array.from(document.images).map(i => [i.getAttribute('src'), "
                "i.complete, i.naturalWidth, i.naturalHeight])"
            )
            assert len(images) == 3, images  # speed vs error, per class, example
            for src, complete, width, height in images:
                assert complete and width > 0 and height > 0, src
        finally:
            browser.close()
    assert errors == []
    assert requests and all(u.startswith(site) or u.startswith("data:") for u in requests), requests


@pytest.mark.parametrize("width, height", [(1400, 900), (390, 844)])
def test_board_fits_a_desktop_and_a_phone(site, width, height):
    """At 1,400 px the whole board fits without sideways scrolling; at 390 px (a phone) the
    page itself never scrolls sideways: the table scrolls inside its own box."""
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        try:
            page = browser.new_page(viewport={"width": width, "height": height})
            page.goto(site, wait_until="load")
            page_width = page.evaluate("document.documentElement.scrollWidth")
            assert page_width <= width, page_width
            box = page.eval_on_selector(
                "div.scroll", "b => [b.scrollWidth, b.clientWidth, getComputedStyle(b).overflowX]"
            )
            assert box[2] == "auto"
            if width >= 1400:
                assert box[0] <= box[1], box  # nothing hidden to scroll to
            rows = page.eval_on_selector_all(
                "table.board tbody tr", "rows => rows.map(r => r.getBoundingClientRect().height)"
            )
            assert max(rows) <= 90, rows  # compact rows (they were 160-203 px)
        finally:
            browser.close()
