"""The bus's access rules, generated from the topology: who may do what on which key.

Every link of a deployment is mutual TLS (framework/keystore.py), so every message a
session receives comes from a known subject: a process of the topology (certificate
common name = process name), `control` (fw deploy: Coordinator, Configurator,
console) or `operator` (the command-line clients). Every session enforces these rules
on what it receives (Zenoh access control, default deny), so a process cannot act
beyond its part even if its own code is compromised:

* a process **publishes** only on its components' output keys (as the topology and
  its configurations wire them), their heartbeats and state, and its own process
  heartbeat and route probe;
* it **declares** liveliness tokens and queryables only for its own components (no
  process can keep a dead one looking alive, or answer in its place);
* **control requests** (lifecycle, wiring, properties, operations) come only from
  `control`; `operator` may ask only what changes nothing: states, descriptions,
  properties, read-only operations (`@operation(readonly=True)`), and offer the
  Coordinator an operator event (which the Coordinator checks, framework/coordinator.py);
* everybody may subscribe (a process of the deployment may read its data), ask a
  key's message type, and use the advanced publishers' internal `@adv` keys (caches
  and their liveliness), which carry only what their publisher already published.

Zenoh matches these rules on full keys, so every key expression carries the
deployment's namespace.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from framework import keys
from framework.keystore import CONTROL, OPERATOR
from framework.topology.model import StepKind

if TYPE_CHECKING:
    from framework.topology import Topology

READ_REQUESTS = ("state", "describe", "get")
"""Control requests that change nothing (the operator may send them)."""
FW_DATA = ("state", "heartbeat", "process", "alive", "types", "config", "coordinator")
"""fw's own key spaces that carry status, not requests (under `fw/`)."""
ALL_MESSAGES = (
    "put",
    "delete",
    "declare_subscriber",
    "query",
    "reply",
    "declare_queryable",
    "liveliness_token",
    "declare_liveliness_subscriber",
    "liveliness_query",
)


def process_keys(topology: Topology, process: str) -> dict[str, list[str]]:
    """What one process may publish (`put`), declare as queryable (`queryable`) and as
    liveliness token (`token`), as keys without the namespace."""
    components = topology.components_in(process)
    names = {c.name for c in components}
    outputs: set[str] = set()
    for spec in components:
        ports = spec.info.outputs if spec.info is not None else spec.outputs
        outputs.update(spec.output_key(port) for port in ports)
        for thinned in topology.thinned.get(spec.name, {}).values():
            outputs.update(thinned)  # its streams thinned for slower readers (`rate:`)
    for configuration in topology.configurations.values():
        for step in configuration.steps:
            if step.kind is not StepKind.CONNECT or step.component not in names:
                continue
            spec = topology.components[step.component]
            if spec.info is not None and step.target in spec.info.outputs and step.key:
                outputs.add(step.key)
    put = sorted(outputs)
    put += [keys.heartbeat(n) for n in sorted(names)] + [keys.state(n) for n in sorted(names)]
    put += [keys.refused(n) for n in sorted(names)]
    put.append(keys.process_heartbeat(process))
    put.append(keys.route_probe(process))
    put.append(keys.config_switched(process))  # its local switches (framework/local_switch.py)
    queryable = [f"{keys.control(n)}/**" for n in sorted(names)]
    queryable += [keys.port_type(k) for k in sorted(outputs)]
    queryable.append(keys.container(process))
    queryable.append(keys.clock(process))
    token = [keys.alive(n) for n in sorted(names)]
    return {"put": put, "queryable": queryable, "token": token}


def data_keys(topology: Topology) -> list[str]:
    """Every key that carries data or fw's own status (anything but requests): what
    any member may subscribe to and ask for history (an advanced subscriber's first
    sample is a query on the key itself)."""
    roots: set[str] = set()
    exact: set[str] = set()
    for process in {c.process for c in topology.components.values()}:
        for key in process_keys(topology, process)["put"]:
            if key.startswith("fw/") and key.split("/")[1] not in FW_DATA:
                exact.add(key)
            elif key.startswith("fw/"):
                continue
            else:
                roots.add(key.split("/", 1)[0])
    return sorted(
        {f"{r}/**" for r in roots}
        | {f"{r}" for r in roots}
        | exact
        | {f"fw/{k}/**" for k in FW_DATA}
        | {"fw/events", "fw/deployer/events", keys.clock("*")}
    )


def operator_requests(topology: Topology) -> list[str]:
    """The control request keys an operator may query (nothing that changes anything)."""
    out = [f"{keys.control('*')}/{op}" for op in READ_REQUESTS]
    for name, spec in sorted(topology.components.items()):
        if spec.info is None:
            continue
        for op in sorted(spec.info.readonly):
            out.append(keys.control_request(name, "call", op))
    for op in ("offer", "active", "takeable"):
        out.append(keys.control_request("coordinator", "call", op))
    out.append(keys.container("*"))  # a container answers only `list`
    return out


def access_control(topology: Topology) -> dict[str, Any]:
    """Zenoh `access_control` settings for every session of the deployment."""
    ns = topology.bus.namespace

    def full(key_exprs: list[str]) -> list[str]:
        return [f"{ns}/{k}" for k in key_exprs]

    def rule(
        rule_id: str, messages: list[str], key_exprs: list[str], flow: str = "ingress"
    ) -> dict[str, Any]:
        # a session judges what it receives, by who sent it (ingress); what it sends is
        # judged by its receivers, so egress is free
        return {
            "id": rule_id,
            "permission": "allow",
            "flows": [flow],
            "messages": messages,
            "key_exprs": full(key_exprs),
        }

    processes = sorted({c.process for c in topology.components.values()})
    rules = [
        rule(
            "everyone reads",
            ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query", "reply"],
            ["**"],
        ),
        rule("everyone asks for data", ["query"], data_keys(topology)),
        rule("advanced publishers' caches", list(ALL_MESSAGES), ["**/@adv/**"]),
        rule("control does everything", list(ALL_MESSAGES), ["**"]),
        rule("anything may be sent", list(ALL_MESSAGES), ["**", "**/@adv/**"], "egress"),
        rule("operator asks", ["query"], operator_requests(topology)),
    ]
    subjects = [
        {"id": CONTROL, "cert_common_names": [CONTROL]},
        {"id": OPERATOR, "cert_common_names": [OPERATOR]},
    ]
    common = [
        "everyone reads",
        "everyone asks for data",
        "advanced publishers' caches",
        "anything may be sent",
    ]
    policies = [
        {"rules": [*common, "control does everything"], "subjects": [CONTROL]},
        {"rules": [*common, "operator asks"], "subjects": [OPERATOR]},
    ]
    for process in processes:
        own = process_keys(topology, process)
        rules += [
            rule(f"{process} publishes", ["put"], own["put"]),
            rule(f"{process} answers", ["declare_queryable"], own["queryable"]),
            rule(f"{process} lives", ["liveliness_token"], own["token"]),
        ]
        subjects.append({"id": f"process {process}", "cert_common_names": [process]})
        policies.append(
            {
                "rules": [
                    *common,
                    f"{process} publishes",
                    f"{process} answers",
                    f"{process} lives",
                ],
                "subjects": [f"process {process}"],
            }
        )
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }
