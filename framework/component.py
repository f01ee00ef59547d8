"""The component contract: OROCOS RTT's TaskContext in Python.

A component declares its ports, properties and operations on its class and
implements hooks; the runtime drives the lifecycle:

    class Doubler(Component):
        '''Doubles every number it reads.'''
        gain = prop(float, 2.0, min=0.0, doc="factor")
        inp = In(float, doc="numbers")
        out = Out(float, doc="doubled numbers")

        def update_hook(self) -> None:
            status, value = self.inp.read()
            if status is ReadStatus.NEW:
                self.out.write(self.gain * value)

        @operation
        def reset(self) -> str:
            return "ok"

States and allowed transitions are RTT's (table in docs/components.md). A hook
refuses by raising `ConfigureError` (or any `FwError`: a file that does not load, a
device that does not answer) with the reason, or by returning False; it then leaves
the component in the documented state with `last_error` saying why. Any other
exception is a bug in the hook: the component goes to Exception. Either way the
change is reported to every state listener (the container publishes it on the
bus): never swallowed.
"""

from __future__ import annotations

import contextlib
import inspect
import math
import threading
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum
from typing import Any

from framework.clock import Clock, MonotonicClock, late
from framework.clock_offset import OffsetEstimate
from framework.errors import FwError
from framework.ports import ConnPolicy, InputPort, OutputPort, TypeAdapter
from framework.properties import Property, PropertyError


class LifecycleError(FwError):
    """A lifecycle operation was called in a state that does not allow it."""


class ConfigureError(FwError):
    """A hook's refusal, with the reason (`raise ConfigureError("no such port")`): the
    component stays where it was (PreOperational after `configure`), `last_error` says
    why, and it may be tried again once the cause is mended."""


class OperationError(FwError):
    """An operation does not exist, got bad arguments, or failed."""


class State(Enum):
    """Component states (RTT TaskCore)."""

    INIT = "Init"
    PRE_OPERATIONAL = "PreOperational"
    STOPPED = "Stopped"
    RUNNING = "Running"
    RUNTIME_ERROR = "RunTimeError"
    EXCEPTION = "Exception"
    FATAL_ERROR = "FatalError"


ALLOWED: dict[str, tuple[State, ...]] = {
    "configure": (State.PRE_OPERATIONAL, State.STOPPED),
    "start": (State.STOPPED,),
    "stop": (State.RUNNING, State.RUNTIME_ERROR),
    "cleanup": (State.STOPPED,),
    "recover": (State.RUNTIME_ERROR, State.EXCEPTION),
    "error": (State.RUNNING,),
}
"""Which states each lifecycle operation may be called from."""


@dataclass(frozen=True)
class StateChange:
    """What state listeners receive."""

    component: str
    old: State
    new: State
    reason: str
    stamp: float


@dataclass(frozen=True)
class Refusal:
    """A sample a component refused: on which port, why, and how many it stands for."""

    component: str
    port: str
    reason: str
    count: int
    stamp: float


@dataclass(frozen=True)
class FileInput:
    """An input port a component's configuration file declares (one per tracker of a
    sensors file, one per camera of a cameras file). It is created when the component
    is hosted and wired like any other input, by the topology's `connections:`, so
    `fw validate`, `fw ls` and the Configurator see it; `fw validate` checks that each
    one is connected."""

    port: str
    type: type
    source: str  # where the file declares it, for messages: "sensors.yaml: certus"
    suggest: str = ""  # the output that usually feeds it ("certus.cto"), for hints
    policy: ConnPolicy | None = None

    @property
    def type_name(self) -> str:
        """The message type's name, as the topology's checks compare it."""
        from framework.messages import type_name

        return type_name(self.type)


class In:
    """Declare an input port on a Component class; `adapter`: the form its samples are
    read in, if not their type's (framework/ports.py `TypeAdapter`)."""

    def __init__(
        self,
        type: type,
        doc: str = "",
        policy: ConnPolicy | dict[str, Any] | None = None,
        adapter: TypeAdapter | None = None,
    ):
        self.type, self.doc, self.policy = type, doc, ConnPolicy.from_spec(policy)
        self.adapter = adapter


class Out:
    """Declare an output port on a Component class. `stream`: written every cycle of a
    fast loop, encoded only while another process reads it (framework/ports.py)."""

    def __init__(self, type: type, doc: str = "", stream: bool = False):
        self.type, self.doc, self.stream = type, doc, stream


