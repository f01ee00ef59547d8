"""Names of the Zenoh keys fw uses (inside the deployment's namespace).

One place, so the container, the remote client, the Configurator and the
console agree without importing each other.
"""

from __future__ import annotations


def alive(component: str) -> str:
    """Liveliness token of a component (vanishes when its process dies)."""
    return f"fw/alive/{component}"


def control(component: str) -> str:
    """Where a component answers lifecycle, connection, property and operation requests
    (its queryable is `control(c)/**`: each request has a key of its own, below)."""
    return f"fw/ctl/{component}"


def control_request(component: str, op: str, operation: str = "") -> str:
    """The key of one kind of request (`state`, `configure`, `batch`...; an operation
    call is `call/<operation>`), so the bus's access rules can tell a read from a
    command (framework/access.py)."""
    return f"fw/ctl/{component}/{op}" + (f"/{operation}" if op == "call" else "")


def state(component: str) -> str:
    """Where a component's state changes are published (latest value cached)."""
    return f"fw/state/{component}"


def refused(component: str) -> str:
    """Where a component says it refused a sample, and why (the flight recorder keeps it)."""
    return f"fw/refused/{component}"


def thinned(key: str, rate: float) -> str:
    """Where an output port publishes its samples on `key` thinned to `rate` Hz (a
    connection's `rate:`): readers of the same rate share it."""
    return f"{key}/at_{rate:g}hz"


def port_type(key: str) -> str:
    """Queryable telling which message type is written on `key` (checked on connect)."""
    return f"fw/types/{key}"


def container(name: str) -> str:
    """Queryable of a container process (list components, shut down)."""
    return f"fw/container/{name}"


def clock(process: str) -> str:
    """Queryable of a process's wall clock (framework/clock_offset.py): any member may
    ask it, to measure how far that host's clock is from its own."""
    return f"fw/clock/{process}"


def heartbeat(component: str) -> str:
    """Where a watched component proves, from its own activity thread, that it runs."""
    return f"fw/heartbeat/{component}"


def process_heartbeat(process: str) -> str:
    """Where a process proves it is scheduled (a hung process falls silent)."""
    return f"fw/process/{process}/heartbeat"


def route_probe(process: str) -> str:
    """Where a process says once a second that it is on the bus, so the others can tell
    routes Zenoh left unmade from a partition (framework/routes.py)."""
    return f"fw/process/{process}/routes"


def default_output(component: str, port: str) -> str:
    """The key an output port publishes on unless told otherwise."""
    return f"{component}/{port}"


def config_switched(process: str) -> str:
    """Where a process reports a local switch it made on a configuration request (the
    Configurator waits for it, framework/configurator.py)."""
    return f"fw/config/switched/{process}"


CONFIG_REQUESTS = "fw/config/request"
"""Where the Coordinator asks for configurations (`ConfigRequest`)."""
CONFIG_ACKS = "fw/config/ack"
"""Where the Configurator answers them (`ConfigAck`)."""
ALL_SWITCHED = "fw/config/switched/*"
DEPLOYER_EVENTS = "fw/deployer/events"
"""Where fw deploy reports what happens to its processes (lost, restarted)."""
ALL_ROUTE_PROBES = "fw/process/*/routes"
ALL_ALIVE = "fw/alive/*"
ALL_STATES = "fw/state/*"
ALL_REFUSED = "fw/refused/*"
