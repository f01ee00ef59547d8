"""Spec, in a real browser (Debian's chromium driven by Playwright): the console of the
SEEG deployment shows the procedure live and answers the operator. START moves the
robot, an occluded tracker is swapped, a STOP enables RELEASE, which must be armed
then confirmed, and motion resumes; a refused command shows its reason.

Set FW_SCREENSHOTS=DIR to keep screenshots of the main states (docs/ has them)."""

import os
import shutil
from pathlib import Path

import pytest

from framework.remote import RemoteComponent
from tests.conftest import (
    REPO,
    SHARED_HOST_MARGIN,
    private_topology,
    wait_until,
    with_deadlines_stretched,
)
from tests.framework.console.conftest import served

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
playwright = pytest.importorskip("playwright.sync_api", reason="playwright is not installed")
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed")
WAIT_MS = 120_000  # a bound for a starved host (the suite runs beside busy loops), not a speed


def seeg(bus_config, tmp_path):
    """The SEEG topology on a private bus, its deadlines stretched for a shared host: these
    tests are about the console, test_seeg_faults.py about the deadlines."""
    topology = private_topology(REPO / "topologies" / "seeg.yaml", bus_config, tmp_path)
    return with_deadlines_stretched(topology, SHARED_HOST_MARGIN)


@pytest.fixture
def seeg_console(bus_config, tmp_path):
    with served(seeg(bus_config, tmp_path), tmp_path / "logs") as running:
        yield running


BROWSER_NICE = 10
"""The browser's nice level here. In an operating room the operator's browser runs on
a machine of its own; in these tests it shares 2 cores with the whole simulated OR,
whose producers it starved past their deadlines (CI: the people detector's 300 ms, a
tracker), so the console's behaviour failed on the host's capacity. Lowered, it takes
what the deployment leaves, as its own machine would give it."""


