"""Feed fw seeded mutants of every shipped YAML file kind; every one must end in a
clean located error or a valid load.

Each mutant is one random change to a shipped file: a text edit (a line deleted,
duplicated or re-indented, random or invalid UTF-8 bytes, NUL, a truncation, a
hostile token: a 5,000-digit integer, an alias bomb, a recursive alias, a list
nested 50,000 deep, a custom tag, a second document) or a change to its data (a
key dropped or misspelt, a value replaced by one of another type, NaN, a huge or
negative number, an empty list) written back as YAML. It is checked exactly as
`fw validate` checks it, in worker processes, so a segmentation fault, a hang or
a memory blow-up is seen and charged to its mutant instead of ending the run.

An outcome is `valid` (no finding), `clean` (every error has file:line:column),
or a failure: `traceback` (an exception that is not an fw error), `unlocated`
(an error without a line), `crash` (the worker died), `hang` (no answer within
--hang-after s), `memory` (the worker grew by more than --max-mb), `slow` (over
--slow s). Failing mutants are written to --out so `fw validate FILE` replays them.

examples:
  python tools/fuzz_files.py --n 20000 --jobs 2      the long run (target: 100% clean)
  python tools/fuzz_files.py --n 1000 --seed 7       what the test suite runs
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import os
import random
import re
import resource
import selectors
import shutil
import subprocess
import sys
import tempfile
import time
import traceback
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
# the benchmarks' report writer, importable from the checkout without fw-bench installed
sys.path.insert(0, str(REPO / "tools" / "bench"))
FOLDERS = ("topologies", "statecharts", "procedures")
FAILURES = ("traceback", "unlocated", "unescaped", "crash", "hang", "memory", "slow")


# -- the shipped files --------------------------------------------------------------


def shipped(root: Path = REPO) -> dict[str, list[str]]:
    """Every shipped YAML file by kind, as paths relative to `root` (sorted)."""
    from framework.filekinds import detect

    out: dict[str, list[str]] = {}
    for folder in FOLDERS:
        for path in sorted((root / folder).rglob("*.yaml")):
            kind = detect(path)
            if kind is not None:
                out.setdefault(kind.name, []).append(str(path.relative_to(root)))
    return dict(sorted(out.items()))


# -- mutations ----------------------------------------------------------------------

HOSTILE_TOKENS = [
    "9" * 5000,
    "-" + "9" * 80,
    "0x" + "f" * 300,
    "1e99999",
    ".nan",
    "-.inf",
    "~",
    "''",
    "[]",
    "{}",
    "-1",
    "0",
    "1e-320",
    "x" * 70_000,
    "*nowhere",
    "&a [*a]",
    "!!python/object/apply:os.system ['true']",
    "!custom x",
    "!!binary aGVsbG8=",
    "2026-11-23",
    "{a: 1, a: 2}",
    "[" * 50_000 + "]" * 50_000,
    "{a: " * 3000 + "1" + "}" * 3000,
    "|\n  block\n  text",
    "'unterminated",
    '"\\x00 escaped NUL"',
    "? [a, b]",
    "<<: *nowhere",
    "yes",
    "on",
]
BOMB = "a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
    f"{n}: &{n} [{', '.join(['*' + p] * 9)}]\n"
    for p, n in zip("abcdefghi", "bcdefghij", strict=True)
)
HOSTILE_VALUES: list[Any] = [
    None,
    "",
    "x",
    0,
    -1,
    1,
    "__HUGE_INT__",  # written as 4,400 digits (Python will not print an int that long)
    -1e308,
    1e-320,
    math.nan,
    math.inf,
    True,
    [],
    {},
    [1, 2],
    [[1, 2, 3]] * 2,
    {"a": 1},
    "x" * 70_000,
    "../../../../etc/passwd",
    "not/a.module",
    "e_START",
    [None] * 5,
]


def _lines(text: str) -> list[str]:
    return text.splitlines(keepends=True) or [""]


def _text_mutation(rng: random.Random, text: str) -> bytes:
    lines = _lines(text)
    i = rng.randrange(len(lines))
    op = rng.randrange(16)
    if op == 0:
        del lines[i]
    elif op == 1:
        lines.insert(i, lines[i])
    elif op == 2:
        j = rng.randrange(len(lines))
        lines[i], lines[j] = lines[j], lines[i]
    elif op == 3:
        lines[i] = " " * rng.choice((1, 2, 4)) + lines[i]
    elif op == 4:
        lines[i] = lines[i].lstrip(" ")
    elif op == 5:
        cut = rng.randrange(len(text) + 1)
        return text[:cut].encode()
    elif op == 6:
        raw = bytearray(text.encode())
        at = rng.randrange(len(raw) + 1)
        raw[at:at] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 8)))
        return bytes(raw)
    elif op == 7:
        raw = bytearray(text.encode())
        if raw:
            raw[rng.randrange(len(raw))] = rng.choice((0, 0x07, 0x1B, 0x80, 0xC3, 0xFF))
        return bytes(raw)
    elif op in (8, 9, 10):
        line = lines[i]
        colon = line.find(": ")
        token = rng.choice(HOSTILE_TOKENS)
        if colon >= 0:
            lines[i] = line[: colon + 2] + token + "\n"
        else:
            lines[i] = line.rstrip("\n") + " " + token + "\n"
    elif op == 11:
        lines.insert(0, BOMB)
        lines.append("boom: *j\n")
    elif op == 12:
        lines.insert(i, "---\n")
    elif op == 13:
        lines[i] = lines[i].replace(" ", "\t", 1)
    elif op == 14:
        a = rng.randrange(len(text) + 1)
        b = min(len(text), a + rng.randint(1, 40))
        return (text[:a] + text[b:]).encode()
    else:
        chars = list(lines[i])
        if chars:
            chars[rng.randrange(len(chars))] = rng.choice("[]{}:-,&*!|>'\"#%@`?")
        lines[i] = "".join(chars)
    return "".join(lines).encode()


def _paths(data: Any, path: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    out = [path]
    if isinstance(data, dict):
        for key, value in data.items():
            out.extend(_paths(value, (*path, key)))
    elif isinstance(data, list):
        for i, value in enumerate(data):
            out.extend(_paths(value, (*path, i)))
    return out


def _data_mutation(rng: random.Random, text: str) -> bytes:
    import yaml

    from framework.yamlio import load_yaml_text

    data = load_yaml_text(text).data
    paths = _paths(data)[1:]
    if not paths:
        return _text_mutation(rng, text)
    path = rng.choice(paths)
    parent = data
    for part in path[:-1]:
        parent = parent[part]
    last = path[-1]
    op = rng.randrange(7)
    if op == 0:  # drop it
        del parent[last]
    elif op == 6 and isinstance(parent, dict):  # a key with control characters
        parent[rng.choice(CONTROL_KEYS)] = parent.pop(last)
    elif op == 1 and isinstance(parent, dict):  # misspell the key
        value = parent.pop(last)
        parent[last[:-1] + rng.choice("xsz_") if last else "x"] = value
    elif op == 2 and isinstance(parent[last], int | float) and not isinstance(parent[last], bool):
        parent[last] = parent[last] * rng.choice((-1, 0, 1e6, 1e-9, math.nan, math.inf))
    elif op == 3 and isinstance(parent[last], list):
        parent[last] = rng.choice(([], parent[last] * 3, parent[last][:1]))
    elif op == 4 and isinstance(parent, list):
        parent.insert(last, copy.deepcopy(parent[last]))
    else:
        parent[last] = copy.deepcopy(rng.choice(HOSTILE_VALUES))
    text = yaml.safe_dump(data, sort_keys=False, allow_unicode=True, width=120)
    return text.replace("__HUGE_INT__", "9" * 4400).encode()


SPECIAL = Path(tempfile.gettempdir()) / f"fw-fuzz-paths-{os.getuid()}"
"""Where the worker makes the paths that are not regular files (a fixed place, so a
saved mutant that names one replays)."""
SPECIAL_PATHS = [
    str(SPECIAL / "fifo"),  # a named pipe: a blocking open waits for a writer forever
    str(SPECIAL / "folder"),
    str(SPECIAL / "socket"),
    str(SPECIAL / "huge.yaml"),  # 5 GB, sparse
    str(SPECIAL / "loop.yaml"),  # a symbolic link to itself
    str(SPECIAL / "missing.yaml"),
    "/dev/zero",  # endless bytes
    "/dev/null",
    "/",
]
FILE_KEYS = {
    "include",
    "statechart",
    "procedure",
    "property_file",
    "rom",
    "tools_file",
    "procedure_file",
    "sensors_file",
    "cameras_file",
}
"""Keys whose value names another file (any value ending in .yaml or .rom does too)."""
CONTROL_KEYS = ["a\x1b[2J\x1b[31mred", "tab\there", "rtl\u202egnp.exe", "bell\x07", "cr\rx"]
"""Keys a hostile file may hold through YAML's escapes: a message quoting one raw would
clear or recolour the operator's terminal, or show its text reversed."""


