"""Motor node: `tactile/motors` intensities -> PWM duty frames on the glove's CAN bus.

Subscribes `tactile/motors` and `safety/stop`, publishes `motors/status`. The logic lives in
touch4d.boards (driver: what to send; link: python-can without exceptions); this node wires it to
topics and timers. Parameters: `glove` (file, default config/glove.yaml), `interface` and
`channel` (override the glove's `can:`), `emulate` (run the board emulator on the same bus in
this process), `board_emulator` (which: `python`, the reference, or `firmware`, the boards' C
core built for this machine), `status_hz` (motors/status rate), `trace` (publish `motors/trace`,
below).

Fail safe: whatever breaks, the motors end off. The broker's death turns them off at the next
refresh tick (its connection closes; counted as `broker_lost`). A process stalled between deciding
a tick's duties and sending them (SIGSTOP, swapping) decides them again before they go out
(`stalled`), so a command fresh when it arrived is not sent seconds later. A command's age is taken from its own
`source_stamp` (the hand pose it came from), so one delayed by a stall anywhere upstream never
turns a motor on: older than the glove's `can.command_max_age_s` (default `watchdog_s`) it counts
as `stale_command` and turns every motor off. This assumes the clocks of the machines in the
chain (tracking PC, motor Pi) are NTP-synchronised; set `command_max_age_s: 0` when they are not.
A `safety/stop` is momentary by default: commands resume `can.stop_hold_s` (1 s) after it;
`stop_hold_s: .inf` latches it until the node restarts. Every refresh tick sends, whatever the
receive side raised, and shutdown always sends NMT STOP and zero duty.
While every motor is off and the boards have been sent so, the refresh slows to the glove's
`can.idle_refresh_hz` (an idle node costs little); a command goes out at once and speeds it up.
A running study gates the motors (`study/trial`, touch4d.study.gate): in a visual trial, between
trials and after the end every duty is 0; the last gate holds if the study node dies, and
`study_gate: closed` keeps a motor node (re)started mid-study off until the study's next message.
The stale command, the watchdog, the stop hold and the gate are one rule set, the driver's `guard`
(touch4d.hapticoutput.OutputGuard, the one every haptic output obeys).

Trace (for latency benchmarks): a command is traced once every board's last accepted frame carries
its duties, with the wall-clock time the python-can `send` of the last such frame returned (the
virtual bus has then delivered it). A command rate-limited by the driver waits for the frame (or
refresh) that carries it; one replaced by a newer command before that is counted in the heartbeat
stat `trace_superseded`; one whose duties were already on the bus needs no frame and is counted in
`trace_unchanged` instead of being traced.
"""
from __future__ import annotations

import dataclasses
import time

import numpy as np
import zmq

from touch4d.bus import Node, Param
from touch4d.bus.broker import BrokerWatch
from touch4d.boards.busload import check_bus_load
from touch4d.boards.config import load_glove_can
from touch4d.boards.driver import MotorDriver, Outgoing
from touch4d.boards.emulator import EMULATORS, make_glove_emulator
from touch4d.boards.link import CAN_ERR_BUSOFF, CanLink
from touch4d.boards.protocol import FrameError, GloveProtocol
from touch4d.messages import MotorCommand, MotorStatus, MotorTrace, Stop, StudyTrial
from touch4d.study.gate import GATE_START, StudyGate

WARN_PERIOD_S = 5.0  # a repeating fault is logged at most this often (it is always counted)
TRACE_PERIOD_S = 0.05  # motors/trace batches


