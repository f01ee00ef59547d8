"""Spec: fw works installed from its wheel, not only from a checkout. The wheel carries
the schemas, the console's page and the SEEG panel's script, and neither the specs'
scaffolding nor the experiment harness; `fw bench` comes from fw-bench's own wheel,
finds the SEEG deployment it measures through FW_HOME (or the current folder) and says
so clearly when there is none. Built offline from a copy of the sources (nothing
downloaded)."""

import json
import os
import shutil
import subprocess
import sys
import venv
from pathlib import Path

import pytest

from tests.conftest import REPO


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """A virtual environment with fw installed from a wheel of this tree; its
    dependencies are those of the environment running the suite (its site-packages
    on the path, but not its editable install of fw, whose hook a plain path entry
    does not run), whether that is the system's Python or a virtual environment."""
    root = tmp_path_factory.mktemp("installed")
    source = root / "src"
    source.mkdir()
    for name in ("framework", "components"):
        shutil.copytree(REPO / name, source / name, ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(REPO / name, source / name)
    shutil.copytree(
        REPO / "tools" / "bench",
        root / "bench",
        ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"),
    )
    wheels = root / "wheels"
    for tree in (source, root / "bench"):
        subprocess.run(
            [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
             str(tree), "-w", str(wheels)],
            check=True, capture_output=True, cwd=root,
        )  # fmt: skip
    env_dir = root / "venv"
    venv.EnvBuilder(system_site_packages=True, with_pip=False).create(env_dir)
    python = env_dir / "bin" / "python"
    own = subprocess.run(
        [str(python), "-c", "import site; print(site.getsitepackages()[0])"],
        check=True, capture_output=True, text=True,
    ).stdout.strip()  # fmt: skip
    # every folder the running interpreter imports from beyond its standard library
    # (a .pth file's own additions, such as Pinocchio's cmeel prefix, included), but
    # neither the checkout nor an editable install's import hook
    folders = [p for p in sys.path if "site-packages" in p and Path(p).is_dir()]
    Path(own, "fw_test_dependencies.pth").write_text("\n".join(folders) + "\n")
    # --ignore-installed: the suite's own environment may hold fw (editable), which this
    # one sees through its system site-packages; pip would then skip the wheel
    subprocess.run(
        [sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps",
         "--ignore-installed",
         "--no-index", "-q", *map(str, sorted(wheels.glob("*.whl")))],
        check=True, capture_output=True,
    )  # fmt: skip
    return env_dir


def run(env_dir, *args, cwd, extra_env=None):
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "FW_HOME")}
    env.update(extra_env or {})
    return subprocess.run(
        [str(env_dir / "bin" / args[0]), *args[1:]],
        capture_output=True, text=True, cwd=cwd, env=env, timeout=600,
    )  # fmt: skip


def test_the_wheel_is_what_runs_and_carries_its_files(installed, tmp_path):
    probe = (
        "import framework, components.supervisor.panel as p;"
        "from framework.console.panels import load_panels;"
        "from framework.console.server import STATIC;"
        "panel = load_panels(['seeg'])[0];"
        "print(framework.__file__);"
        "print((panel.static / 'seeg.js').is_file(), (STATIC / 'console.js').is_file())"
    )
    out = run(installed, "python", "-c", probe, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    where, files = out.stdout.split("\n")[:2]
    assert where.startswith(str(installed)), where
    assert files == "True True"
    checked = run(installed, "fw", "validate", "topologies/pick_place.yaml", cwd=REPO)
    assert checked.returncode == 0, checked.stdout + checked.stderr


def test_fws_wheel_holds_only_fw(installed):
    """The specs' scaffolding and the experiment harness stay out of fw's wheel."""
    import zipfile

    wheel = next((installed.parent / "wheels").glob("fw-0*.whl"))
    tops = {name.split("/")[0] for name in zipfile.ZipFile(wheel).namelist()}
    assert {t for t in tops if not t.endswith(".dist-info")} == {"framework", "components"}


def test_fw_bench_needs_a_seeg_home_and_says_where_it_looked(installed, tmp_path):
    lost = run(installed, "fw", "bench", "braking", "--quick", "--out", "o", cwd=tmp_path)
    assert lost.returncode == 1, lost.stdout + lost.stderr
    assert "no topologies/seeg.yaml was found" in lost.stderr
    assert "set FW_HOME" in lost.stderr and "Traceback" not in lost.stderr
    found = run(
        installed,
        "fw", "bench", "braking", "--quick", "--out", str(tmp_path / "out"),
        cwd=tmp_path, extra_env={"FW_HOME": str(REPO)},
    )  # fmt: skip
    assert found.returncode == 0, found.stdout + found.stderr
    assert (tmp_path / "out" / "report.md").is_file()
    rows = json.loads((tmp_path / "out" / "summary.json").read_text())["rows"]
    measured = {r["experiment"] for r in rows}
    # an offline experiment carries the host's speed, not Zenoh hops it is never read against
    assert "host" in measured and "braking" in measured and "zenoh" not in measured


def test_the_constraints_file_pins_every_dependency_fw_names():
    """tools/constraints.txt (`tools/install.sh --pinned`) holds a version for every
    package pyproject.toml asks for, extras included: a reproducible install."""
    import re
    import tomllib

    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    wanted = list(project["dependencies"])
    for extra in project["optional-dependencies"].values():
        wanted += extra
    names = {re.split(r"[<>=!~\[; ]", w, maxsplit=1)[0].lower().replace("_", "-") for w in wanted}
    pinned = {
        line.split("==")[0].lower().replace("_", "-")
        for line in (REPO / "tools" / "constraints.txt").read_text().splitlines()
        if "==" in line and not line.startswith("#")
    }
    assert names - pinned == set()


def test_what_the_tutorial_runs_is_installed_by_the_readmes_first_command(tmp_path):
    """The README's first command installs fw's runtime dependencies only: every
    command of docs/tutorial.md and every import of what `fw new procedure` writes must
    come from them (a new user met 'No module named pytest' in step 2)."""
    import ast
    import re
    import tomllib

    from framework.scaffold import new_procedure

    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    runtime = {re.split(r"[<>=!~\[; ]", d, maxsplit=1)[0].lower() for d in project["dependencies"]}
    tutorial = (REPO / "docs" / "tutorial.md").read_text()
    for module in re.findall(r"^\$ python -m (\w+)", tutorial, re.M):
        assert module in runtime, f"the tutorial runs `python -m {module}`"
    imported = set()
    for path in new_procedure("hello", tmp_path, 7447):
        if path.suffix == ".py":
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.Import):
                    imported |= {alias.name.split(".")[0] for alias in node.names}
                elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
                    imported.add(node.module.split(".")[0])
    standard = set(sys.stdlib_module_names) | {"framework", "components"}
    assert imported - standard <= runtime, imported - standard - runtime
