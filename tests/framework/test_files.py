"""Spec: every file fw reads for a user is a regular file, read to a bound. A named
pipe, a folder, a device, a socket, a link to itself or a file too large is refused
at once with what it is, and where the path was written when a file names it."""

import os
import socket
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from framework.files import UnreadableFile, read_file
from tests.conftest import REPO


def refused_at_once(path, max_bytes=1024) -> UnreadableFile:
    """read_file on `path`, in a thread: it must end (not block) and refuse."""
    outcome: list[BaseException | bytes] = []

    def read():
        try:
            outcome.append(read_file(path, max_bytes))
        except BaseException as exc:
            outcome.append(exc)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    reader.join(60)  # generous: a blocking open would never end
    assert outcome, f"reading {path} blocked"
    assert isinstance(outcome[0], UnreadableFile), outcome[0]
    return outcome[0]


@pytest.fixture
def odd(tmp_path):
    """Paths that are not regular files."""
    os.mkfifo(tmp_path / "fifo")
    (tmp_path / "folder").mkdir()
    server = socket.socket(socket.AF_UNIX)
    server.bind(str(tmp_path / "socket"))
    (tmp_path / "loop").symlink_to(tmp_path / "loop")
    with (tmp_path / "huge").open("wb") as handle:
        handle.truncate(5 * 1024**3)  # sparse: nothing is written
    yield tmp_path
    server.close()


@pytest.mark.parametrize(
    ("name", "says"),
    [
        ("fifo", "a named pipe (FIFO), not a regular file"),
        ("folder", "a folder, not a regular file"),
        ("socket", "a socket"),
        ("loop", "symbolic links"),
        ("huge", "5,368,709,120 bytes, larger than 1,024 bytes"),
        ("missing", "file not found"),
    ],
)
def test_what_is_not_a_regular_file_is_refused_without_reading_it(odd, name, says):
    error = refused_at_once(odd / name)
    assert says in error.reason
    assert error.missing == (name == "missing")


def test_a_device_of_endless_bytes_is_never_read():
    assert "a character device" in refused_at_once("/dev/zero").reason


def test_a_regular_file_is_read_whole_up_to_its_bound(tmp_path):
    (tmp_path / "ok").write_bytes(b"x" * 1024)
    assert read_file(tmp_path / "ok", 1024) == b"x" * 1024
    with pytest.raises(UnreadableFile, match="larger than 1,023 bytes"):
        read_file(tmp_path / "ok", 1023)


def validate(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "framework.cli", "validate", *args],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=REPO,
    )


@pytest.fixture
def topology_file(tmp_path):
    """topologies/seeg.yaml with one text replaced, in a copy of the repository's
    layout (its folders linked), so its relative paths still hold."""
    home = tmp_path / "home"
    (home / "topologies").mkdir(parents=True)
    for folder in ("statecharts", "procedures"):
        (home / folder).symlink_to(REPO / folder)
    made = []

    def make(old, new):
        text = (REPO / "topologies" / "seeg.yaml").read_text()
        assert old in text
        made.append(home / "topologies" / f"seeg{len(made)}.yaml")
        made[-1].write_text(text.replace(old, new))
        return str(made[-1])

    return make


def line_of(path: str, text: str) -> int:
    lines = Path(path).read_text().splitlines()
    return next(i for i, line in enumerate(lines, 1) if text in line)


def test_a_fifo_or_folder_named_by_a_topology_is_an_error_where_it_is_named(odd, topology_file):
    chart = topology_file("statechart: ../statecharts/seeg.yaml", "statechart: ../statecharts")
    done = validate(chart)
    assert done.returncode == 1
    where = line_of(chart, "statechart: ../statecharts")
    assert f"{chart}:{where}:" in done.stdout and "a folder, not a regular file" in done.stdout
    tools = topology_file("tools_file: procedures/seeg/tools.yaml", f"tools_file: {odd}/fifo")
    done = validate(tools)
    assert done.returncode == 1, "a FIFO named as the tools file never blocks fw validate"
    where = line_of(tools, "tools_file:")
    assert f"{tools}:{where}:" in done.stdout
    assert "vicra.tools_file: cannot read file: a named pipe (FIFO)" in done.stdout


def test_the_files_a_topology_names_are_checked_with_it(tmp_path, topology_file):
    """A procedure file, a tools file with a tool definition that is a FIFO: wrong
    files a component would only refuse when deployed are reported by fw validate of
    the topology, at their own line."""
    procedure = tmp_path / "procedure.yaml"
    text = (REPO / "procedures" / "seeg.yaml").read_text()
    procedure.write_text(text.replace("critical_radius:", "critical_radius: -1 #", 1))
    path = topology_file(
        "properties: {procedure_file: procedures/seeg.yaml}  # referees",
        f"properties: {{procedure_file: {procedure}}}  # referees",
    )
    done = validate(path)
    assert done.returncode == 1
    assert f"{procedure}:" in done.stdout, done.stdout
    os.mkfifo(tmp_path / "pipe.rom")
    tools = tmp_path / "tools.yaml"
    tools.write_text("tools:\n  cto:\n    rom: pipe.rom\n")
    path = topology_file("tools_file: procedures/seeg/tools.yaml", f"tools_file: {tools}")
    done = validate(path)
    assert done.returncode == 1
    assert f"{tools}:3:" in done.stdout and "a named pipe (FIFO)" in done.stdout


def test_control_characters_of_a_file_never_reach_the_terminal_raw(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text('topology: t\ncomponents:\n  "a\\e[2Jb\\u202e": {class: x}\n')
    done = validate(str(bad))
    assert done.returncode == 1
    assert "\x1b" not in done.stdout + done.stderr and "\u202e" not in done.stdout
    assert "\\x1b[2J" in done.stdout or "\\x1b[2J" in done.stderr