def make_special_paths() -> None:
    """Make `SPECIAL_PATHS` that live in `SPECIAL` (idempotent)."""
    import socket

    SPECIAL.mkdir(parents=True, exist_ok=True)
    (SPECIAL / "folder").mkdir(exist_ok=True)
    if not (SPECIAL / "fifo").exists():
        os.mkfifo(SPECIAL / "fifo")
    if not (SPECIAL / "socket").exists():
        sock = socket.socket(socket.AF_UNIX)
        sock.bind(str(SPECIAL / "socket"))
        sock.close()  # the socket file stays
    huge = SPECIAL / "huge.yaml"
    if not huge.exists():
        with huge.open("wb") as handle:
            handle.truncate(5 * 1024**3)
    if not (SPECIAL / "loop.yaml").is_symlink():
        (SPECIAL / "loop.yaml").symlink_to(SPECIAL / "loop.yaml")


def _path_mutation(rng: random.Random, text: str) -> bytes:
    """A value that names a file now names what is not one (a FIFO, a folder, a
    device, a socket, a 5 GB file, a link to itself) or nothing."""
    import yaml

    from framework.yamlio import load_yaml_text

    data = load_yaml_text(text).data
    named = []
    for path in _paths(data)[1:]:
        value = data
        for part in path:
            value = value[part]
        if isinstance(value, str) and (path[-1] in FILE_KEYS or value.endswith((".yaml", ".rom"))):
            named.append(path)
    if not named:
        return _data_mutation(rng, text)
    path = rng.choice(named)
    parent = data
    for part in path[:-1]:
        parent = parent[part]
    parent[path[-1]] = rng.choice(SPECIAL_PATHS)
    return yaml.safe_dump(data, sort_keys=False, allow_unicode=True, width=120).encode()