class MotorsNode(Node):
    """Drives the glove's motor boards over CAN."""

    default_name = "motors"
    PARAMS = {
        "glove": Param("config/glove.yaml", "the glove file", path="glove file"),
        "interface": Param("", "python-can interface, overriding the glove's can.interface"),
        "channel": Param("", "CAN channel, overriding the glove's can.channel"),
        "emulate": Param(False, "run the board emulator on the same bus, in this process"),
        "board_emulator": Param("python", "which board emulator runs with emulate", choices=tuple(sorted(EMULATORS))),
        "status_hz": Param(10.0, "motors/status messages per second", unit="Hz", above=0),
        "trace": Param(False, "publish motors/trace (when each command's frames were sent)"),
        "study_gate": Param("open", "before any study/trial: open (no study), closed (a study runs)",
                            choices=GATE_START),
    }

    # A python-can bus to use instead of opening the glove's channel (tests: set it between
    # `MotorsNode(..., start=False)` and `start()`, or on a subclass).
    can_bus_factory = None

    def setup(self) -> None:
        p = self.params
        self.emulator = None
        self._trace_pending: float | None = None   # source_stamp of the command whose duties are not all sent
        self._trace_stamps: list[float] = []
        self._trace_times: list[float] = []
        self._last_sent_at = 0.0                  # wall clock when the last accepted duty frame's send returned
        self._last_command: MotorCommand | None = None
        self.tracing = p["trace"]
        cfg = load_glove_can(p["glove"] or None)
        cfg = dataclasses.replace(cfg, interface=p["interface"] or cfg.interface, channel=p["channel"] or cfg.channel)
        self.cfg = cfg
        self.load = check_bus_load(cfg)
        self.protocol = GloveProtocol(cfg)
        self.driver = MotorDriver(cfg, self.protocol, now=time.monotonic())
        # Frames decided longer ago than this are decided again before they go out (see _send_frames).
        self._stall_s = 0.5 * cfg.watchdog_s
        if p["emulate"]:
            self.emulator = make_glove_emulator(p["board_emulator"], cfg).start()
            self.add_cleanup(self.emulator.stop)
        self.link = CanLink(cfg.interface, cfg.channel, cfg.bitrate, cfg.send_timeout_s,
                            bus=self.can_bus_factory() if self.can_bus_factory else None)
        self.add_cleanup(self.link.close)
        fault = self.link.ensure_open()
        if fault:
            self.driver.errors[fault] += 1
            self.log.error("CAN: %s; retrying", self.link.last_error)
        self._can_bus_off = False
        self.status_pub = self.create_publisher("motors/status", MotorStatus)
        self.create_subscription("tactile/motors", MotorCommand, self.on_command, latest_only=True)
        self.create_subscription("safety/stop", Stop, self.on_stop, optional=True)
        # The broker's death is seen at once (its connection closes): every motor off then, rather
        # than a watchdog period after the last command that got through.
        self.broker_watch = BrokerWatch(self.bus, grace=0.0, context=zmq.Context.instance())   # the node's
        self.add_cleanup(self.broker_watch.close)
        self._broker_down = False
        self.gate = StudyGate(p["study_gate"])
        self.driver.gate(self.gate.motors, time.monotonic())   # the driver's guard holds every duty at 0 while closed
        self.create_subscription("study/trial", StudyTrial, self.on_trial, optional=True)
        self.refresh_timer = self.create_timer(self.driver.refresh_period(time.monotonic()), self.on_refresh)
        self.create_timer(1.0 / p["status_hz"], self.publish_status)
        if self.tracing:
            for name in ("trace_traced", "trace_unchanged", "trace_superseded"):
                self.count(name, 0)   # in the heartbeat from the start, 0 until it happens
            self.trace_pub = self.create_publisher("motors/trace", MotorTrace)
            self.create_timer(TRACE_PERIOD_S, self.publish_trace)
        self.log.info("%d motors on %d boards, %s channel %s at %d bit/s; bus load %.1f %% worst case%s",
                      len(cfg.motor_names), len(cfg.boards), cfg.interface, cfg.channel, cfg.bitrate,
                      100 * self.load.fraction, f" ({p['board_emulator']} emulated boards)" if self.emulator else "")

    def on_command(self, msg: MotorCommand) -> None:
        self._last_command = msg
        now = time.monotonic()
        age = time.time() - msg.source_stamp   # wall clocks: NTP-synchronised across machines (see above)
        errors = self.driver.errors
        stale, future = errors["stale_command"], errors["command_from_future"]
        self.driver.command(msg.names, msg.intensity, now, age=age)   # the gate is the driver's guard's
        if errors["stale_command"] != stale:
            self._can_warn("stale_command", f"a tactile/motors command {age:.3f} s old (limit "
                                            f"{self.cfg.command_max_age_s} s): every motor off")
        elif errors["command_from_future"] != future:
            self._can_warn("command_from_future", f"a tactile/motors command stamped {-age:.3f} s in the future: "
                                                  "are the clocks NTP-synchronised?")
        if not self.tracing:
            self._send_frames(self.driver.outgoing(now), now)
            self._pace(now)
            return
        if self._trace_pending is not None:
            self.count("trace_superseded")
        self._trace_pending = None
        outs = self.driver.outgoing(now)
        if not outs and self.driver.duties_on_bus():
            self.count("trace_unchanged")
            return
        self._trace_pending = msg.source_stamp
        self._send_frames(outs, now)
        self._pace(now)

    def on_stop(self, msg: Stop) -> None:
        now = time.monotonic()
        self.log.warning("stop from %s: %s", msg.origin or "?", msg.reason or "-")
        if self._trace_pending is not None:
            self.count("trace_superseded")   # a stop replaces it with zero duties
            self._trace_pending = None
        self._stop_all(now)
        self.publish_status()

    def on_trial(self, msg: StudyTrial) -> None:
        """Follow the study's gate at once: when it closes every motor goes off now, when it opens the
        latest command (if still fresh) goes out now, not at the next one."""
        if not self.gate.update(msg):
            return
        now = time.monotonic()
        self.driver.gate(self.gate.motors, now)
        if self.gate.motors:
            last = self._last_command
            if last is not None and not self.driver.is_stale(time.time() - last.source_stamp):
                self.on_command(last)
            return
        self._send_frames(self.driver.outgoing(now), now)
        self._pace(now)

    def _stop_all(self, now: float) -> None:
        """NMT STOP first (highest priority frame), then zero duty to every board."""
        stop = self.driver.stop(now)
        self._send_frames([Outgoing(0, stop)], now)
        self._send_frames(self.driver.outgoing(now, refresh=True, force=True), now)
        self._pace(now)

    def _pace(self, now: float) -> None:
        """Refresh at refresh_hz, or at idle_refresh_hz while every motor is off and sent."""
        period = self.driver.refresh_period(now)
        if period != self.refresh_timer.period:
            self.set_timer_period(self.refresh_timer, period)

    def on_refresh(self) -> None:
        now = time.monotonic()
        down = self.broker_watch.lost(now) is not None
        if down and not self._broker_down:
            self.driver.silence(now)
            self._can_fault("broker_lost", f"the broker at {self.broker_watch.endpoint} went away: every motor off")
        self._broker_down = down
        try:
            self._receive_frames(now)
            for event in self.driver.check_boards(now):
                self.log.warning("%s", event) if "not answering" in event else self.log.info("%s", event)
        except Exception as exc:  # noqa: BLE001 - fail safe: the tick's frames (and watchdog) must go out
            self._can_fault("receive_error", f"{type(exc).__name__}: {exc}")
        self._send_frames(self.driver.outgoing(now, refresh=True), now)
        self._pace(now)

    def _receive_frames(self, now: float) -> None:
        msgs, fault = self.link.receive()
        if fault:
            self._can_fault(fault)
        for m in msgs:
            if m.is_error_frame:
                self.driver.errors["error_frames"] += 1
                if m.arbitration_id & CAN_ERR_BUSOFF:
                    self._can_fault("bus_off")
                continue
            try:
                frame = self.protocol.decode(m)
            except FrameError as exc:
                self._can_fault("malformed_rx", str(exc))
                continue
            self.driver.receive(m, frame, now)
        bus_off = self.link.bus_state_fault() == "bus_off"
        if bus_off and not self._can_bus_off:
            self._can_fault("bus_off")
        self._can_bus_off = bus_off

    def _send_frames(self, outs: list[Outgoing], now: float) -> None:
        duty_sent = False
        for out in outs:
            if out.board != 0 and time.monotonic() - now > self._stall_s:
                # This process stalled (SIGSTOP, swapping, a debugger) between deciding these duties
                # at `now` and sending them: the command they carry may be long stale. Decide again.
                self._decide_again()
                break
            fault = self.link.send(out.msg)
            if fault is None:
                duty_sent = duty_sent or out.board != 0
                self.driver.sent(out, now)
            else:
                self.driver.failed(out, fault)
                self._can_warn(fault, self.link.last_error)
            if out.board != 0 and time.monotonic() - now > self._stall_s:
                # ... or in the instant before the frame left: correct it at once.
                self._decide_again()
                break
        if duty_sent and self.tracing:
            self._last_sent_at = time.time()   # just after the last accepted duty frame's send returned
        if self._trace_pending is not None and outs and self.driver.duties_on_bus():
            self._trace_stamps.append(self._trace_pending)
            self._trace_times.append(self._last_sent_at)
            self.count("trace_traced")
            self._trace_pending = None

    def _decide_again(self) -> None:
        """Every board's duties decided afresh and sent now (after a stall of this process)."""
        self.driver.errors["stalled"] += 1
        now = time.monotonic()
        self._send_frames(self.driver.outgoing(now, refresh=True, force=True), now)

    def publish_trace(self) -> None:
        """The commands traced since the last batch, on motors/trace."""
        if self._trace_stamps:
            self.trace_pub.publish(MotorTrace(source_stamps=np.array(self._trace_stamps),
                                              frame_times=np.array(self._trace_times)))
            self._trace_stamps, self._trace_times = [], []

    def _can_fault(self, kind: str, detail: str | None = None) -> None:
        self.driver.errors[kind] += 1
        self._can_warn(kind, detail)

    def _can_warn(self, kind: str, detail: str | None) -> None:
        self.warn_once(("can", kind), f"CAN {kind} ({self.driver.errors[kind]} so far): {detail or '-'}",
                       every=WARN_PERIOD_S)

    def status(self) -> MotorStatus:
        errors = {k: int(v) for k, v in self.driver.errors.items()}
        return MotorStatus(boards=self.driver.board_report(), duty=self.driver.sent_duty(),
                           bus_load=float(self.load.fraction), errors=errors)

    def publish_status(self) -> None:
        self.status_pub.publish(self.status())

    def on_shutdown(self) -> None:
        """NMT STOP and zero duty before the link closes (the cleanups close it, then the emulator)."""
        self._stop_all(time.monotonic())
        self.publish_status()


if __name__ == "__main__":   # python -m touch4d.nodes.NAME: run it, as `touch4d node run NAME` does
    from touch4d.bus.process import main_for_module

    main_for_module(__spec__.name)
