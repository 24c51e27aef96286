"""The web page in a real headless browser: Debian's chromium driven by Playwright.

The API runs in uvicorn on a loopback port against the throwaway Redis, with a real worker
process; a job is submitted through the page's form, followed to ``finished``, and opened in
the viewer. Every request to another host is refused and recorded (the page must work
offline). The viewer's screenshot is saved in ``tests/artifacts/``.

Playwright is used only as a driver of the installed chromium (``.ci/run`` installs it);
it never downloads a browser. ``MOJU_TEST_CHROMIUM`` names another chromium binary; without
one the tests are skipped.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import time
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import urlsplit

import httpx
import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from moju_cli.main import cli
from moju_core import reconstruct
from moju_core.io import Measurements, write_measurements, write_result
from moju_core.neighbour_check import trusted
from moju_core.params import SolverParams

CHROMIUM = Path(os.environ.get("MOJU_TEST_CHROMIUM", "/usr/bin/chromium"))
pytestmark = pytest.mark.skipif(
    not CHROMIUM.is_file(),
    reason=f"no chromium at {CHROMIUM} (apt-get install chromium; .ci/run does it as root)",
)

ARTIFACTS = Path(__file__).resolve().parents[1] / "artifacts"
LAUNCH_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
#: With max_iter 1500, a 300-point job that runs for a few seconds: long enough to see several
#: progress events (as in test_service_end_to_end.py).
WATCHABLE = {"tol": 0.0, "rho_growth": 1.01, "rho_max": 1e12, "seed": 2}
SCENE = "#viewer-container .moju-scene"


@pytest.fixture(scope="module")
def browser() -> Iterator:
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        launched = playwright.chromium.launch(executable_path=str(CHROMIUM), args=LAUNCH_ARGS)
        yield launched
        launched.close()


class Watched:
    """A page whose console errors, uncaught exceptions and foreign requests are recorded."""

    def __init__(self, page) -> None:
        self.page = page
        self.console_errors: list[str] = []
        self.foreign_requests: list[str] = []
        page.on(
            "console",
            lambda message: message.type == "error" and self.console_errors.append(message.text),
        )
        page.on("pageerror", lambda error: self.console_errors.append(f"uncaught: {error}"))
        page.route("**/*", self._only_local)

    def _only_local(self, route) -> None:
        url = route.request.url
        parts = urlsplit(url)
        if parts.scheme in ("data", "blob", "file") or parts.hostname == "127.0.0.1":
            route.continue_()
        else:
            self.foreign_requests.append(url)
            route.abort()


@pytest.fixture
def watched(browser) -> Iterator[Watched]:
    context = browser.new_context(viewport={"width": 1280, "height": 900}, accept_downloads=True)
    page = context.new_page()
    page.set_default_timeout(30_000)
    try:
        yield Watched(page)
    finally:
        context.close()


def scene_points(page) -> dict:
    """What plotly drew in the viewer: trace type, point count, first coordinates, canvases."""
    return page.evaluate(
        """(selector) => {
            const scene = document.querySelector(selector);
            const trace = scene.data[0];
            return {type: trace.type, count: trace.x.length, x: Array.from(trace.x),
                    canvases: scene.querySelectorAll("canvas").length};
        }""",
        SCENE,
    )


def coloured_fraction(page) -> float:
    """Fraction of the scene's pixels in colour: the group-coloured markers (axes are grey)."""
    image = Image.open(io.BytesIO(page.locator(SCENE).screenshot())).convert("RGB")
    rgb = np.asarray(image).astype(int)
    fraction = float((rgb.max(axis=2) - rgb.min(axis=2) > 60).mean())
    print(f"coloured pixels of the scene: {fraction:.4f}")
    return fraction