def mutant(
    seed: int, index: int, files: dict[str, list[str]], root: Path
) -> tuple[str, str, bytes]:
    """Mutant `index` of run `seed`: (kind, relative path, bytes); the same every time.
    Half change the text, a third the data, the rest the paths it names."""
    rng = random.Random(f"fw-fuzz:{seed}:{index}")
    kind = sorted(files)[index % len(files)]  # every kind gets its share
    rel = rng.choice(files[kind])
    text = (root / rel).read_text(encoding="utf-8")
    level = rng.random()
    if level < 0.5:
        return kind, rel, _text_mutation(rng, text)
    if level < 0.85:
        return kind, rel, _data_mutation(rng, text)
    return kind, rel, _path_mutation(rng, text)


# -- the worker: checks mutants as `fw validate` does ----------------------------------


def _check(kind: str, path: str) -> list[Any]:
    from framework.filekinds import kinds
    from framework.statechart.files import validate_file

    if kind == "statechart":
        return validate_file(path)
    return kinds()[kind].check(path)


UNPRINTABLE = re.compile("[\x00-\x1f\x7f-\x9f\u202a-\u202e\u2066-\u2069]")
"""What a message must never print raw (framework.errors.printable escapes it)."""
_HELD: list[bytes] = []


def _raise_raw() -> None:
    from framework.errors import FwError

    raise FwError("a message that clears the screen \x1b[2J")


