"""Spec, in a real browser (Debian's chromium driven by Playwright): the console of the
SEEG deployment shows the procedure live and answers the operator. START moves the
robot, an occluded tracker is swapped, a STOP enables RELEASE, which must be armed
then confirmed, and motion resumes; a refused command shows its reason.

Set FW_SCREENSHOTS=DIR to keep screenshots of the main states (docs/ has them)."""

import os
import shutil
from pathlib import Path

import pytest

from framework.console.model import ConsoleModel
from framework.console.server import ConsoleServer
from framework.deployer import Deployment
from framework.remote import RemoteComponent
from tests.conftest import REPO, private_topology

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
playwright = pytest.importorskip("playwright.sync_api", reason="playwright is not installed")
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed")
WAIT_MS = 20_000  # a bound for slow machines, not a speed requirement


@pytest.fixture
def seeg_console(bus_config, tmp_path):
    topology = private_topology(REPO / "topologies" / "seeg.yaml", bus_config, tmp_path)
    deployment = Deployment(topology, tmp_path / "logs")
    deployment.start()
    model = ConsoleModel(deployment.hub, topology, deployment.coordinator.chart).start()
    server = ConsoleServer(model, "127.0.0.1", 0)
    server.start()
    yield server, deployment
    server.stop()
    model.stop()
    deployment.stop()


@pytest.fixture
def page():
    with playwright.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        yield browser.new_page(viewport={"width": 1400, "height": 1000})
        browser.close()


def shot(page, name):
    folder = os.environ.get("FW_SCREENSHOTS")
    if folder:
        Path(folder).mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(Path(folder) / f"console_{name}.png"), full_page=True)


def text_is(page, testid, expected):
    page.wait_for_function(
        "([id, text]) => document.querySelector(`[data-testid=${id}]`).textContent"
        ".startsWith(text)",
        arg=[testid, expected],
        timeout=WAIT_MS,
    )


def test_the_operator_drives_the_procedure_from_the_browser(seeg_console, page):
    server, deployment = seeg_console
    page.goto(server.url)
    text_is(page, "link", "live")
    text_is(page, "operation", "wait")
    assert page.is_disabled("#release"), "nothing to release while waiting"
    page.wait_for_selector("#start:enabled", timeout=WAIT_MS)
    page.wait_for_selector("#chart-svg g.node.active", timeout=WAIT_MS)
    shot(page, "wait")

    page.click("#start")
    text_is(page, "answer", "e_START: accepted")
    text_is(page, "operation", "approaching target")
    text_is(page, "tracker", "certus")
    shot(page, "moving")

    certus = RemoteComponent(deployment.hub, "certus")
    certus.call("occlude", tool="cto")
    text_is(page, "tracker", "vicra")
    certus.call("occlude", tool="cto", hidden=False)

    page.click("#stop")
    text_is(page, "operation", "stopped")
    page.wait_for_selector("#release:enabled", timeout=WAIT_MS)
    shot(page, "stopped")
    page.click("#release")
    assert page.is_visible("#release-confirm") and page.is_hidden("#release")
    page.click("#release-confirm")
    text_is(page, "answer", "e_RELEASE: accepted")
    text_is(page, "operation", "approaching")

    # a command the chart cannot take now is answered with the reason
    page.evaluate("send('e_RELEASE')")
    text_is(page, "answer", "e_RELEASE: refused: e_RELEASE is not taken in")
    page.wait_for_selector("#log-lines li.warning", timeout=WAIT_MS)


def test_a_lost_connection_is_shown_and_the_data_marked_stale(seeg_console, page):
    server, _ = seeg_console
    page.goto(server.url)
    text_is(page, "link", "live")
    server.stop()
    text_is(page, "link", "connection lost")
    assert "stale" in page.get_attribute("main", "class")
