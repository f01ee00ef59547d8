"""How long after a partition heals Zenoh alone routes queries and samples again.

Plain Zenoh sessions, no fw component: the hub on a `control` namespace and five
peers placed as topologies/seeg_hosts.yaml places fw's processes (the arm on the
KRC's link), linked as fw's deployer links them (`framework.bus`; `--links` for
other layouts). Every peer declares a queryable, a liveliness token and an echo
subscriber, and pings every other peer directly; the hub asks and pings each one
every ~0.4 s and hears from each which peers answer it. The control host is cut off
for `--partition` seconds (`--cut` another host), then the tool reports, per run,
when every peer answered the hub, echoed it and heard every other peer again.

Written for issue 46: after a control-host partition fw's requests to some
processes got "nothing on the bus takes it" for 10 s and more while their tokens
were alive. This tool shows it happens without fw (eclipse-zenoh/zenoh#2517 is
the nearest upstream report) and checks a new Zenoh release again:

    sudo python tools/zenoh_partition.py --runs 6
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

NAMES = ("arm", "cameras", "robot", "supervision", "trackers")
HOST = {"arm": "krc", "cameras": "cameras", "robot": "robot", "supervision": "robot"}
HOST["trackers"] = "tracking"
PORT = 7600


def _config(name: str, address: dict[str, str]):
    """fw's bus settings for the hub (`name` == "hub") or one peer, linked as
    `address["links"]` says (`--links`)."""
    from framework.bus import BusConfig

    def endpoint(peer: str) -> str:
        return f"tcp/{address[peer]}:{PORT + 1 + NAMES.index(peer)}"

    hub = address["hub"]
    links = address.get("links", "fw")
    extra: dict = {}
    if name == "hub":
        hub_links = tuple(endpoint(n) for n in NAMES if links == "both")
        if address.get("routing") == "hub-router":
            extra = {"mode": "router"}
        return BusConfig("zp", PORT, hub, peers=hub_links, extra=extra)
    i = NAMES.index(name)
    before = tuple(endpoint(n) for n in NAMES[:i] if links != "gossip")
    return BusConfig(
        "zp", PORT, hub, listen=address[name], listen_port=PORT + 1 + i, peers=before, extra=extra
    )


REOPEN_AFTER = 6.0
"""s a peer (`--reopen`) waits, hearing no more another peer while it hears the hub,
before it opens its session again (a normal heal relinks within ~2 s)."""


def peer(name: str, address: dict[str, str]) -> None:
    """One peer: a queryable, a token and an echo, until killed; with `--reopen`, a
    peer that has not heard another for `REOPEN_AFTER` while it still hears the hub
    closes its session and opens a new one (the workaround to try: does a new session
    make the routes?)."""
    from framework.bus import Bus

    advanced = address.get("advanced", False)  # fw's latest-value ports, or plain ones
    others = [n for n in NAMES if n != name]
    heard: dict[str, bytes] = {}
    seq = 0
    hub_at = [0.0]  # when the hub's last ping came

    while True:
        bus = Bus(_config(name, address))
        heard_at, redeclare = _peer_session(bus, name, others, address, heard, hub_at)
        status = bus.publisher(f"st/{name}", cache=advanced)
        pings = {n: bus.publisher(f"pp/{n}/{name}", cache=advanced) for n in others}
        while True:
            redeclare()
            seq += 1
            for n in others:
                pings[n].put(str(seq).encode())
            time.sleep(0.3)
            fresh = {str(seq).encode(), str(seq - 1).encode()}
            now = time.monotonic()
            for n in others:
                if heard.get(n) in fresh:
                    heard_at[n] = now
            status.put(json.dumps([n for n in others if heard.get(n) in fresh]).encode())
            hub_fresh = now - hub_at[0] < 1.0
            lost = [n for n, at in heard_at.items() if hub_fresh and now - at > REOPEN_AFTER]
            if address.get("reopen") and lost:
                print(f"{name}: hears {', '.join(lost)} no more: a new session", file=sys.stderr)
                bus.close()
                heard.clear()
                break


def _peer_session(
    bus: Any,
    name: str,
    others: list[str],
    address: dict[str, Any],
    heard: dict[str, bytes],
    hub_at: list[float],
) -> tuple[dict[str, float], Any]:
    """Declare a peer's queryable, token, echo and ping answers on `bus`: when each
    other peer was last heard (the session's start until it is), and the call that
    declares the subscribers again if a token came back (`--redeclare`)."""
    advanced = address.get("advanced", False)
    bus.queryable(f"q/{name}", lambda query: query.reply(query.key_expr, b"1"))
    bus.token(f"alive/{name}")
    echo = bus.publisher(f"r/{name}", cache=advanced)

    def echoed(sample: Any) -> None:
        hub_at[0] = time.monotonic()
        echo.put(sample.payload.to_bytes())

    bus.subscribe(f"s/{name}", echoed, history=advanced)
    # and every other peer, directly: pinged, and its pings answered
    answers = {n: bus.publisher(f"pr/{n}/{name}", cache=advanced) for n in others}

    def answer(sample: Any) -> None:
        answers[str(sample.key_expr).rsplit("/", 1)[1]].put(sample.payload.to_bytes())

    def declare() -> list[Any]:
        return [
            bus.subscribe(f"pp/{name}/*", answer, history=advanced),
            bus.subscribe(
                f"pr/{name}/*",
                lambda s: heard.__setitem__(
                    str(s.key_expr).rsplit("/", 1)[1], s.payload.to_bytes()
                ),
                history=advanced,
            ),
        ]

    subscribers = declare()
    back = threading.Event()  # a peer's token came back: declare again (--redeclare)
    if address.get("redeclare"):
        import zenoh

        bus.session.liveliness().declare_subscriber(
            "alive/*",
            lambda s: back.set() if s.kind == zenoh.SampleKind.PUT else None,
            history=False,
        )

    def redeclare() -> None:
        if back.is_set():
            back.clear()
            for subscriber in subscribers:
                subscriber.undeclare()
            subscribers[:] = declare()

    return dict.fromkeys(others, time.monotonic()), redeclare


def hub(address: dict[str, str], seconds: float) -> None:
    """Ask and ping every peer until `seconds` pass; print one JSON line per round."""
    from framework.bus import Bus

    bus = Bus(_config("hub", address), hub=True)
    echoed: dict[str, bytes] = {}
    advanced = address.get("advanced", False)
    bus.subscribe(
        "r/*",
        lambda s: echoed.__setitem__(str(s.key_expr).rsplit("/", 1)[1], s.payload.to_bytes()),
        history=advanced,
    )
    pings = {n: bus.publisher(f"s/{n}", cache=advanced) for n in NAMES}
    hears: dict[str, list[str]] = {}  # what each peer says it hears from the others
    bus.subscribe(
        "st/*",
        lambda s: hears.__setitem__(
            str(s.key_expr).rsplit("/", 1)[1], json.loads(bytes(s.payload.to_bytes()))
        ),
        history=advanced,
    )
    start, n = time.monotonic(), 0
    while time.monotonic() - start < seconds:
        n += 1
        answered = {}
        for name in NAMES:
            try:
                answered[name] = bool(bus.query(f"q/{name}", b"", 0.3))
            except Exception:
                answered[name] = False
            pings[name].put(str(n).encode())
        time.sleep(0.1)
        # the echo of this round's ping or of the last one's (it may still be on its way)
        fresh = {str(n).encode(), str(n - 1).encode()}
        said = {m: v for m, v in hears.items() if isinstance(v, list)}  # a peer's list
        apart = {m: sorted(set(NAMES) - {m} - set(said.get(m, []))) for m in NAMES}
        ok = [m for m in NAMES if answered[m] and echoed.get(m) in fresh and not apart[m]]
        deaf = [m for m in NAMES if echoed.get(m) not in fresh]
        mute = [m for m in NAMES if not answered[m]]
        line = {"t": round(time.monotonic() - start, 2), "ok": ok, "mute": mute, "deaf": deaf}
        line["linked"] = bus.peers()
        line["apart"] = {m: a for m, a in apart.items() if a}
        print(json.dumps(line), flush=True)


def one_run(
    partition: float,
    after: float,
    links: str = "fw",
    cut: str = "control",
    advanced: bool = False,
    routing: str = "peers",
    redeclare: bool = False,
    reopen: bool = False,
) -> float | None:
    """Seconds from the heal until every peer answered and echoed (None: not within
    `after`)."""
    from framework import netns

    hosts = netns.Hosts(prefix="zp-", bridge="zpbr0").up()
    address: dict = {"hub": hosts.address("control"), "links": links, "advanced": advanced}
    address["routing"] = routing
    address["redeclare"] = redeclare
    address["reopen"] = reopen
    address |= {n: hosts.address(HOST[n]) for n in NAMES}
    me = [sys.executable, __file__]
    peers = [
        subprocess.Popen(hosts.command(HOST[n], *me, "--peer", n, json.dumps(address)))
        for n in NAMES
    ]
    try:
        time.sleep(0.5)
        watch = subprocess.Popen(
            hosts.command("control", *me, "--hub", json.dumps(address), str(3 + partition + after)),
            stdout=subprocess.PIPE,
            text=True,
        )
        time.sleep(3)
        hosts.cut(cut)
        time.sleep(partition)
        hosts.heal(cut)
        lines, _ = watch.communicate(timeout=60 + partition + after)
        rounds = [json.loads(line) for line in lines.splitlines() if line.startswith("{")]
        heal_at = 3 + partition
        after_heal = [r for r in rounds if r["t"] > heal_at]
        # back: the first round from which every later one reached every peer
        back = None
        for r in reversed(after_heal):
            if len(r["ok"]) != len(NAMES):
                break
            back = r["t"]
        if back is None:
            last = after_heal[-1] if after_heal else {"mute": NAMES, "deaf": NAMES}
            print(
                f"  at the end, queries unanswered: {', '.join(last['mute']) or 'none'}; "
                f"pings not echoed: {', '.join(last['deaf']) or 'none'}; "
                f"peers not hearing each other: {last.get('apart') or 'none'}; "
                f"the hub linked to {last.get('linked', 0)} of {len(NAMES)}"
            )
            return None
        return back - heal_at
    finally:
        for p in peers:
            p.kill()
            p.wait()
        hosts.down()


def main(argv: list[str] | None = None) -> int:
    """Parse the command line and run (or play one role of a run)."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=6)
    parser.add_argument("--partition", type=float, default=2.0, help="s the control host is cut")
    parser.add_argument("--after", type=float, default=15.0, help="s watched after the heal")
    parser.add_argument(
        "--links",
        choices=("fw", "both", "gossip"),
        default="fw",
        help="fw: each peer links to the hub and to the peers before it (as fw deploys); "
        "both: the hub also links to every peer (fw until 2026-11-29); gossip: each "
        "peer links to the hub only, gossip makes the rest",
    )
    parser.add_argument("--cut", default="control", help="the host cut off (default control)")
    parser.add_argument(
        "--advanced",
        action="store_true",
        help="echo through fw's latest-value publishers and subscribers (zenoh.ext), as "
        "its ports do, instead of plain ones",
    )
    parser.add_argument(
        "--routing",
        choices=("peers", "hub-router"),
        default="peers",
        help="peers: every session a Zenoh peer (a sample reaches only the peers linked to "
        "its publisher: since Zenoh 1.9 peers relay nothing); hub-router: the hub is a "
        "Zenoh router, which relays between peers linked to it but not to each other "
        "(failover brokering)",
    )
    parser.add_argument(
        "--redeclare",
        action="store_true",
        help="each peer declares its subscribers again whenever another peer's liveliness "
        "token comes back (a workaround to try: are the missing routes declarations?)",
    )
    parser.add_argument(
        "--reopen",
        action="store_true",
        help=f"a peer that hears another no more for {REOPEN_AFTER:g} s while it still hears "
        "the hub closes its session and opens a new one (a workaround to try: does a new "
        "session make the routes?)",
    )
    parser.add_argument("--peer", nargs=2, help=argparse.SUPPRESS)
    parser.add_argument("--hub", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.peer:
        peer(args.peer[0], json.loads(args.peer[1]))
        return 0
    if args.hub:
        hub(json.loads(args.hub[0]), float(args.hub[1]))
        return 0
    from framework import netns

    why = netns.available()
    if why:
        print(f"zenoh_partition: {why}", file=sys.stderr)
        return 2
    from importlib.metadata import version

    times: list[float] = []
    lost = 0
    for i in range(args.runs):
        back = one_run(
            args.partition,
            args.after,
            args.links,
            args.cut,
            args.advanced,
            args.routing,
            args.redeclare,
            args.reopen,
        )
        said = "not back" if back is None else f"{back:.2f} s"
        print(f"run {i + 1}/{args.runs}: every peer answers again {said} after the heal")
        if back is None:
            lost += 1
        else:
            times.append(back)
    print(
        f"eclipse-zenoh {version('eclipse-zenoh')}, links {args.links}"
        + (", advanced publishers" if args.advanced else "")
        + f", routing {args.routing}"
        + (", subscribers declared again on a token's return" if args.redeclare else "")
        + (", a new session where a peer is heard no more" if args.reopen else "")
        + ", "
        f"{args.cut} cut for {args.partition:g} s: "
        f"{len(times)} of {args.runs} runs back within {args.after:g} s"
        + (f" (median {statistics.median(times):.2f} s, max {max(times):.2f} s)" if times else "")
        + f"; {lost} with routes missing for the whole {args.after:g} s"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