CANARIES: dict[str, Callable[[], object]] = {
    "traceback": lambda: [][1],
    "crash": lambda: os.kill(os.getpid(), 11),
    "hang": lambda: time.sleep(3600),
    "unlocated": lambda: None,
    "unescaped": lambda: _raise_raw(),
    "memory": lambda: _HELD.append(b"x" * 300_000_000),
    "slow": lambda: time.sleep(2.5),
}


def canary_for(index: int, every: int) -> str:
    """The failure mutant `index` fakes on purpose ('' for a real check)."""
    if not every or index % every != every - 1:
        return ""
    return list(CANARIES)[(index // every) % len(CANARIES)]


def _outcome(kind: str, path: str, canary: str) -> tuple[str, str]:
    from framework.errors import FwError, LocatedError

    try:
        if canary:
            CANARIES[canary]()
            if canary == "unlocated":
                from framework.errors import Finding, Location

                findings = [Finding("error", "canary", "no line", Location(path))]
            else:  # pragma: no cover - the canary ended the check
                findings = []
        else:
            findings = _check(kind, path)
    except MemoryError:
        return "memory", "MemoryError"
    except FwError as exc:  # a check should return findings, but a located raise is clean
        if UNPRINTABLE.search(str(exc)):
            return "unescaped", ascii(str(exc))[:300]
        if isinstance(exc, LocatedError) and exc.location.line > 0:
            return "clean", str(exc)
        return "unlocated", str(exc)
    except BaseException as exc:
        frames = [
            f
            for f in traceback.extract_tb(exc.__traceback__)
            if "/site-packages/" not in f.filename
        ]
        where = f" at {Path(frames[-1].filename).name}:{frames[-1].lineno}" if frames else ""
        return "traceback", f"{type(exc).__name__}: {str(exc)[:200]}{where}"
    for finding in findings:
        if UNPRINTABLE.search(finding.one_line()):
            return "unescaped", ascii(finding.one_line())[:300]
    errors = [f for f in findings if f.severity == "error"]
    if not errors:
        return "valid", ""
    for finding in errors:
        if finding.location.line < 1:
            return "unlocated", finding.one_line()[:300]
    return "clean", errors[0].one_line()[:300]


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def worker(seed: int, indexes: list[int], canary_every: int) -> None:
    """Check the mutants `indexes` one by one in a mirror of the repository's files,
    printing a JSON line before (`begin`) and after each."""
    root = Path(tempfile.mkdtemp(prefix="fw-fuzz-"))
    make_special_paths()
    try:
        for folder in FOLDERS:
            shutil.copytree(REPO / folder, root / folder)
        files = shipped(root)
        for kind, rels in files.items():  # warm up: imports and caches are not a mutant's cost
            for rel in rels:
                _outcome(kind, str(root / rel), "")
        baseline = _rss_mb()
        for index in indexes:
            kind, rel, raw = mutant(seed, index, files, root)
            target = root / rel
            original = target.read_bytes()
            canary = canary_for(index, canary_every)
            print(json.dumps({"begin": index}), flush=True)
            target.write_bytes(raw)
            start = time.perf_counter()
            outcome, detail = _outcome(kind, str(target), canary)
            seconds = time.perf_counter() - start
            target.write_bytes(original)
            grown = _rss_mb() - baseline
            print(
                json.dumps(
                    {
                        "index": index,
                        "kind": kind,
                        "file": rel,
                        "outcome": outcome,
                        "detail": detail,
                        "seconds": seconds,
                        "grown_mb": grown,
                        "canary": canary,
                    }
                ),
                flush=True,
            )
    finally:
        shutil.rmtree(root, ignore_errors=True)


# -- the parent: runs workers, charges crashes and hangs to their mutant ---------------


class _Worker:
    def __init__(self, args: argparse.Namespace, indexes: list[int]):
        self.todo = list(indexes)
        self.current: int | None = None
        self.deadline = math.inf
        self.buffer = b""
        self.proc: subprocess.Popen[bytes] | None = None
        self.args = args

    def start(self) -> None:
        command = [
            sys.executable,
            __file__,
            "--worker",
            "--seed",
            str(self.args.seed),
            "--indexes",
            ",".join(map(str, self.todo)),
            "--canary-every",
            str(self.args.canary_every),
        ]
        self.proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
        os.set_blocking(self.proc.stdout.fileno(), False)  # type: ignore[union-attr]
        self.current, self.buffer = None, b""
        self.deadline = time.monotonic() + 120  # imports and the warm-up


def run(args: argparse.Namespace) -> list[dict[str, Any]]:
    """Every mutant's result, in index order."""
    indexes = list(range(args.n))
    workers = [_Worker(args, indexes[j :: args.jobs]) for j in range(args.jobs)]
    results: dict[int, dict[str, Any]] = {}
    selector = selectors.DefaultSelector()
    for w in workers:
        if w.todo:
            w.start()
            selector.register(w.proc.stdout, selectors.EVENT_READ, w)  # type: ignore[union-attr]
    last_progress = time.monotonic()

    def restart(w: _Worker) -> None:
        """Stop the worker; start a fresh one on what it has left."""
        selector.unregister(w.proc.stdout)  # type: ignore[union-attr]
        w.proc.kill()  # type: ignore[union-attr]
        w.proc.wait()  # type: ignore[union-attr]
        if w.todo:
            w.start()
            selector.register(w.proc.stdout, selectors.EVENT_READ, w)  # type: ignore[union-attr]

    def charge(w: _Worker, outcome: str, detail: str) -> None:
        """Charge a crash or hang to the mutant being checked, then go on without it."""
        index = w.current if w.current is not None else w.todo[0]
        results[index] = {
            "index": index,
            "outcome": outcome,
            "detail": detail,
            "seconds": math.nan,
            "grown_mb": math.nan,
            "canary": canary_for(index, args.canary_every),
        }
        w.todo = [i for i in w.todo if i > index]
        restart(w)

    while any(w.todo for w in workers):
        for key, _ in selector.select(timeout=0.5):
            w = key.data
            chunk = w.proc.stdout.read()
            if not chunk:  # the worker ended: done, or died
                code = w.proc.wait()
                if not w.todo:
                    selector.unregister(w.proc.stdout)
                    continue
                signal = f" (signal {-code})" if code < 0 else ""
                charge(w, "crash", f"worker exited with {code}{signal}")
                continue
            w.buffer += chunk
            *lines, w.buffer = w.buffer.split(b"\n")
            for line in lines:
                message = json.loads(line)
                if "begin" in message:
                    w.current = message["begin"]
                    w.deadline = time.monotonic() + args.hang_after
                    continue
                if message["outcome"] in ("valid", "clean") and message["seconds"] > args.slow:
                    message["outcome"], message["detail"] = "slow", f"{message['seconds']:.2f} s"
                if message["grown_mb"] > args.max_mb:
                    message["outcome"] = "memory"
                    message["detail"] = f"the worker grew by {message['grown_mb']:.0f} MB"
                results[message["index"]] = message
                w.todo.remove(message["index"])
                w.current, w.deadline = None, math.inf
                if message["outcome"] == "memory":  # go on in a small process
                    restart(w)
                    break
        now = time.monotonic()
        for w in workers:
            if w.todo and now > w.deadline:
                charge(w, "hang", f"no answer within {args.hang_after:g} s")
        if not args.json and now - last_progress > 5:
            last_progress = now
            print(f"  {len(results)}/{args.n} mutants", file=sys.stderr, flush=True)
    for w in workers:
        if w.proc is not None:
            w.proc.wait()
    return [results[i] for i in sorted(results)]


def report(args: argparse.Namespace, results: list[dict[str, Any]]) -> dict[str, Any]:
    """Counts per kind and outcome; failing mutants saved under --out for replay."""
    from fw_bench.micro.lib import percentiles, write_report

    files = shipped()
    out = Path(args.out)
    by_kind: dict[str, Counter[str]] = {}
    failures = []
    for r in results:
        kind, rel, raw = mutant(args.seed, r["index"], files, REPO)
        r.setdefault("kind", kind)
        r.setdefault("file", rel)
        by_kind.setdefault(kind, Counter())[r["outcome"]] += 1
        if r["outcome"] in FAILURES and not r.get("canary"):
            saved = out / "fuzz_failures" / f"{r['index']:06d}-{Path(rel).name}"
            saved.parent.mkdir(parents=True, exist_ok=True)
            saved.write_bytes(raw)
            failures.append({**r, "saved": str(saved)})
    timing = percentiles([r["seconds"] for r in results if not math.isnan(r["seconds"])])
    grown = max((r["grown_mb"] for r in results if not math.isnan(r["grown_mb"])), default=0.0)
    real = [r for r in results if not r.get("canary")]
    ok = sum(r["outcome"] in ("valid", "clean") for r in real)
    lines = [
        f"# Hostile files: {len(real)} seeded mutants (seed {args.seed})",
        "",
        "| kind | mutants | valid | clean error | " + " | ".join(FAILURES) + " |",
        "|---|---|---|---|" + "---|" * len(FAILURES),
    ]
    for kind, counts in sorted(by_kind.items()):
        total = sum(counts.values())
        lines.append(
            f"| {kind} | {total} | {counts['valid']} | {counts['clean']} | "
            + " | ".join(str(counts[f]) for f in FAILURES)
            + " |"
        )
    lines += [
        "",
        f"Clean: {ok}/{len(real)} ({100 * ok / max(1, len(real)):.2f}%). Per mutant: "
        f"median {timing['p50_us'] / 1000:.1f} ms, p99 {timing['p99_us'] / 1000:.1f} ms, "
        f"max {max((r['seconds'] for r in real if not math.isnan(r['seconds'])), default=0):.2f} s; "
        f"largest worker growth {grown:.0f} MB.",
    ]
    for f in failures[:30]:
        lines.append(f"- {f['outcome']}: {f['saved']} ({f['kind']}): {f['detail']}")
    summary = {
        "seed": args.seed,
        "mutants": len(real),
        "clean": ok,
        "by_kind": {k: dict(v) for k, v in by_kind.items()},
        "failures": failures,
        "canaries": [r for r in results if r.get("canary")],
        "timing": timing,
        "max_grown_mb": grown,
    }
    if args.json:
        print(json.dumps(summary, default=float))
        return summary
    write_report(args.out, "fuzz_files", lines, {"100% clean": ok == len(real)}, summary)
    return summary


def main() -> int:
    from fw_bench.micro.lib import bench_parser

    parser = bench_parser(__doc__, quick=None)
    parser.add_argument("--n", type=int, default=1000, help="mutants to try (default 1000)")
    parser.add_argument("--seed", type=int, default=1, help="which mutants (default 1)")
    parser.add_argument("--jobs", type=int, default=1, help="worker processes (default 1)")
    parser.add_argument("--hang-after", type=float, default=20.0, help="s without answer")
    parser.add_argument("--slow", type=float, default=2.0, help="s: a slower check fails")
    parser.add_argument("--max-mb", type=float, default=200.0, help="MB a check may grow by")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON only")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--indexes", default="", help=argparse.SUPPRESS)
    parser.add_argument(
        "--canary-every",
        type=int,
        default=0,
        help="make every Nth check fail on purpose (proves the harness sees each failure)",
    )
    args = parser.parse_args()
    if args.worker:
        worker(args.seed, [int(i) for i in args.indexes.split(",") if i], args.canary_every)
        return 0
    results = run(args)
    summary = report(args, results)
    return 0 if summary["clean"] == summary["mutants"] else 1


if __name__ == "__main__":
    sys.exit(main())