def lower_the_browser(nice: int = BROWSER_NICE) -> int:
    """Lower every thread of this process's browser processes (Chromium and
    Playwright's driver, and whatever they start later: threads inherit it) to `nice`;
    how many threads. Never needs a privilege: it only lowers."""
    mine, children = os.getpid(), {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            children.setdefault(int(stat.rsplit(")", 1)[1].split()[1]), []).append(int(entry.name))
    lowered, todo = 0, list(children.get(mine, []))
    while todo:
        pid = todo.pop()
        todo.extend(children.get(pid, []))
        try:
            command = (Path("/proc") / str(pid) / "cmdline").read_bytes()
        except OSError:
            continue
        if b"chrom" not in command and b"playwright" not in command:
            continue  # the deployment's own processes
        for task in (Path("/proc") / str(pid) / "task").glob("*"):
            try:
                if os.getpriority(os.PRIO_PROCESS, int(task.name)) < nice:
                    os.setpriority(os.PRIO_PROCESS, int(task.name), nice)
                    lowered += 1
            except OSError:
                continue
    return lowered


@pytest.fixture
def page():
    """Chromium with a page, lowered to `BROWSER_NICE`. Tests ask for it before their
    deployment: launched while the simulated OR already ran, Chromium's start (its
    processes, at the default priority until lowered) starved the OR's producers for
    seconds (a camera process silent 300 ms, a 5 ms detector update taking 94 ms)."""
    with playwright.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        page = browser.new_page(viewport={"width": 1400, "height": 1000})
        page.set_default_timeout(WAIT_MS)
        lower_the_browser()
        yield page
        browser.close()


def shot(page, name):
    """With FW_SCREENSHOTS: a picture of the page as it is now, through its snapshot
    view (`&snapshot`, the way a user takes one for a bug report: a second page that
    finishes loading), for docs/console and the README."""
    folder = os.environ.get("FW_SCREENSHOTS")
    if not folder:
        return
    Path(folder).mkdir(parents=True, exist_ok=True)
    url = page.url
    if "snapshot" in url:
        page.screenshot(path=str(Path(folder) / f"console_{name}.png"), full_page=True)
        return
    context = page.context.browser.new_context(viewport=page.viewport_size)
    context.add_cookies(page.context.cookies())  # this run's login
    try:
        still = context.new_page()
        still.goto(url + ("&" if "?" in url else "?") + "snapshot", wait_until="networkidle")
        still.wait_for_selector("body[data-snapshot=ready]")
        still.wait_for_timeout(300)  # the panel's canvases drawn
        still.screenshot(path=str(Path(folder) / f"console_{name}.png"), full_page=True)
    finally:
        context.close()


def wait_for(page, script, arg, shown, expected):
    """Wait until `script(arg)` holds in the page; if it never does, fail saying what
    the page showed (`shown`: a selector) instead of a bare timeout."""
    try:
        page.wait_for_function(script, arg=arg, timeout=WAIT_MS)
    except playwright.Error:
        robot = (
            page.inner_text("[data-testid=robot]")
            if page.query_selector("[data-testid=robot]")
            else ""
        )
        log = page.evaluate(
            "() => [...document.querySelectorAll('#log-lines li')].slice(0, 16)"
            ".map(li => li.textContent)"
        )
        pytest.fail(
            f"{shown} shows {page.inner_text(shown)!r}, expected {expected} (robot: {robot!r});"
            " the console's log ended with:\n  " + "\n  ".join(log)
        )


TILE = '(document.querySelector(`[data-testid=${id}]`) || {textContent: ""}).textContent'


def text_is(page, testid, expected):
    script = f"([id, text]) => {TILE}.startsWith(text)"
    wait_for(page, script, [testid, expected], f"[data-testid={testid}]", f"{expected!r}...")


def text_matches(page, testid, pattern):
    script = f"([id, re]) => new RegExp(re).test({TILE})"
    wait_for(page, script, [testid, pattern], f"[data-testid={testid}]", f"/{pattern}/")


def log_has(page, text):
    script = "(t) => [...document.querySelectorAll('#log-lines li')].some(li => li.textContent.includes(t))"
    wait_for(page, script, text, "#log-lines", f"a line with {text!r}")


PATIENT_AND_TOOL = """() => {
  const c = document.getElementById("scene");
  const d = c.getContext("2d").getImageData(0, 0, c.width, c.height).data;
  let green = 0, cyan = 0;
  for (let i = 0; i < d.length; i += 4) {
    if (d[i] < 110 && d[i + 1] > 200 && d[i + 2] > 100 && d[i + 2] < 160) green++;
    if (d[i] < 60 && d[i + 1] > 190 && d[i + 2] > 220) cyan++;
  }
  return green > 20 && cyan > 20;
}"""


ORANGE_PIXELS = """() => {
  const c = document.getElementById("scene");
  const d = c.getContext("2d").getImageData(0, 0, c.width, c.height).data;
  let n = 0;
  for (let i = 0; i < d.length; i += 4) if (d[i] > 200 && d[i + 1] > 100 && d[i + 1] < 180 && d[i + 2] < 100) n++;
  return n > 200;
}"""


def test_the_operator_drives_the_procedure_from_the_browser(page, seeg_console):
    server, deployment = seeg_console
    page.goto(server.url)
    text_is(page, "link", "live")
    text_is(page, "operation", "wait")
    assert page.is_disabled("#release"), "nothing to release while waiting"
    page.wait_for_selector("#start:enabled", timeout=WAIT_MS)
    page.wait_for_selector("#chart-svg g.node.active", timeout=WAIT_MS)
    # a surgeon at the table appears in the 3D view (orange envelopes)
    RemoteComponent(deployment.hub, "people_world").call(
        "place", person=1, x=1.6, y=0.6, facing_deg=200.0
    )
    page.wait_for_function(ORANGE_PIXELS, timeout=WAIT_MS)
    page.wait_for_function(PATIENT_AND_TOOL, timeout=WAIT_MS)  # the reference, the TCP tool
    shot(page, "wait")
    # and leaves before the arm moves: this spec is the console's; a person beside the
    # moving arm is the scenarios' (collision, crowd, walk_in) and test_seeg_faults'. With
    # one beside it, the simulated OR needs all of 2 cores while moving (issue 43's
    # figures), and the browser's share starved the camera pipeline past its deadline
    # (a correct safety stop, not a console behaviour) in 3 of 4 runs here
    RemoteComponent(deployment.hub, "people_world").call("leave", person=1)

    # the target form: refused in the page, refused again by the server, then taken
    form = "#form-e_DEFINE_TARGET"
    page.wait_for_selector(f"{form} button:enabled", timeout=WAIT_MS)
    on_patient = {"x": 0.23, "y": 0.24, "z": 0.17, "roll": 180, "pitch": 0, "yaw": 163}
    red = "(el) => getComputedStyle(el).borderColor"
    untouched = page.eval_on_selector_all(f"{form} input", f"els => els.map({red})")
    assert len(set(untouched)) == 1, "empty fields are not errors before a Send"
    for name, value in on_patient.items():
        page.fill(f"{form} input[name={name}]", str(value))
    page.fill(f"{form} input[name=x]", "5")
    page.click(f"{form} button")
    text_is(page, "answer", "e_DEFINE_TARGET: refused: a value is missing or out of range")
    after = page.eval_on_selector_all(f"{form} input", f"els => els.map({red})")
    assert after[0] != untouched[0] and len(set(after[1:])) == 1, "after Send, x is shown wrong"
    page.evaluate("send('e_DEFINE_TARGET', {x: 5, y: 0, z: 0.1, roll: 0, pitch: 180, yaw: 0})")
    text_is(page, "answer", "e_DEFINE_TARGET: refused: e_DEFINE_TARGET.x must be at most 0.5 m")
    page.fill(f"{form} input[name=x]", "0.23")
    page.click(f"{form} button")
    text_is(page, "answer", "e_DEFINE_TARGET: accepted")
    supervisor = RemoteComponent(deployment.hub, "supervisor")
    navigator = RemoteComponent(deployment.hub, "navigator")
    assert wait_until(lambda: navigator.call("report")["revisions"]["target"] == 1)
    assert wait_until(lambda: supervisor.call("report")["target"] is not None)

    page.click("#start")
    text_is(page, "answer", "e_START: accepted")
    text_is(page, "operation", "approaching target")
    page.wait_for_selector("#chart-svg g.node.active", timeout=WAIT_MS)
    seen = page.evaluate(
        """() => {
          const pane = document.getElementById("chart").getBoundingClientRect();
          const svg = document.querySelector("#chart-svg svg");
          const shown = (g) => { const leaf = g.getBoundingClientRect();
            return leaf.left >= pane.left - 1 && leaf.right <= pane.right + 1
              && leaf.top >= pane.top - 1 && leaf.bottom <= pane.bottom + 1; };
          const inside = [...document.querySelectorAll("#chart-svg g.node.active")].some(shown);
          return {inside, natural: svg.getBoundingClientRect().width >= svg.width.baseVal.value - 1};
        }"""
    )
    assert seen == {"inside": True, "natural": True}, (
        "the chart at its size, its active state shown"
    )
    text_is(page, "tracker", "certus")
    moved = (
        "() => { const t = (lastState.trace && lastState.trace.data) || []; return t.length > 2 && Math.hypot("
        "t[t.length-1][1]-t[0][1], t[t.length-1][2]-t[0][2], t[t.length-1][3]-t[0][3]) > 0.005; }"
    )
    page.wait_for_function(moved, timeout=WAIT_MS)  # the TCP the page plots has moved 5 mm
    shot(page, "moving")

    certus = RemoteComponent(deployment.hub, "certus")
    certus.call("occlude", tool="cto")
    text_is(page, "tracker", "vicra")
    certus.call("occlude", tool="cto", hidden=False)
    assert wait_until(
        lambda: any(
            i["kind"] == "sensor swap" and i["ms"] > 0
            for i in (page.evaluate("lastState.latencies") or {}).get("data") or []
        ),
        timeout=20,
    ), "the swap's latency is measured live"

    text_is(page, "robot", "released")
    page.click("#stop")
    text_is(page, "operation", "stopped")
    # braked by the STOP; on a starved host by the robot side's own safety stop, or by
    # the Fault state's brake when the STOP's configuration failed (tests/topologies
    # prove those paths; here the console must show the brakes and let RELEASE through)
    text_matches(page, "robot", r"^(braked \((stop|fault)\)|SAFETY STOP: )")
    page.wait_for_selector("#release:enabled", timeout=WAIT_MS)
    shot(page, "stopped")
    page.click("#release")
    assert page.is_visible("#release-confirm") and page.is_hidden("#release")
    page.click("#release-confirm")
    text_is(page, "answer", "e_RELEASE: accepted")
    # the approach goes on; the STOP may have come close enough to the target that a
    # page served late by a busy host first shows it at the goal (CI: 1 s after RELEASE)
    text_matches(page, "operation", r"^(approaching|at the goal)")

    # a command the chart cannot take now is answered with the reason
    page.evaluate("send('e_START')")
    text_is(page, "answer", "e_START: refused: e_START is not taken in")
    page.wait_for_selector("#log-lines li.warning", timeout=WAIT_MS)


def test_a_lost_connection_is_shown_and_the_data_marked_stale(page, seeg_console):
    server, _ = seeg_console
    page.goto(server.url)
    text_is(page, "link", "live")
    server.stop()
    text_is(page, "link", "connection lost")
    assert "stale" in page.get_attribute("main", "class")


def test_a_second_console_sees_every_command_with_its_origin(page, seeg_console):
    server, _ = seeg_console
    other = page.context.browser.new_page()
    for p in (page, other):
        p.goto(server.url)
        text_is(p, "link", "live")
    page.wait_for_selector("#start:enabled", timeout=WAIT_MS)
    page.click("#start")
    text_is(page, "answer", "e_START: accepted")
    log_has(other, "command e_START from console@127.0.0.1")
    # approaching, or already at the goal when this page got its share of a busy host
    # late (CI: the approach's ~9 s went by unseen), unless a starved host tripped the
    # robot side (its job: the deadline monitor stops the arm when an input is late, the
    # KRC when its FRI answers stop); before START it was "wait"
    script = (
        "() => /^(approaching|at the goal)/.test(document.querySelector("
        "'[data-testid=operation]').textContent) || /SAFETY STOP: .*(no data for|the arm "
        "braked by itself)/.test(document.querySelector('[data-testid=robot]').textContent)"
    )
    wait_for(
        other,
        script,
        None,
        "[data-testid=operation]",
        "'approaching' or 'at the goal' (or a safety stop)",
    )


def test_a_failed_setup_opens_a_dialog_and_the_robot_never_moves(bus_config, tmp_path, page):
    # in the first setup step, before any device must answer in time
    topology = seeg(bus_config, tmp_path)
    topology.components["patient"].properties["procedure_file"] = str(tmp_path / "none.yaml")
    with served(topology, tmp_path / "logs") as (server, _):
        page.goto(server.url)
        page.wait_for_selector("#alert[open]", timeout=WAIT_MS)
        assert page.inner_text("#alert-title") == "Setup failed"
        assert "setup_components: state patient -> running" in page.inner_text("#alert-text")
        text_is(page, "operation", "stopped")
        assert page.is_disabled("#start")


def test_a_lost_process_shows_a_latched_safety_stop_and_what_keeps_release_refused(
    page, seeg_console
):
    """The cameras' process dies: the robot tile says SAFETY STOP with the reason, the
    log keeps the loss and the restart; once it is back, RELEASE is possible."""
    import os
    import signal

    server, deployment = seeg_console
    page.goto(server.url)
    text_is(page, "operation", "wait")
    cameras = next(p for p in deployment.processes if p.name == "cameras")
    os.kill(cameras.popen.pid, signal.SIGKILL)
    text_is(page, "robot", "SAFETY STOP: ")
    text_is(page, "operation", "stopped")
    log_has(page, "cameras: process lost: killed by signal 9")
    log_has(page, "cameras: process restarted")
    page.wait_for_function(
        "() => document.querySelector('[data-testid=robot]').textContent.endsWith('(RELEASE possible)')",
        timeout=60_000,
    )


EVIL_PAGE = """<!doctype html><title>evil</title><script>
const target = "%s";
async function attack() {
  const out = [];
  for (const [kind, body] of [["text/plain", '{"event": "e_SWAP"}'],
                              ["application/json", '{"event": "e_SWAP"}']]) {
    try {
      const r = await fetch(target + "api/command", {method: "POST", body,
        headers: {"Content-Type": kind}, credentials: "include"});
      out.push("command " + r.status);
    } catch (e) { out.push("command blocked"); }
  }
  try {
    const r = await fetch(target + "api/state", {credentials: "include"});
    out.push("read " + (await r.text()).slice(0, 20));
  } catch (e) { out.push("read blocked"); }
  document.title = out.join(" | ");
}
attack();
</script>"""


def test_a_page_of_another_origin_can_neither_command_nor_read_the_console(toy, tmp_path, page):
    """The operator is logged in; a page from another origin in the same browser tries
    to send a command (a "simple" text/plain post and a JSON one) and to read the
    state. Nothing reaches the chart and nothing is read."""
    import functools
    import http.server
    import threading

    from tests.framework.console.conftest import served

    with served(toy, tmp_path) as (server, deployment):
        page.goto(server.url)  # logs in: the cookie is set
        text_is(page, "link", "live")
        evil_dir = tmp_path / "evil"
        evil_dir.mkdir()
        (evil_dir / "index.html").write_text(EVIL_PAGE % server.base)
        handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(evil_dir))
        handler.log_message = lambda *a: None
        evil = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
        threading.Thread(target=evil.serve_forever, daemon=True).start()
        try:
            page.goto(f"http://127.0.0.1:{evil.server_address[1]}/index.html")
            page.wait_for_function("() => document.title.includes('read')", timeout=WAIT_MS)
            outcome = page.title()
        finally:
            evil.shutdown()
        assert "command 200" not in outcome and "read {" not in outcome, outcome
        assert deployment.coordinator.active()["active"] == ["Use_T1"], outcome