def operation(
    fn: Callable[..., Any] | None = None,
    *,
    doc: str = "",
    exclusive: bool = True,
    readonly: bool = False,
) -> Any:
    """Mark a method as an operation, callable locally and from other processes.

    An operation runs holding the component's lock (never beside an update or another
    operation); `exclusive=False` is for one that only waits for, or reads,
    thread-safe state, so waiting does not stall the component's own activity.
    `readonly=True` declares that it changes nothing (a report, a query): the bus's
    access rules let an operator's tools call it (framework/access.py); only the
    deployment's control may call the others."""

    def mark(method: Callable[..., Any]) -> Callable[..., Any]:
        method.__fw_operation__ = doc or (inspect.getdoc(method) or "").split("\n")[0]
        method.__fw_exclusive__ = exclusive
        method.__fw_readonly__ = readonly
        return method

    return mark(fn) if fn is not None else mark


class Heartbeat:
    """A watched component's proof of life (see framework/safety.py): a sample on its
    heartbeat key at most once per `period`, written from the component's own activity
    thread and only while it is Running, so a hung thread, a dead process or a component
    that left Running all fall silent."""

    def __init__(self, port: OutputPort[Any], period: float, clock: Clock):
        self.port, self.period, self.clock = port, period, clock
        self.count = 0
        self._last = -float("inf")

    def beat(self) -> None:
        """Publish if a period has passed since the last beat."""
        now = self.clock.now()
        if now - self._last >= self.period:
            from framework.messages import Scalar

            self._last = now
            self.count += 1
            self.port.write(Scalar(time.time(), float(self.count)))