def assert_viewer_fits(page) -> None:
    """On first open the convergence plot fits its card: the page does not grow sideways."""
    from playwright.sync_api import TimeoutError as PlaywrightTimeout

    page.wait_for_selector("#viewer-container .moju-convergence .main-svg")
    with contextlib.suppress(PlaywrightTimeout):  # the assertion below says what is wrong
        page.wait_for_function(
            """() => document.documentElement.scrollWidth <= window.innerWidth""", timeout=5000
        )
    fit = page.evaluate(
        """() => {
            const plot = document.querySelector("#viewer-container .moju-convergence");
            const svg = plot.querySelector(".main-svg").getBoundingClientRect();
            const card = document.querySelector("#viewer").getBoundingClientRect();
            return {page: document.documentElement.scrollWidth, window: window.innerWidth,
                    svgRight: svg.right, cardRight: card.right};
        }"""
    )
    assert fit["page"] <= fit["window"] and fit["svgRight"] <= fit["cardRight"] + 1, fit


def test_submit_follow_and_view_a_job(
    watched: Watched, live_api: str, worker, input_file: Path, tmp_path: Path
) -> None:
    page = watched.page
    page.goto(live_api + "/")
    # The form is built from the parameter schema; the readiness line sees the worker.
    page.wait_for_selector("#method option[value=moju]", state="attached")
    page.wait_for_function("document.querySelector('#readiness').textContent.startsWith('Ready')")
    assert page.locator("#readiness").text_content() == "Ready: 1 worker waiting for jobs."
    options = page.locator("#rotations option").evaluate_all("os => os.map(o => o.value)")
    assert options == ["", "auto", "intersection", "windowed", "rigid", "plane", "known"]
    # Every select shows its whole option text (none is cut by a narrow field).
    cut = page.evaluate(
        """() => Array.from(document.querySelectorAll("#submit-form select")).flatMap(s => {
            const shown = s.getBoundingClientRect().width;
            s.style.width = "max-content";
            const needed = s.getBoundingClientRect().width;
            s.style.width = "";
            return needed > shown + 1 ? [[s.id, shown, needed]] : [];
        })"""
    )
    assert cut == [], cut

    # Record every distinct progress text the job list shows while the job runs.
    page.evaluate(
        """() => {
            window.seenProgress = [];
            new MutationObserver(() => {
                for (const node of document.querySelectorAll(".progress-text")) {
                    if (window.seenProgress.at(-1) !== node.textContent) {
                        window.seenProgress.push(node.textContent);
                    }
                }
            }).observe(document.querySelector("#jobs-body"), {childList: true, subtree: true});
        }"""
    )
    page.set_input_files("#file", str(input_file))
    page.select_option("#method", "moju")
    page.select_option("#rotations", "intersection")
    page.fill("#n_groups", "6")
    page.fill("#subspace_dim", "3")
    page.fill("#max_iter", "1500")
    page.fill("#extra_params", json.dumps(WATCHABLE))
    page.click("#submit-button")

    page.wait_for_selector("#submit-status:has-text('submitted job')")
    job_id = page.locator("#submit-status").text_content().removeprefix("submitted job ")
    row = f'tr[data-job-id="{job_id}"]'
    page.wait_for_selector(f'{row}[data-status="finished"]', timeout=60_000)
    assert page.locator(f"{row} .badge").text_content() == "finished"
    outcome = page.locator(f"{row} .progress-cell").text_content()
    assert outcome.startswith("1500 iterations, max_iter"), outcome

    job = httpx.get(f"{live_api}/v1/jobs/{job_id}").json()
    submitted = job["parameters"]
    assert (submitted["n_groups"], submitted["subspace_dim"], submitted["max_iter"]) == (6, 3, 1500)
    assert submitted["rotations"] == "intersection"
    assert (submitted["tol"], submitted["seed"]) == (0, 2)
    # Live progress came from the event stream: several iteration counts were shown.
    seen = page.evaluate("window.seenProgress")
    iterations = {int(m.group(1)) for text in seen if (m := re.search(r"iteration (\d+)", text))}
    assert len(iterations) >= 2, seen
    # No time left is promised before it can be estimated, nor a meaningless "0.0 s".
    assert not [text for text in seen if re.search(r"about 0\.0 s left|iteration 1 /.* left", text)]

    # Downloads are links to the API's files.
    links = page.locator(f"{row} a.download").evaluate_all("as => as.map(a => a.href)")
    assert links == [
        f"{live_api}/v1/jobs/{job_id}/result?format=npz",
        f"{live_api}/v1/jobs/{job_id}/result?format=h5",
        f"{live_api}/v1/jobs/{job_id}/frames.zip",
    ]
    with page.expect_download() as download:
        page.click(f"{row} a.download:has-text('npz')")
    saved = tmp_path / "result.npz"
    download.value.save_as(saved)
    assert saved.read_bytes()[:2] == b"PK"

    # The viewer: frame 0 has every point, drawn on a WebGL canvas.
    page.click(f"{row} button.view")
    page.wait_for_selector('#viewer-container[data-rendered-frame="0"]')
    assert page.url.endswith(f"#view={job_id}")
    assert_viewer_fits(page)
    first = scene_points(page)
    assert first["type"] == "mesh3d"  # the upload had triangles
    assert first["count"] == 300 and first["canvases"] >= 1
    page.select_option("#viewer-container .moju-style", "points")
    page.wait_for_function(f"document.querySelector('{SCENE}').data[0].type === 'scatter3d'")
    points = scene_points(page)
    assert points["count"] == 300 and points["x"] == first["x"]
    assert coloured_fraction(page) > 0.002
    assert page.locator("#viewer-container .moju-curve option").count() >= 4

    # Moving the slider draws another frame: the data of that frame, from the API.
    page.focus("#viewer-container .moju-frame")
    for _ in range(3):
        page.keyboard.press("ArrowRight")
    page.wait_for_selector('#viewer-container[data-rendered-frame="3"]')
    moved = scene_points(page)
    assert moved["count"] == 300 and moved["x"] != first["x"]
    frame_3 = httpx.get(f"{live_api}/v1/jobs/{job_id}/viewer-data/frames/3").json()
    assert moved["x"] == frame_3["x"]
    assert page.locator("#viewer-container .moju-frame-label").text_content() == "frame 4 / 10"

    page.select_option("#viewer-container .moju-color", "depth")
    page.wait_for_function(
        f"Array.isArray(document.querySelector('{SCENE}').data[0].marker.color)"
        f" && typeof document.querySelector('{SCENE}').data[0].marker.color[0] === 'number'"
    )
    ARTIFACTS.mkdir(exist_ok=True)
    screenshot = ARTIFACTS / "service_ui_viewer.png"
    page.screenshot(path=str(screenshot), full_page=True)
    print(f"screenshot: {screenshot}")

    # Play advances the frames by itself; Pause stops.
    page.click("#viewer-container .moju-play")
    page.wait_for_function(
        "!['3', undefined].includes(document.querySelector('#viewer-container')"
        ".dataset.renderedFrame)"
    )
    page.click("#viewer-container .moju-play")
    assert page.locator("#viewer-container .moju-play").text_content() == "Play"

    # Delete (after confirming): the row and the viewer go, and so does the job.
    page.once("dialog", lambda dialog: dialog.accept())
    page.click(f"{row} button.delete")
    page.wait_for_selector(row, state="detached")
    page.wait_for_selector("#viewer", state="hidden")
    assert httpx.get(f"{live_api}/v1/jobs/{job_id}").status_code == 404

    assert watched.console_errors == []
    assert watched.foreign_requests == []


