"""Several hosts on one machine: Linux network namespaces joined by a bridge, and the
faults a real network has.

An operating room's fw runs on several machines (a tracking PC, a camera PC, the
robot's control PC, the operator's); `Hosts` builds them as network namespaces on one
Linux machine so a deployment crosses real network interfaces: each host gets a
namespace `<prefix><host>` with loopback and one veth into a bridge in the machine's own
namespace (`10.77.0.0/24`, the hosts in order from .1), and the KRC, as FRI has its own
network port, a namespace of its own on a point-to-point link to the robot's host
(`10.78.0.1` robot side, `10.78.0.2` the KRC). Processes are placed with
`ip netns exec <namespace> ...` (`Hosts.command`).

Faults (`Hosts.cut` / `Hosts.heal`): a partition takes a host's link down (every
connection through it stalls, as a pulled cable; TCP keeps its state) and up again.
`Hosts.impair` makes a link lossy or slow. Loss is a random drop by nftables of every
packet crossing the host's link, in both directions, each with the given probability
(a bad cable or radio loses both ways), taken where each end receives it (the host's
side and the bridge's), so no sender is told; it needs `nft` (Debian's `nftables`,
which tools/install.sh installs) and the kernel's nf_tables. Delay and jitter are `tc netem`
on what the host sends, where the kernel has sch_netem; where it has not (some VMs'
kernels), the host's link is swapped for the fault's time for a wire of two TAP devices
and a process that carries each frame after its delay (framework/netns_delay.py; not
for the KRC's link, whose delay `arm.impair` makes at FRI's level).

The bridge and its ports live in the namespace `up` ran in (the machine's own).
`up` names it `<prefix>machine` (`ip netns attach`), so a fault injected from inside
a host (the control host's `fw deploy --scenario`) still reaches the bridge's side of
a link: from there, until 2026-12-02, the drop rule at a link's bridge end was made in
the control host's namespace, on a device it does not have (nf_tables takes such a
hook and waits for the device), and a lossy link lost only what the host received.

Needs root (CAP_NET_ADMIN) and `ip`; `available()` says why not, and tests skip with
that reason.
"""

from __future__ import annotations

import contextlib
import functools
import os
import shutil
import signal
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

from framework.errors import FwError

LOSS_TABLE = "fw_loss"
"""The prefix of the nftables tables (family netdev, `fw_loss_<device>`, one at each
end of a lossy link) that drop its packets."""
BRIDGE_NET = "10.77.0"
KRC_NET = "10.78.0"
KRC = "krc"
"""The host name of the KRC's namespace (on its own link to the robot's host)."""


class NetnsError(FwError):
    """A namespace, link or fault could not be made (what and why)."""


def available() -> str:
    """Empty if this machine can build hosts as namespaces; else why not, in words."""
    if os.geteuid() != 0:
        return "network namespaces need root (CAP_NET_ADMIN)"
    if shutil.which("ip") is None:
        return "the `ip` command (iproute2) is missing"
    probe = f"fwprobe{os.getpid()}"
    made = subprocess.run(["ip", "netns", "add", probe], capture_output=True, text=True)
    if made.returncode != 0:
        return f"cannot make a network namespace: {made.stderr.strip()}"
    subprocess.run(["ip", "netns", "del", probe], capture_output=True)
    return ""


@functools.cache
def netem_available() -> bool:
    """Does the kernel have the netem queueing discipline (loss, delay)? (Asked once
    per process: a fault made in the middle of a run must not wait for a probe.)"""
    probe = f"fwnetem{os.getpid()}"
    subprocess.run(["ip", "netns", "add", probe], capture_output=True)
    try:
        run = subprocess.run(
            ["ip", "netns", "exec", probe, "tc", "qdisc", "add", "dev", "lo", "root", "netem"],
            capture_output=True,
            text=True,
        )
        return run.returncode == 0
    finally:
        subprocess.run(["ip", "netns", "del", probe], capture_output=True)


def loss_available() -> str:
    """Empty if `Hosts.impair` can drop packets here (nftables); else why not."""
    if shutil.which("nft") is None:
        return "random loss needs nftables' `nft` command (Debian: apt install nftables)"
    probe = f"fwloss{os.getpid()}"
    subprocess.run(["ip", "netns", "add", probe], capture_output=True)
    try:
        run = _nft(probe, _loss_rules("lo", 0.5))
        return "" if run.returncode == 0 else f"nftables refused a drop rule: {run.stderr.strip()}"
    finally:
        subprocess.run(["ip", "netns", "del", probe], capture_output=True)