class Component:
    """Base of every fw component (see the module docstring)."""

    needs_configuration = True
    """If False, the component starts in Stopped (RTT: initial state Stopped)."""
    hosts_safety_monitor = False
    """True if the component runs a `SafetyMonitor` in its control loop (see
    framework/safety.py): a topology may then name it as its `safety: monitor:`."""
    idle_within: float | None = None
    """An event-driven component's next idle tick comes at most this long after its last
    update (s; None: the activity's `idle`): a component that knows when its inputs fall
    due (a tracker's staleness deadline) wakes then, not on a fixed beat."""
    _deferring: tuple[OutputPort[Any], ...] = ()
    """The ports `defer_outputs` deferred (none until a paced loop asks)."""
    after_cycles = False
    """True once a paced loop ran this component's `after_cycle` (it is the paced one or
    runs after it): a hook may then leave to `after_cycle_hook` what needs no answer
    within the cycle, and must take it in `update_hook` otherwise."""
    realtime = False
    """A periodic component that is a device's own clock (the simulated KRC) runs a
    device loop: its cycles timed, the collector kept out of them, and real-time
    priority for its thread as a paced loop has (framework/realtime.py), unless it is a
    `simulated_device`."""
    simulated_device = False
    """A `realtime` component that simulates a machine of its own (the KRC of the
    simulated OR): where the host gives real-time priority its loop runs SCHED_DEADLINE
    with a bounded share of each period (framework/realtime.py `SIMULATED_SHARE`), so it
    keeps real time whatever else runs, yet on a host too slow for the whole simulation
    the simulation slows down instead of taking the CPU from the system under test
    (SCHED_FIFO is the robot interface's, the PC side, as in an OR where the KRC is
    another computer); elsewhere SCHED_OTHER at its process's nice level."""
    periods_per_update = 1
    """A periodic component's next update comes this many periods later (it then does
    that many periods' work): a controller in monitor mode wakes less often than in
    command mode (RTT: an activity's period changed at run time)."""

    def __init__(self, name: str):
        if not name.isidentifier():
            raise FwError(f"component name {name!r} must be an identifier (letters, digits, _)")
        self.name = name
        self.update_stage = f"update {name}"
        """The name of this component's update among a paced loop's stages (`fw bench cost`)."""
        self._state = State.INIT
        self.last_error = ""
        self._listeners: list[Callable[[StateChange], None]] = []
        self._refusal_listeners: list[Callable[[Refusal], None]] = []
        self._refusals: dict[str, tuple[float, int]] = {}  # port -> (last said, unsaid since)
        self._lifecycle_lock = _YieldingLock()
        self.inputs: dict[str, InputPort[Any]] = {}
        self.outputs: dict[str, OutputPort[Any]] = {}
        self.declared_properties: dict[str, Property] = {}
        self._values: dict[str, Any] = {}
        self.operations: dict[str, Callable[..., Any]] = {}
        self.bus: Any = None
        """The bus of the hosting container (set when a container adds the component)."""
        self.clock: Clock = MonotonicClock()
        """The time of the hosting executor: monotonic, or a test's simulated clock."""
        self.peer_clocks: Callable[[str | None], OffsetEstimate | None] = lambda key: None
        """The measured offset of the clock that stamps a key's samples when another
        host writes it (framework/peer_clocks.py), else None: set by the container."""
        self.heartbeat: Heartbeat | None = None
        self.file_error = ""
        """Why the ports its configuration files declare could not be (see file_ports)."""
        self._awaited: dict[str, tuple[str, ConnPolicy | None]] = {}
        self._wakes: dict[str, Callable[[Any], None]] = {}
        """Set by the container when the topology watches this component."""
        self.safety: Any = None
        """The `SafetyMonitor` the container attaches if the topology names this component
        as its safety monitor (only when `hosts_safety_monitor`)."""
        self.loop_stats: Any = None
        """A real-time periodic loop's `LoopStats` (framework/realtime.py), set by the
        executor (a paced loop's are its engine's)."""
        self.engine: Any = None
        """The `ExecutionEngine` of the paced loop that runs this component (as its
        device's component or after it), set by the executor: while the loop runs, its
        exclusive operations are queued to it (framework/engine.py)."""
        for attr, _ in declarations(type(self)):
            if attr in _RESERVED:
                raise FwError(
                    f"{type(self).__name__}.{attr} shadows the component API; "
                    "rename that port, property or operation"
                )
        for attr, decl in declarations(type(self)):
            if isinstance(decl, In):
                port = InputPort(attr, decl.type, decl.doc, decl.policy, adapter=decl.adapter)
                port.owner = name
                self.inputs[attr] = port
                self.__dict__[attr] = port  # shadows the class-level declaration
            elif isinstance(decl, Out):
                port = OutputPort(attr, decl.type, decl.doc, decl.stream)
                port.owner = name
                self.outputs[attr] = port
                self.__dict__[attr] = port
            elif isinstance(decl, Property):
                self.declared_properties[attr] = decl
                self._values[attr] = decl.default
            elif callable(decl) and hasattr(decl, "__fw_operation__"):
                self.operations[attr] = getattr(self, attr)
        self._initial = State.PRE_OPERATIONAL if self.needs_configuration else State.STOPPED
        self._state = self._initial

    # -- ports and properties --------------------------------------------------------
    def port(self, name: str) -> InputPort[Any] | OutputPort[Any]:
        """A port by name; `FwError` listing the ports otherwise."""
        found = self.inputs.get(name) or self.outputs.get(name)
        if found is None:
            known = ", ".join(sorted([*self.inputs, *self.outputs])) or "none"
            raise FwError(f"component {self.name!r} has no port {name!r} (ports: {known})")
        return found

    @classmethod
    def file_inputs(cls, properties: dict[str, Any]) -> list[FileInput]:
        """The inputs this component will open from its configuration files, given its
        topology properties (none by default); FwError if a file cannot be read."""
        return []

    def file_ports(self) -> list[InputPort[Any]]:
        """The input ports the configuration files declare, given the properties now
        (`file_inputs`), in their order; a port not declared yet is created (unconnected:
        the topology's `connections:` wire it), one declared before is kept with its
        connections. FwError if a file cannot be read."""
        ports = []
        try:
            declared = type(self).file_inputs(self._values)
        except FwError as exc:
            self.file_error = str(exc)
            raise
        self.file_error = ""
        for wanted in declared:
            port = self.inputs.get(wanted.port)
            if port is None:
                port = InputPort(
                    wanted.port, wanted.type, f"declared by {wanted.source}", wanted.policy
                )
                port.owner, port.bus = self.name, self.bus
                port.on_data = self._wakes.get(wanted.port)
                self.inputs[wanted.port] = port
                awaited = self._awaited.pop(wanted.port, None)
                if awaited is not None:
                    port.connect(*awaited)
            ports.append(port)
        return ports

    def stamp_clock(self, port: str) -> OffsetEstimate | None:
        """The offset of the clock that stamps input `port`'s samples, if another host
        writes them (its interval bounds their age: `OffsetEstimate.age`); None if this
        host does (its own clock: no offset) or the port is not connected."""
        inp = self.inputs.get(port)
        return self.peer_clocks(inp.key if inp is not None else None)

    def local_stamp(self, port: str, stamp: float) -> float | None:
        """`stamp`, a sample of input `port`, on this host's wall clock: as it is when
        this host writes the port, moved by the measured offset of the host that does
        (the interval's middle: off by at most half a round trip), None while that
        host's clock is not measured yet. For pairing stamps of different hosts in
        time (a tracker's sample with the joints of its moment); ages are judged with
        `stamp_clock(port).age`, which never errs on the fresh side."""
        clock = self.stamp_clock(port)
        if clock is None:
            return stamp
        return clock.local_time(stamp, time.time())

    def wake_on(self, ports: tuple[str, ...], callback: Callable[[Any], None]) -> None:
        """Call `callback(port)` when any of these inputs receives a sample (an event
        activity's wake); a port its file declares later gets it when created."""
        for name in ports:
            self._wakes[name] = callback
            if name in self.inputs:
                self.inputs[name].on_data = callback

    def await_connection(self, port: str, key: str, policy: ConnPolicy | None = None) -> None:
        """Wire a port its file will declare once the file can be read (the topology's
        connection of a component whose file failed: `configure` says why, and connects
        it if the file is fixed)."""
        self._awaited[port] = (key, policy)

    def get_property(self, name: str) -> Any:
        """The value of a declared property."""
        self._property(name)
        return self._values[name]

    def set_property(self, name: str, value: Any) -> Any:
        """Validate and set a property; returns the stored value."""
        declared = self._property(name)
        stored = declared.validate(value, self.name)
        self._values[name] = stored
        return stored

    def set_properties(self, values: dict[str, Any]) -> None:
        """Set several properties; all are validated before any is changed."""
        checked = {k: self._property(k).validate(v, self.name) for k, v in values.items()}
        self._values.update(checked)

    def load_properties(self, path: Any) -> None:
        """Set properties from a YAML file (`name: value`); errors name file:line."""
        from framework.properties import load_property_file

        self._values.update(load_property_file(path, self.declared_properties, self.name))

    def _property(self, name: str) -> Property:
        declared = self.declared_properties.get(name)
        if declared is None:
            known = ", ".join(sorted(self.declared_properties)) or "none"
            raise PropertyError(
                f"component {self.name!r} has no property {name!r} (properties: {known})"
            )
        return declared

    # -- operations ----------------------------------------------------------------
    def call(self, operation_name: str, /, **kwargs: Any) -> Any:
        """Call an operation by name with keyword arguments (checked against its signature)."""
        return self.invoke(operation_name, kwargs)

    def invoke(
        self, operation_name: str, kwargs: dict[str, Any], deadline: float | None = None
    ) -> Any:
        """`call` for a request with a wall-clock `deadline`: refused, not run, if the
        deadline has passed by the time the component's lock is free."""
        method = self.operations.get(operation_name)
        if method is None:
            known = ", ".join(sorted(self.operations)) or "none"
            raise OperationError(
                f"component {self.name!r} has no operation {operation_name!r} (operations: {known})"
            )
        try:
            inspect.signature(method).bind(**kwargs)
        except TypeError as exc:
            raise OperationError(f"{self.name}.{operation_name}: {exc}") from None
        exclusive = getattr(method, "__fw_exclusive__", True)
        engine = self.engine
        if exclusive and engine is not None and engine.running and not engine.in_loop():
            # the paced loop runs it between cycles: nobody takes its lock mid-cycle
            return engine.call(
                lambda: self._run_operation(operation_name, method, kwargs, deadline)
            )
        with self._lifecycle_lock if exclusive else contextlib.nullcontext():
            return self._run_operation(operation_name, method, kwargs, deadline)

    def _run_operation(
        self,
        operation_name: str,
        method: Callable[..., Any],
        kwargs: dict[str, Any],
        deadline: float | None,
    ) -> Any:
        """Run an operation now: refused if its deadline has passed (checked when it is
        its turn, not when it was asked for), its failure an `OperationError`."""
        overdue = late(deadline)
        if overdue:
            raise OperationError(f"{self.name}.{operation_name}: {overdue}")
        try:
            return method(**kwargs)
        except FwError:
            raise
        except Exception as exc:  # the user's operation: any error is the caller's answer
            raise OperationError(
                f"{self.name}.{operation_name} failed: {type(exc).__name__}: {exc}"
            ) from exc

    # -- lifecycle -----------------------------------------------------------------
    @property
    def state(self) -> State:
        """The current lifecycle state."""
        return self._state

    def add_state_listener(self, listener: Callable[[StateChange], None]) -> None:
        """Be told of every state change (the container publishes them)."""
        self._listeners.append(listener)

    def add_refusal_listener(self, listener: Callable[[Refusal], None]) -> None:
        """Be told of refused samples (the container publishes them)."""
        self._refusal_listeners.append(listener)

    REFUSAL_PERIOD = 1.0
    """s: a port's refusals are said at most this often (the others are counted)."""

    def refuse(self, port: str, reason: str) -> None:
        """Say that a sample read on `port` was refused, and why: a value no correct
        producer sends (beyond the procedure's limits, a jump no arm can make). The
        container publishes it on `fw/refused/<component>` and the flight recorder
        keeps it. A flood is said once per `REFUSAL_PERIOD`, with how many it stood for."""
        now = self.clock.now()
        last, unsaid = self._refusals.get(port, (-math.inf, 0))
        if now - last < self.REFUSAL_PERIOD:
            self._refusals[port] = (last, unsaid + 1)
            return
        self._refusals[port] = (now, 0)
        refusal = Refusal(self.name, port, reason, unsaid + 1, time.time())
        for listener in list(self._refusal_listeners):
            try:
                listener(refusal)
            except Exception:  # a broken listener must not break the component
                traceback.print_exc()

    def _set_state(self, new: State, reason: str = "") -> None:
        old, self._state = self._state, new
        if reason:
            self.last_error = reason
        if old is new and not reason:
            return
        change = StateChange(self.name, old, new, reason, time.time())
        for listener in list(self._listeners):
            try:
                listener(change)
            except Exception:  # a broken listener must not break the lifecycle
                traceback.print_exc()

    def _check(self, op: str) -> None:
        if self._state not in ALLOWED[op]:
            allowed = ", ".join(s.value for s in ALLOWED[op])
            raise LifecycleError(
                f"cannot {op} {self.name!r} in state {self._state.value} (allowed from: {allowed})"
            )

    def _run_hook(self, hook: str) -> tuple[bool, str]:
        """(True, '') if the hook succeeded; (False, why) if it returned False; raises on error."""
        self.last_error = ""
        if hook == "configure_hook":
            empty = [n for n, d in self.declared_properties.items() if d.missing(self._values[n])]
            if empty:
                return False, "required " + ", ".join(
                    f"property {n} is empty ({self.declared_properties[n].doc or 'no doc'})"
                    for n in empty
                )
        try:
            result = getattr(self, hook)()
        except FwError as exc:  # a refusal, with its reason (`ConfigureError`)
            return False, str(exc) or f"{hook} refused"
        if result is False:  # keep the reason the hook gave, if it set one
            return False, self.last_error or f"{hook} returned False"
        return True, ""

    def _guarded(self, op: str, hook: str, success: State, failure: State) -> bool:
        with self._lifecycle_lock:
            self._check(op)
            try:
                ok, why = self._run_hook(hook)
            except Exception as exc:  # a hook's error of any kind: Exception, as RTT does
                self.exception(f"{hook} raised {type(exc).__name__}: {exc}")
                return False
            if ok:
                self.last_error = ""
                self._set_state(success)
            else:
                self._set_state(failure, why)
            return ok

    def configure(self) -> bool:
        """PreOperational/Stopped -> Stopped if configure_hook succeeds."""
        return self._guarded("configure", "configure_hook", State.STOPPED, self._state)

    def start(self) -> bool:
        """Stopped -> Running if start_hook succeeds."""
        return self._guarded("start", "start_hook", State.RUNNING, State.STOPPED)

    def stop(self) -> bool:
        """Running/RunTimeError -> Stopped (stop_hook)."""
        return self._guarded("stop", "stop_hook", State.STOPPED, State.STOPPED)

    def cleanup(self) -> bool:
        """Stopped -> PreOperational (cleanup_hook)."""
        return self._guarded("cleanup", "cleanup_hook", State.PRE_OPERATIONAL, State.STOPPED)

    def recover(self) -> bool:
        """RunTimeError -> Running; Exception -> the initial state."""
        with self._lifecycle_lock:
            self._check("recover")
            self.last_error = ""
            self._set_state(State.RUNNING if self._state is State.RUNTIME_ERROR else self._initial)
            return True

    def error(self, reason: str = "error() called") -> None:
        """Called by the component itself: Running -> RunTimeError (error_hook runs instead
        of update_hook until recover())."""
        with self._lifecycle_lock:
            self._check("error")
            self._set_state(State.RUNTIME_ERROR, reason)

    def exception(self, reason: str) -> None:
        """Go to Exception: stop_hook if running, cleanup_hook, then exception_hook; any of
        them failing means FatalError."""
        with self._lifecycle_lock:
            was = self._state
            if was in (State.EXCEPTION, State.FATAL_ERROR):  # already there: nothing to undo
                self.last_error = reason
                return
            try:
                if was in (State.RUNNING, State.RUNTIME_ERROR):
                    self.stop_hook()
                if (
                    was in (State.STOPPED, State.RUNNING, State.RUNTIME_ERROR)
                    and self._initial is State.PRE_OPERATIONAL
                ):
                    self.cleanup_hook()
                self.exception_hook()
            except Exception as exc:  # failing while making safe: FatalError, with both reasons
                self._set_state(
                    State.FATAL_ERROR,
                    f"{reason}; then {type(exc).__name__} while handling it: {exc}",
                )
                return
            self._set_state(State.EXCEPTION, reason)

    def fatal(self, reason: str) -> None:
        """Unrecoverable: FatalError (the process should be restarted)."""
        with self._lifecycle_lock:
            self._set_state(State.FATAL_ERROR, reason)

    def update(self) -> None:
        """One activity cycle: update_hook when Running, error_hook in RunTimeError."""
        self._lifecycle_lock.let_waiters_in()
        with self._lifecycle_lock:
            state = self._state
            if state is not State.RUNNING and state is not State.RUNTIME_ERROR:
                return
            hook = "update_hook" if state is State.RUNNING else "error_hook"
            try:
                getattr(self, hook)()
            except Exception as exc:  # a cycle's error of any kind: Exception (made safe)
                self.exception(f"{hook} raised {type(exc).__name__}: {exc}")
                return
            if self.heartbeat is not None and self._state is State.RUNNING:
                self.heartbeat.beat()

    def stage(self, name: str, seconds: float) -> None:
        """Say that a stage of this cycle (safety, separation, IK...) took `seconds`:
        kept in the paced loop's statistics (`fw bench cost`), nothing otherwise."""
        engine = self.engine
        stats = engine.loop if engine is not None else self.loop_stats
        if stats is not None:
            stats.stage(name, seconds)

    def read_cycle(self, timeout: float) -> bool:
        """A paced activity's wait for the device's next cycle (`read_hook`), outside the
        component's lock (a stop may close the device meanwhile): True if one came; False
        when it timed out, the component is not Running, or the hook failed (then it
        goes to Exception)."""
        if self._state is not State.RUNNING:
            return False
        try:
            return bool(self.read_hook(timeout))
        except Exception as exc:  # a device read's error of any kind: Exception (made safe)
            if self._state is State.RUNNING:
                self.exception(f"read_hook raised {type(exc).__name__}: {exc}")
            return False

    def write_cycle(self) -> None:
        """A paced activity's end of cycle (`write_hook`), after `update` and the
        components that run after this one."""
        with self._lifecycle_lock:
            if self._state is not State.RUNNING and self._state is not State.RUNTIME_ERROR:
                return
            try:
                self.write_hook()
            except Exception as exc:  # a device write's error of any kind: Exception
                self.exception(f"write_hook raised {type(exc).__name__}: {exc}")

    def after_cycle(self) -> None:
        """A paced loop's time after a cycle's command went out (this component is the
        paced one or runs after it): `after_cycle_hook` while Running, then what its
        ports deferred is sent (`defer_outputs`). Work here delays no answer to the
        device, only the next cycle if it overran the time before it (`fw bench cost`
        times it apart from the cycles)."""
        self.after_cycles = True
        with self._lifecycle_lock:
            if self._state is State.RUNNING:
                try:
                    self.after_cycle_hook()
                except Exception as exc:  # a hook's error of any kind: Exception (made safe)
                    self.exception(f"after_cycle_hook raised {type(exc).__name__}: {exc}")
        self.flush_outputs()

    def defer_outputs(self) -> None:
        """Send this component's samples to other processes at `flush_outputs`, not
        inside each write (framework/ports.py: `OutputPort.defer`); its heartbeat too.
        Called by a paced loop, before its first cycle, for the components it runs."""
        beat = [self.heartbeat.port] if self.heartbeat is not None else []
        self._deferring = (*self.outputs.values(), *beat)  # asked after every cycle: made once
        for port in self._deferring:
            port.defer()

    def undefer_outputs(self) -> None:
        """Its loop ended: send what is still deferred, and from now on inside each write
        (a stop_hook run later by another thread must not leave its samples queued)."""
        ports, self._deferring = self._deferring, ()
        for port in ports:
            try:
                port.undefer()
            except Exception as exc:  # what its write would have raised: made safe
                self.exception(f"{port.full_name}: {type(exc).__name__}: {exc}")

    def flush_outputs(self) -> None:
        """Send what this component's ports deferred (in the loop's thread). A sample
        that cannot be encoded is the component's error, as in the write that made it:
        it goes to Exception."""
        for port in self._deferring:
            if port._deferred:
                try:
                    port.flush()
                except Exception as exc:  # what its write would have raised: made safe
                    self.exception(f"{port.full_name}: {type(exc).__name__}: {exc}")

    def idle(self) -> None:
        """Called by an event-driven activity when no data came for a while: `idle_hook`
        runs, and a watched component still proves it runs (its thread is alive and it
        is not blocked)."""
        with self._lifecycle_lock:
            if self._state is not State.RUNNING:
                return
            try:
                self.idle_hook()
            except Exception as exc:  # an idle tick's error of any kind: Exception (made safe)
                self.exception(f"idle_hook raised {type(exc).__name__}: {exc}")
                return
            if self.heartbeat is not None:
                self.heartbeat.beat()

    # -- hooks (override) -----------------------------------------------------------
    # Every hook runs under the component's lifecycle lock, so no two of them (nor an
    # exclusive operation) ever run at once; read_hook alone runs outside it. Lifecycle
    # hooks run in the thread that asked for the transition: the container's control
    # request (a Zenoh query thread), its startup (the process's main thread) or a local
    # switch. Cycle hooks run in the activity's thread. A hook that raises sends the
    # component to Exception (stop_hook, cleanup_hook, exception_hook run; any of them
    # failing is FatalError); a refusal (`False`, or FwError for a reason) is no error.

    def configure_hook(self) -> bool | None:
        """PreOperational or Stopped -> Stopped: read the properties, open devices and
        files, build what the cycles need (never in a cycle). Runs in the thread that
        asked (a control request, the container's startup), under the lifecycle lock.
        Return False (with `last_error` set) or raise FwError to refuse: the component
        stays where it was and the reason goes to whoever asked. May be called again
        after `cleanup`, so it must set every member a cycle reads."""
        return True

    def start_hook(self) -> bool | None:
        """Stopped -> Running, just before the first cycle: reset per-run state. Runs in
        the thread that asked, under the lifecycle lock; False or FwError refuses (the
        component stays Stopped)."""
        return True

    def update_hook(self) -> None:
        """One cycle of work while Running: read inputs, compute, write outputs. Runs in
        the activity's thread (periodic, event-driven, or the paced loop between its
        read_hook and write_hook), under the lifecycle lock, never beside another hook
        or an exclusive operation. Must not block (a paced loop has a 1 ms budget). An
        exception sends the component to Exception; `error()` instead goes to
        RunTimeError, where error_hook runs in its place."""

    def error_hook(self) -> None:
        """Runs instead of update_hook while in RunTimeError (after the component called
        `error()`), in the activity's thread, under the lifecycle lock, until
        `recover()`. Keep outputs safe; an exception sends the component to Exception."""

    def idle_hook(self) -> None:
        """An event-driven activity's input was silent for its `idle` period (a paced
        one's device, for its `idle`): check deadlines, say what is stale. Runs in the
        activity's thread, under the lifecycle lock, while Running; an exception sends
        the component to Exception."""

    def read_hook(self, timeout: float) -> bool:
        """Paced activity only, in the loop's thread, first in every cycle and outside the
        component's lock: wait (at most `timeout` s) for the device's next cycle and take
        its data; True if it came. The device is the clock (the KRC's measurement). It
        may touch only what update_hook reads of the device (a stop may close the
        device meanwhile: return False then); an exception sends the component to
        Exception."""
        raise FwError(f"{type(self).__name__} has no read_hook: it cannot be paced")

    def write_hook(self) -> None:
        """Paced activity only, in the loop's thread, last in every cycle (after
        update_hook and every component that runs after this one), under the lifecycle
        lock: send the cycle's answer to the device. An exception sends the component to
        Exception."""

    def after_cycle_hook(self) -> None:
        """Paced activity only (the paced component and those that run after it), in the
        loop's thread after the cycle's command went out, under the lifecycle lock, while
        Running: work that needs no answer in this cycle (a goal to steer toward, news
        to publish), so the time from measurement to command stays short. Runs once per
        cycle, before the next one's read; an exception sends the component to
        Exception."""

    def stop_hook(self) -> None:
        """Running or RunTimeError -> Stopped, and first on the way to Exception: make
        outputs safe (brake, hold, tell the device). Runs in the thread that asked (a
        control request, the container's shutdown, an exception in a cycle hook), under
        the lifecycle lock, after the last cycle. It must not fail: an exception here on
        the way to Exception is FatalError."""

    def cleanup_hook(self) -> None:
        """Stopped -> PreOperational, and on the way to Exception: release what
        configure_hook acquired (sockets, files, devices). Runs in the thread that
        asked, under the lifecycle lock; an exception on the way to Exception is
        FatalError."""

    def exception_hook(self) -> None:
        """Entering Exception, after stop_hook and cleanup_hook: last chance to make
        things safe. Runs in the thread whose hook failed (a cycle's, or the one that
        asked), under the lifecycle lock; an exception here is FatalError."""

    # -- introspection ----------------------------------------------------------------
    def holds_bus(self) -> str:
        """Why no process of the deployment may reopen its bus now ('' if it may): the
        route watch (framework/routes.py) asks before it reopens, says it in its probes,
        and every process's watch waits while any says why. A device loop says so while
        it commands its device: a reopen costs its process a moment of interpreter time
        (a new session, every subscription made again), which makes the loop's answers,
        or another process's heartbeat it watches, late. Runs in the route watch's
        thread: read plain attributes, take no lock the loop takes."""
        return ""

    def describe(self) -> dict[str, Any]:
        """Plain data: class, state, ports, properties, operations (for `fw ls`)."""
        return {
            "name": self.name,
            "class": class_path(type(self)),
            "doc": (inspect.getdoc(type(self)) or "").split("\n")[0],
            "state": self._state.value,
            "last_error": self.last_error,
            "inputs": [
                {
                    "name": p.name,
                    "type": p.type_name,
                    "doc": p.doc,
                    "key": p.key,
                    "policy": p.policy.to_dict(),
                    "stats": p.stats.to_dict(),
                }
                for p in self.inputs.values()
            ],
            "outputs": [
                {
                    "name": p.name,
                    "type": p.type_name,
                    "doc": p.doc,
                    "keys": p.keys,
                    "stats": p.stats.to_dict(),
                }
                for p in self.outputs.values()
            ],
            "properties": [
                d.describe(self._values[n]) for n, d in self.declared_properties.items()
            ],
            "operations": [
                {
                    "name": n,
                    "doc": m.__fw_operation__,
                    "args": list(inspect.signature(m).parameters),
                    "readonly": bool(getattr(m, "__fw_readonly__", False)),
                }
                for n, m in self.operations.items()
            ],
        }