def test_api_errors_are_shown_as_stated_and_jobs_can_be_cancelled(
    watched: Watched, live_api: str, input_file
) -> None:
    """No worker here: the job stays queued until cancelled."""
    page = watched.page
    page.goto(live_api + "/")
    page.wait_for_selector("#method option[value=moju]", state="attached")
    page.set_input_files("#file", str(input_file))

    # A parameter the API refuses: its message, word for word.
    page.fill("#extra_params", '{"max_itr": 5}')
    page.click("#submit-button")
    page.wait_for_selector("#submit-error:not([hidden])")
    with input_file.open("rb") as handle:
        expected = httpx.post(
            f"{live_api}/v1/jobs",
            files={"file": (input_file.name, handle)},
            data={"params": json.dumps({"method": "moju", "max_itr": 5})},
        )
    assert expected.status_code == 422
    assert page.locator("#submit-error").text_content() == expected.json()["detail"]

    page.fill("#extra_params", "")
    page.fill("#n_groups", "0")
    page.click("#submit-button")
    page.wait_for_selector("#submit-error:has-text('n_groups')")
    assert page.locator("#submit-error").text_content() == (
        "parameter 'n_groups': Input should be greater than or equal to 1 (got 0)"
    )

    # Accepted, queued (no worker), cancelled, then deleted.
    page.fill("#n_groups", "")
    page.click("#submit-button")
    page.wait_for_selector("#submit-status:has-text('submitted job')")
    assert page.locator("#submit-error").is_hidden()
    job_id = page.locator("#submit-status").text_content().removeprefix("submitted job ")
    row = f'tr[data-job-id="{job_id}"]'
    page.wait_for_selector(f'{row}[data-status="queued"]')
    assert page.locator(f"{row} .progress-cell").text_content() == "waiting for a worker"
    page.click(f"{row} button.cancel")
    page.wait_for_selector(f'{row}[data-status="cancelled"]')
    assert httpx.get(f"{live_api}/v1/jobs/{job_id}").json()["status"] == "cancelled"
    page.once("dialog", lambda dialog: dialog.accept())
    page.click(f"{row} button.delete")
    page.wait_for_selector(row, state="detached")
    assert page.locator("#jobs-empty").is_visible()

    # The readiness line says why nothing runs.
    page.wait_for_function("document.querySelector('#readiness').textContent.startsWith('Not')")
    assert "worker" in page.locator("#readiness").text_content()
    # The browser logs each refused request (422, and 503 from /readyz) as an error; nothing else.
    unexpected = [
        text
        for text in watched.console_errors
        if not re.fullmatch(
            r"Failed to load resource: the server responded with a status of (422|503) .*", text
        )
    ]
    assert unexpected == []
    assert watched.foreign_requests == []