def test_a_topology_of_its_own_gets_its_tiles_plots_and_buttons(bus_config, tmp_path, page):
    """Not SEEG: the toy topology with a `console:` section. Its tiles fill in, its plot
    is drawn, its confirmed button swaps the trackers, and no SEEG part is on the page."""
    from tests.framework.console.test_generic import CONSOLE, toy_with

    topology = private_topology(toy_with(tmp_path, CONSOLE), bus_config)
    with served(topology, tmp_path / "logs") as (server, deployment):
        page.goto(server.url)
        text_is(page, "link", "live")
        text_matches(page, "count", r"^-?\d+\.\d$")
        text_matches(page, "samples-read", r"^[1-9]\d*$")
        page.wait_for_selector("#plot-tracker-1", timeout=WAIT_MS)
        assert not page.query_selector("#scene") and not page.query_selector(
            "[data-testid=tracker]"
        )
        page.wait_for_selector("#swap-trackers:enabled", timeout=WAIT_MS)
        page.click("#swap-trackers")
        assert page.is_visible("#swap-trackers-confirm") and page.is_hidden("#swap-trackers")
        page.click("#swap-trackers-confirm")
        text_is(page, "answer", "e_SWAP: accepted")
        assert wait_until(lambda: deployment.coordinator.active()["active"] == ["Use_T2"])


def test_a_snapshot_of_the_page_finishes_loading_for_a_screenshot(page, seeg_console):
    """`?snapshot`: the state once, no stream: the page reaches network idle (a headless
    browser's --screenshot returns) and shows the deployment as it was."""
    server, _ = seeg_console
    page.goto(f"{server.url}&snapshot", wait_until="networkidle")
    page.wait_for_selector("body[data-snapshot=ready]", timeout=WAIT_MS)
    assert page.text_content("[data-testid=link]").startswith("snapshot of ")
    assert page.text_content("[data-testid=operation]") in ("setting up", "wait")
    assert page.query_selector("#chart-svg g.node.active") is not None
    shot(page, "snapshot")