def _reserved_names() -> frozenset[str]:
    names = {n for n in vars(Component) if not n.startswith("__")}
    return frozenset(
        names
        | {"name", "inputs", "outputs", "operations", "last_error", "declared_properties"}
        | {"bus", "clock", "heartbeat", "safety"}
    )


def class_path(cls: type) -> str:
    """`package.module:Class`, as topologies name a component class."""
    return f"{cls.__module__}:{cls.__qualname__}"


def declarations(cls: type) -> list[tuple[str, Any]]:
    """Declared ports, properties and operations of a class, base classes first."""
    seen: dict[str, Any] = {}
    for klass in reversed(cls.__mro__):
        for attr, value in vars(klass).items():
            if isinstance(value, (In, Out, Property)) or hasattr(value, "__fw_operation__"):
                seen[attr] = value
    return list(seen.items())


_RESERVED = _reserved_names()


class _YieldingLock:
    """The component's re-entrant lock, which a busy activity lets others take.

    A component updated at 1 kHz re-acquires its lock as soon as it releases it, and
    Python locks are not fair: an operation or lifecycle request from another thread
    could wait for seconds. `let_waiters_in` (called before each update) steps aside
    while anyone is waiting, so requests are served within one update."""

    def __init__(self) -> None:
        self._lifecycle_lock = threading.RLock()
        self._waiting = 0

    def __enter__(self) -> _YieldingLock:
        self._waiting += 1
        self._lifecycle_lock.acquire()
        self._waiting -= 1
        return self

    def __exit__(self, *exc: object) -> None:
        self._lifecycle_lock.release()

    def let_waiters_in(self) -> None:
        """Wait (briefly, repeatedly) while other threads wait for the lock."""
        for _ in range(1000):
            if not self._waiting:
                return
            time.sleep(0.0001)