def test_standalone_file_of_moju_view(watched: Watched, small_sequence, tmp_path: Path) -> None:
    """``moju view`` writes the same viewer, which works from a file, offline."""
    input_path = write_measurements(
        tmp_path / "tracks.npz",
        Measurements(W=small_sequence.W, faces=small_sequence.faces, colors=small_sequence.colors),
    )
    result = reconstruct(small_sequence.W, SolverParams(max_iter=30))
    result_path = write_result(tmp_path / "result.h5", result)
    output = tmp_path / "result.html"
    run = CliRunner().invoke(
        cli, ["view", str(result_path), "--input", str(input_path), "-o", str(output)]
    )
    assert run.exit_code == 0, run.output

    page = watched.page
    started = time.monotonic()
    page.goto(output.as_uri())
    page.wait_for_selector('#viewer-container[data-rendered-frame="0"]')
    first = scene_points(page)
    assert first["type"] == "mesh3d" and first["count"] == 300 and first["canvases"] >= 1
    page.select_option("#viewer-container .moju-color", "input")
    page.focus("#viewer-container .moju-frame")
    page.keyboard.press("End")
    page.wait_for_selector('#viewer-container[data-rendered-frame="9"]')
    last = scene_points(page)
    assert last["count"] == 300 and last["x"] != first["x"]
    assert time.monotonic() - started < 20
    assert watched.console_errors == []
    assert watched.foreign_requests == []