def _loss_rules(dev: str, loss: float) -> str:
    """An nftables table dropping each packet `dev` receives with probability `loss` (in
    steps of 1/10000). On ingress, as a lossy cable would: the sender sees nothing (a
    drop on output would fail its send with EPERM)."""
    drop = f"numgen random mod 10000 < {round(loss * 10000)} drop"
    return (
        f"table netdev {LOSS_TABLE}_{dev} {{\n"
        f'  chain lossy {{ type filter hook ingress device "{dev}" priority 0; {drop}; }}\n'
        "}\n"
    )


def _nft(ns: str | None, script: str) -> subprocess.CompletedProcess[str]:
    """`nft -f -` in namespace `ns` (None: this machine's own)."""
    where = ["ip", "netns", "exec", ns] if ns else []
    return subprocess.run([*where, "nft", "-f", "-"], input=script, capture_output=True, text=True)


def _ip(*args: str) -> None:
    run = subprocess.run(["ip", *args], capture_output=True, text=True)
    if run.returncode != 0:
        raise NetnsError(f"ip {' '.join(args)}: {run.stderr.strip() or run.returncode}")


@dataclass
class Hosts:
    """The namespaces of one set of hosts (see the module docstring). `up()` builds
    them (replacing any left by an earlier run), `down()` removes them."""

    names: tuple[str, ...] = ("control", "tracking", "cameras", "robot")
    prefix: str = "fw-"
    krc: bool = True
    """Also the KRC's namespace, linked to `robot` only."""
    bridge: str = "fwbr0"
    made: list[str] = field(default_factory=list)
    _wires: dict[str, subprocess.Popen[str]] = field(default_factory=dict)
    """Hosts whose link is swapped for a delaying wire, and its process."""

    @property
    def machine(self) -> str:
        """The name `up` gives the namespace of the bridge (the machine's own)."""
        return f"{self.prefix}machine"

    def namespace(self, host: str) -> str:
        """The namespace of `host`."""
        return f"{self.prefix}{host}"

    def address(self, host: str) -> str:
        """Where `host` listens (the KRC: on its own link)."""
        if host == KRC:
            return f"{KRC_NET}.2"
        return f"{BRIDGE_NET}.{self.names.index(host) + 1}"

    @property
    def krc_link_address(self) -> str:
        """The robot host's address on the KRC's link (FRI's other end)."""
        return f"{KRC_NET}.1"

    def up(self) -> Hosts:
        """Build every namespace, the bridge and the links (replacing leftovers)."""
        self.down()
        _ip("netns", "attach", self.machine, str(os.getpid()))
        _ip("link", "add", self.bridge, "type", "bridge")
        _ip("link", "set", self.bridge, "up")
        for index, host in enumerate(self.names):
            ns, here, there = self.namespace(host), self._veth(f"{index}h"), self._veth(f"{index}b")
            self._namespace(ns)
            _ip("link", "add", here, "type", "veth", "peer", "name", there)
            _ip("link", "set", here, "netns", ns)
            _ip("-n", ns, "link", "set", here, "name", "eth0")
            _ip("-n", ns, "addr", "add", f"{self.address(host)}/24", "dev", "eth0")
            _ip("-n", ns, "link", "set", "eth0", "up")
            _ip("link", "set", there, "master", self.bridge)
            _ip("link", "set", there, "up")
        if self.krc and "robot" in self.names:
            ns = self.namespace(KRC)
            self._namespace(ns)
            near, far = self._veth("k0"), self._veth("k1")
            _ip("link", "add", near, "type", "veth", "peer", "name", far)
            _ip("link", "set", near, "netns", self.namespace("robot"))
            _ip("link", "set", far, "netns", ns)
            robot = self.namespace("robot")
            _ip("-n", robot, "link", "set", near, "name", "fri0")
            _ip("-n", ns, "link", "set", far, "name", "fri0")
            _ip("-n", robot, "addr", "add", f"{self.krc_link_address}/30", "dev", "fri0")
            _ip("-n", ns, "addr", "add", f"{self.address(KRC)}/30", "dev", "fri0")
            _ip("-n", robot, "link", "set", "fri0", "up")
            _ip("-n", ns, "link", "set", "fri0", "up")
            # the simulated KRC is also a process of the deployment (its status, the real
            # TCP the simulated trackers see): its bus traffic is routed through the robot
            # host, as a real KRC's would not be (it speaks FRI only)
            subprocess.run(
                ["ip", "netns", "exec", robot, "sysctl", "-qw", "net.ipv4.ip_forward=1"],
                capture_output=True,
            )
            for host in (*self.names, KRC):
                self._route(host)
        return self

    def _route(self, host: str) -> None:
        """The route of `host`'s bus traffic to or from the KRC, through the robot host:
        made by `up`, and made again by `heal` (a link taken down loses every route
        through it, and brought up gets back only its own subnet's: a healed host could
        no longer reach the KRC, nor the KRC anyone)."""
        if not (self.krc and "robot" in self.names) or host == "robot":
            return
        if host == KRC:
            route = ["default", "via", self.krc_link_address]
        else:
            route = [f"{KRC_NET}.0/30", "via", self.address("robot")]
        _ip("-n", self.namespace(host), "route", "replace", *route)

    def _veth(self, suffix: str) -> str:
        """A link's name in this machine's namespace, unique to this set of hosts."""
        return (self.prefix.replace("-", "") + suffix)[:15]

    def _namespace(self, ns: str) -> None:
        _ip("netns", "add", ns)
        self.made.append(ns)
        _ip("-n", ns, "link", "set", "lo", "up")

    def down(self) -> None:
        """Remove the namespaces (their processes' links go with them) and the bridge."""
        for wire in self._wires.values():  # first: their TAPs are in the namespaces
            _end_wire(wire)
        self._wires.clear()
        for host in [*self.names, KRC]:
            subprocess.run(["ip", "netns", "del", self.namespace(host)], capture_output=True)
        # a namespace's links go with it, but the kernel frees them later: an `up` right
        # after would find their names taken
        links = [self._veth(f"{i}{end}") for i in range(len(self.names)) for end in "hbwd"]
        for link in [*links, self._veth("k0"), self._veth("k1"), self.bridge]:
            subprocess.run(["ip", "link", "del", link], capture_output=True)
        if shutil.which("nft") is not None:  # a lossy link's tables at the bridge's ports
            for i in range(len(self.names)):  # (a run that died before its heal)
                _nft(None, f"delete table netdev {LOSS_TABLE}_{self._veth(f'{i}b')}\n")
        subprocess.run(["ip", "netns", "del", self.machine], capture_output=True)
        self.made.clear()

    def command(self, host: str, *argv: str) -> list[str]:
        """`argv` run on `host` (inside its namespace)."""
        return ["ip", "netns", "exec", self.namespace(host), *argv]

    def deploy(
        self,
        host: str,
        topology: Path,
        keys: Path,
        cwd: Path,
        environment: dict[str, str] | None = None,
    ) -> subprocess.Popen[bytes]:
        """Start `host`'s part of `topology` on it (`fw deploy --host`, headless, in a
        session of its own so `end` stops every process it started); output discarded."""
        variables = [f"{k}={v}" for k, v in (environment or {}).items()]
        argv = [sys.executable, "-m", "framework.cli", "deploy", str(topology)]
        argv += ["--keys", str(keys), "--headless", "--host", host]
        return subprocess.Popen(
            self.command(host, "env", *variables, *argv),
            cwd=cwd,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
        )

    def deploy_others(
        self,
        topology: Path,
        keys: Path,
        cwd: Path,
        environment: dict[str, dict[str, str]] | None = None,
    ) -> list[subprocess.Popen[bytes]]:
        """Start the part of every host but `control` (whose part the caller runs,
        with its chart), the KRC's included; `environment`: variables by host."""
        hosts = (*[h for h in self.names if h != "control"], KRC)
        return [self.deploy(h, topology, keys, cwd, (environment or {}).get(h)) for h in hosts]

    def end(self, parts: list[subprocess.Popen[bytes]]) -> None:
        """Stop hosts' parts started by `deploy` (SIGINT, as an operator's Ctrl-C; killed
        after 20 s), then any process left in a host, so that nothing of one run
        outlives it (the next run's ports and component names are the same)."""
        for part in parts:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(part.pid, signal.SIGINT)
        for part in parts:
            try:
                part.wait(20)
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(part.pid, signal.SIGKILL)
                part.wait(5)
        for host in (*self.names, KRC):
            pids = subprocess.run(
                ["ip", "netns", "pids", self.namespace(host)], capture_output=True, text=True
            ).stdout.split()
            for pid in pids:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(int(pid), signal.SIGKILL)

    def _link(self, host: str) -> tuple[str, str]:
        """`host`'s namespace and the device its traffic crosses now."""
        if host in self._wires:
            return self.namespace(host), WIRE_DEVICE
        return self.namespace(host), "fri0" if host == KRC else "eth0"

    def bridge_port(self, host: str) -> str:
        """The device in the bridge's namespace that `host`'s traffic crosses now (its
        veth's end, or its delaying wire's TAP): what it receives, the host sent."""
        index = self.names.index(host)
        return self._veth(f"{index}{'d' if host in self._wires else 'b'}")

    def cut(self, host: str) -> None:
        """Partition `host`: its link goes down (the KRC's: its FRI link)."""
        ns, dev = self._link(host)
        _ip("-n", ns, "link", "set", dev, "down")

    def heal(self, host: str) -> None:
        """End a partition of `host` and any impairment of its link."""
        self._unwire(host)
        ns, dev = self._link(host)
        _ip("-n", ns, "link", "set", dev, "up")
        self._route(host)
        subprocess.run(
            ["ip", "netns", "exec", ns, "tc", "qdisc", "del", "dev", dev, "root"],
            capture_output=True,
        )
        if shutil.which("nft") is not None:  # none there unless the link was lossy
            for where, point in self._ends(host):
                _nft(where, f"delete table netdev {LOSS_TABLE}_{point}\n")

    def impair(self, host: str, loss: float = 0.0, delay: float = 0.0, jitter: float = 0.0) -> None:
        """Make `host`'s link lossy (each packet either way dropped with probability
        `loss`, 0-1: nftables) and slow (`delay` and `jitter`, s, on what it sends: tc
        netem), until `heal`. `NetnsError` says what this machine cannot do."""
        if not 0.0 <= loss <= 1.0:
            raise NetnsError(f"a loss is a share between 0 and 1, not {loss!r}")
        ns, dev = self._link(host)
        if (delay or jitter) and not netem_available():
            if host == KRC:
                raise NetnsError(
                    "cannot delay the KRC's link without the kernel's sch_netem (FRI's own "
                    "delay is arm.impair's); partitions and loss still work"
                )
            self._wire(host, delay, jitter, loss)
            return
        if delay or jitter:
            argv = ["ip", "netns", "exec", ns, "tc", "qdisc", "replace", "dev", dev, "root"]
            argv += ["netem", "delay", f"{delay * 1e3:g}ms", f"{jitter * 1e3:g}ms"]
            run = subprocess.run(argv, capture_output=True, text=True)
            if run.returncode != 0:
                raise NetnsError(
                    f"cannot delay {host}'s link: {run.stderr.strip()} (this kernel may lack "
                    "sch_netem; partitions and loss still work)"
                )
        if loss:
            why = "" if shutil.which("nft") else loss_available()  # says what is missing
            for where, point in [] if why else self._ends(host):
                run = _nft(where, _loss_rules(point, loss))
                if run.returncode != 0:
                    why = f"nftables refused the drop rule: {run.stderr.strip()}"
                    break
            if why:
                self.heal(host)
                raise NetnsError(f"cannot make {host}'s link lossy: {why}")

    def _ends(self, host: str) -> list[tuple[str | None, str]]:
        """Both ends of `host`'s link, as (namespace, device); None: this machine's own
        namespace (the bridge's port)."""
        if host == KRC:
            return [(self.namespace(KRC), "fri0"), (self.namespace("robot"), "fri0")]
        index = self.names.index(host)
        return [(self.namespace(host), "eth0"), (self._at_machine(), self._veth(f"{index}b"))]

    def _at_machine(self) -> str | None:
        """Where the bridge is: its namespace's name, None for hosts built before
        `up` named it (then this process must run in that namespace)."""
        return self.machine if Path("/run/netns", self.machine).exists() else None

    def _wire(self, host: str, delay: float, jitter: float, loss: float) -> None:
        """Swap `host`'s link for a delaying wire (framework/netns_delay.py) until
        `heal`: both TAPs are made in the bridge's namespace, the host's is moved into
        the host with eth0's MAC and address (peers' ARP entries stay right, TCP
        connections go on), then eth0 goes down."""
        machine = self._at_machine()
        if machine is None:
            raise NetnsError(
                f"cannot delay {host}'s link: its hosts were built before fw named "
                "the bridge's namespace (build them again: python -m framework.netns up)"
            )
        ns, index = self.namespace(host), self.names.index(host)
        near, far = self._veth(f"{index}w"), self._veth(f"{index}d")
        argv = ["ip", "netns", "exec", machine, sys.executable, "-m", "framework.netns_delay"]
        wire = subprocess.Popen(
            [*argv, near, far, repr(delay), repr(jitter), repr(loss)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            start_new_session=True,
        )
        if (wire.stdout.readline() if wire.stdout else "").strip() != "ready":
            _end_wire(wire)
            raise NetnsError(
                f"cannot delay {host}'s link: its wire did not start: "
                f"{(wire.stderr.read() if wire.stderr else '').strip()[-300:]}"
            )
        self._wires[host] = wire
        try:
            mac = _link_field(ns, "eth0", "link/ether", "no MAC address")
            address = f"{self.address(host)}/24"
            # the bridge its own link is a port of (a fault's Hosts knows only the prefix)
            bridge = _link_field(machine, self._veth(f"{index}b"), "master", "in no bridge")
            _batch(machine, [f"link set {far} master {bridge}", f"link set {far} up"])
            _batch(machine, [f"link set {near} netns {ns}"])
            _batch(
                ns, [f"link set {near} name {WIRE_DEVICE}", f"link set {WIRE_DEVICE} address {mac}"]
            )
            # the swap itself, in one `ip`: the host is without a link for well under 1 ms
            _batch(
                ns,
                [
                    "link set eth0 down",
                    f"addr del {address} dev eth0",
                    f"addr add {address} dev {WIRE_DEVICE}",
                    f"link set {WIRE_DEVICE} up",
                ],
            )
            self._route(host)
        except NetnsError:
            self._unwire(host)
            raise

    def _unwire(self, host: str) -> None:
        """Give `host` its own link back (the wire's TAPs go with its process)."""
        wire = self._wires.pop(host, None)
        if wire is None:
            return
        _end_wire(wire)
        ns = self.namespace(host)
        subprocess.run(["ip", "-n", ns, "link", "del", WIRE_DEVICE], capture_output=True)
        subprocess.run(
            ["ip", "-n", ns, "addr", "add", f"{self.address(host)}/24", "dev", "eth0"],
            capture_output=True,  # already there if the swap failed before moving it
        )


WIRE_DEVICE = "dly0"
"""The name of a delaying wire's TAP inside its host."""


def _link_field(ns: str, device: str, word: str, missing: str) -> str:
    """The value after `word` in `ip -o link show device` in namespace `ns` (its MAC
    after `link/ether`, its bridge after `master`); `NetnsError` with `missing` if none."""
    run = subprocess.run(
        ["ip", "-n", ns, "-o", "link", "show", device], capture_output=True, text=True
    )
    words = run.stdout.split()
    if run.returncode != 0 or word not in words:
        raise NetnsError(f"{device} in {ns}: {missing} {run.stderr.strip()}".rstrip())
    return words[words.index(word) + 1]


def _batch(ns: str, commands: list[str]) -> None:
    """`ip` commands run in namespace `ns` by one `ip -batch` (in order, fast)."""
    run = subprocess.run(
        ["ip", "-n", ns, "-batch", "-"],
        input="\n".join(commands) + "\n",
        capture_output=True,
        text=True,
    )
    if run.returncode != 0:
        raise NetnsError(
            f"ip -n {ns}: {'; '.join(commands)}: {run.stderr.strip() or run.returncode}"
        )


def _end_wire(wire: subprocess.Popen[str]) -> None:
    """Stop a wire's process (its TAPs vanish with it)."""
    with contextlib.suppress(ProcessLookupError):
        os.killpg(wire.pid, signal.SIGKILL)
    wire.wait(5)


def main(argv: list[str] | None = None) -> int:
    """`python -m framework.netns up|down`: build or remove the default hosts."""
    import argparse
    import sys

    parser = argparse.ArgumentParser(
        prog="python -m framework.netns",
        description="Build the hosts of topologies/seeg_hosts.yaml as network namespaces "
        "of this machine (control, tracking, cameras, robot, and the KRC on its own link), "
        "or remove them. Needs root.",
        epilog="then: ip netns exec fw-tracking fw deploy topologies/seeg_hosts.yaml "
        "--keys KEYS --host tracking (one per host; control runs the chart)",
    )
    parser.add_argument("action", choices=["up", "down"])
    args = parser.parse_args(argv)
    why = available()
    if why:
        print(f"fw: cannot build hosts here: {why}", file=sys.stderr)
        return 1
    hosts = Hosts()
    if args.action == "down":
        hosts.down()
        return 0
    try:
        hosts.up()
    except NetnsError as exc:
        hosts.down()
        print(f"fw: {exc}", file=sys.stderr)
        return 1
    for host in (*hosts.names, KRC):
        print(f"{host:<9} {hosts.namespace(host):<12} {hosts.address(host)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