def test_standalone_viewer_dims_or_hides_filled_in_points(
    watched: Watched, small_sequence, tmp_path: Path
) -> None:
    """Points a frame did not observe are a second, fainter trace; "hidden" drops them."""
    result = reconstruct(small_sequence.W, SolverParams(max_iter=5))
    result.visibility = np.ones((10, 300), dtype=bool)
    result.visibility[0, :40] = False
    result_path = write_result(tmp_path / "occluded.h5", result)
    output = tmp_path / "occluded.html"
    run = CliRunner().invoke(cli, ["view", str(result_path), "-o", str(output)])
    assert run.exit_code == 0, run.output

    page = watched.page
    page.goto(output.as_uri())
    page.wait_for_selector('#viewer-container[data-rendered-frame="0"]')
    traces = "document.querySelector('#viewer-container .moju-scene').data"
    drawn = page.evaluate(f"{traces}.map(t => [t.x.length, t.opacity ?? 1])")
    assert drawn == [[260, 1], [40, 0.3]]
    assert page.locator("#viewer-container .moju-filled").is_visible()
    page.select_option("#viewer-container .moju-filled", "hide")
    page.wait_for_function(f"{traces}.length === 1")
    assert page.evaluate(f"{traces}[0].x.length") == 260
    page.select_option("#viewer-container .moju-filled", "same")
    page.wait_for_function(f"{traces}.length === 1 && {traces}[0].x.length === 300")
    assert watched.console_errors == []
    assert watched.foreign_requests == []


def test_the_page_works_with_an_api_key(
    watched: Watched, settings, input_file: Path, tmp_path: Path
) -> None:
    """A server with keys: the page asks for one, then submits, follows (by polling),
    downloads and views with it."""
    from api_thread import serving
    from pydantic import SecretStr
    from service_testing import running_worker

    from service.auth import key_digest

    key = "browser-key-0123456789abcdef"
    keyed = settings.model_copy(update={"api_keys": SecretStr(f"sha256:{key_digest(key)}")})
    page = watched.page
    with serving(keyed) as base, running_worker(keyed, tmp_path / "worker.log"):
        page.goto(base + "/")
        page.wait_for_selector("#jobs-error:has-text('this server needs an API key')")
        page.fill("#api-key", key)
        page.dispatch_event("#api-key", "change")
        page.wait_for_selector("#jobs-error", state="hidden")
        page.wait_for_selector("#method option[value=moju]", state="attached")
        page.set_input_files("#file", str(input_file))
        page.fill("#max_iter", "30")
        page.click("#submit-button")
        page.wait_for_selector("#submit-status:has-text('submitted job')")
        job_id = page.locator("#submit-status").text_content().removeprefix("submitted job ")
        row = f'tr[data-job-id="{job_id}"]'
        page.wait_for_selector(f'{row}[data-status="finished"]', timeout=60_000)

        with page.expect_download() as download:
            page.click(f"{row} a.download:has-text('npz')")
        saved = tmp_path / "result.npz"
        download.value.save_as(saved)
        assert saved.read_bytes()[:2] == b"PK"
        assert download.value.suggested_filename == f"moju-{job_id}.npz"

        page.click(f"{row} button.view")
        page.wait_for_selector('#viewer-container[data-rendered-frame="0"]')
        assert scene_points(page)["count"] == 300
        # The key stays in the tab, never in an address.
        assert page.evaluate("sessionStorage.getItem('moju-api-key')") == key
        assert key not in page.url
    # Only the refusals before the key was given (401) reached the console.
    unexpected = [
        text
        for text in watched.console_errors
        if not re.fullmatch(
            r"Failed to load resource: the server responded with a status of 401 .*", text
        )
    ]
    assert unexpected == []
    assert watched.foreign_requests == []


def test_video_upload_through_the_page(
    watched: Watched, live_api: str, worker, tmp_path: Path
) -> None:
    """A tiny rendered video and its mask, submitted through the form: the worker tracks and
    solves it; every kept track has a shape in every frame, and the viewer shows the first frame
    with the tracks beside the 3D shape."""
    import cv2

    from moju_core.footage.render import render_sequence, write_video

    n_frames, (width, height) = 8, (96, 72)
    rendered = render_sequence("paper", width=width, height=height, n_frames=n_frames)
    video = write_video(tmp_path / "paper.mp4", rendered.frames)
    mask = tmp_path / "mask.png"
    cv2.imwrite(str(mask), rendered.mask.astype(np.uint8) * 255)

    page = watched.page
    page.set_viewport_size({"width": 1400, "height": 900})
    page.goto(live_api + "/")
    page.wait_for_selector("#method option[value=moju]", state="attached")
    page.set_input_files("#file", str(video))
    page.set_input_files("#mask", str(mask))
    page.fill("#focal", "150")
    page.fill("#max_iter", "5")
    page.click("#submit-button")
    page.wait_for_selector("#submit-status:has-text('submitted job')")
    job_id = page.locator("#submit-status").text_content().removeprefix("submitted job ")
    row = f'tr[data-job-id="{job_id}"]'
    page.wait_for_selector(f'{row}[data-status="finished"]', timeout=60_000)

    job = httpx.get(f"{live_api}/v1/jobs/{job_id}").json()
    assert job["input"]["format"] == "video" and job["input"]["video"]["has_mask"] is True
    assert job["parameters"]["max_iter"] == 5
    assert job["input"]["camera"]["source"] == "focal" and job["input"]["camera"]["K"][0][0] == 150
    assert "focal 150 px (focal)" in page.locator(f"{row} .camera").text_content()
    links = page.locator(f"{row} a.download").evaluate_all("as => as.map(a => a.href)")
    assert f"{live_api}/v1/jobs/{job_id}/tracks.npz" in links
    tracks = httpx.get(f"{live_api}/v1/jobs/{job_id}/tracks.npz")
    with np.load(io.BytesIO(tracks.content), allow_pickle=False) as data:
        W, visibility = data["W"], data["visibility"]
    n_tracks = job["result"]["tracking"]["reconstructed"]
    assert W.shape == (2 * n_frames, n_tracks) and n_tracks > 0
    result = httpx.get(f"{live_api}/v1/jobs/{job_id}/result", params={"format": "npz"})
    with np.load(io.BytesIO(result.content), allow_pickle=False) as data:
        shapes = data["shapes"]
        # the observations used: less the positions the perspective solve set aside
        np.testing.assert_array_equal(data["visibility"], trusted(W, visibility))
    assert shapes.shape == (n_frames, n_tracks, 3) and np.isfinite(shapes).all()

    # The viewer: the 3D shape has every track; beside it, the first frame of the video.
    page.click(f"{row} button.view")
    page.wait_for_selector('#viewer-container[data-rendered-frame="0"]')
    assert sum(page.evaluate(f"document.querySelector('{SCENE}').data.map(t => t.x.length)")) == (
        n_tracks
    )
    page.wait_for_selector("#viewer-frame:not([hidden])")
    page.wait_for_function("document.querySelector('#viewer-frame-image').naturalWidth > 0")
    size = page.evaluate(
        "(() => { const i = document.querySelector('#viewer-frame-image');"
        " return [i.naturalWidth, i.naturalHeight]; })()"
    )
    assert size == [width, height]
    assert_viewer_fits(page)
    # The first frame may appear only after the plots were drawn at the full width (a slow
    # image): the plots follow their narrower container.
    svg = "#viewer-container .moju-convergence .main-svg"
    narrow = page.evaluate(f"document.querySelector('{svg}').getBoundingClientRect().width")
    page.evaluate(
        """() => {
            document.querySelector("#viewer-frame").hidden = true;
            window.dispatchEvent(new Event("resize"));  // plotly redraws at the full width
        }"""
    )
    page.wait_for_function(
        f"document.querySelector('{svg}').getBoundingClientRect().width > {narrow}"
    )
    page.evaluate("document.querySelector('#viewer-frame').hidden = false")
    assert_viewer_fits(page)
    assert watched.console_errors == []
    assert watched.foreign_requests == []


def test_api_docs_render_offline(watched: Watched, live_api: str) -> None:
    """``/docs`` draws every operation of the API with no request to another host."""
    page = watched.page
    page.goto(live_api + "/docs")
    page.wait_for_selector("#swagger-ui .opblock")
    operations = sum(
        1
        for methods in httpx.get(f"{live_api}/openapi.json").json()["paths"].values()
        for method in methods
        if method in ("get", "post", "put", "patch", "delete")
    )
    assert page.locator("#swagger-ui .opblock").count() == operations
    assert watched.foreign_requests == []
