"""The controller's python-can connection: sends and receives without ever raising.

Every failure is classified ('tx_queue_full', 'bus_off', 'send_error', 'receive_error',
'bus_closed', 'open_failed') and returned, so the motor node can report and retry it. Any
exception counts, not only `can.CanError`: a driver's OSError or ValueError, or an AttributeError
from a bus closed under us, must not skip the motor node's stop and zero frames (fail safe). A
bus that is closed, cannot be opened or keeps failing with bus-off is reopened, at most every
`REOPEN_PERIOD_S`.
"""
from __future__ import annotations

import errno
import logging
import time

import can

log = logging.getLogger("touch4d.boards.link")

REOPEN_PERIOD_S = 0.5
BUS_OFF_REOPEN_AFTER = 20  # consecutive bus-off failures before the bus is closed and reopened
CAN_ERR_BUSOFF = 0x40       # SocketCAN error frame class: bus off


def classify(exc: Exception) -> str:
    """The fault name of a python-can send error."""
    code = getattr(exc, "error_code", None) or getattr(exc, "errno", None)
    text = str(exc).lower()
    if code in (errno.ENOBUFS, errno.EAGAIN) or "buffer full" in text or "one or more recipients" in text:
        return "tx_queue_full"  # SocketCAN's ENOBUFS, select timeout; a virtual receiver's full queue
    if code in (errno.ENETDOWN, errno.ENETUNREACH) or "bus off" in text or "bus-off" in text:
        return "bus_off"
    if "closed" in text:
        return "bus_closed"
    return "send_error"


class CanLink:
    """One python-can bus, opened on demand and reopened after it fails."""

    def __init__(self, interface: str, channel: str, bitrate: int, send_timeout: float = 0.002,
                 bus: can.BusABC | None = None, clock=time.monotonic, **bus_kwargs):
        self.interface, self.channel, self.bitrate = interface, channel, bitrate
        self.send_timeout = send_timeout
        self.bus_kwargs = bus_kwargs
        self.clock = clock
        self.bus = bus
        self._last_open_try = -float("inf")
        self._bus_off_run = 0
        self.last_error: str | None = None
        self._logged_causes: set[str] = set()

    def ensure_open(self) -> str | None:
        """Open the bus if needed; None when open, else the fault name."""
        if self.bus is not None:
            return None
        now = self.clock()
        if now - self._last_open_try < REOPEN_PERIOD_S:
            return "bus_closed"
        self._last_open_try = now
        try:
            self.bus = can.Bus(interface=self.interface, channel=self.channel, bitrate=self.bitrate,
                               **self.bus_kwargs)
        except Exception as exc:  # noqa: BLE001 - any driver failure: report and retry later
            self.last_error = f"cannot open {self.interface} channel {self.channel}: {exc}"
            return "open_failed"
        self._bus_off_run = 0
        return None

    def send(self, msg: can.Message) -> str | None:
        """Send one frame; None on success, else the fault name."""
        if self.bus is None:
            fault = self.ensure_open()
            if fault:
                return fault
        try:
            self.bus.send(msg, timeout=self.send_timeout)
        except can.CanError as exc:
            fault = classify(exc)
            self.last_error = str(exc)
            self._note(fault)
            return fault
        except Exception as exc:  # noqa: BLE001 - fail safe: the caller's stop path must go on
            self._unexpected("send", exc)
            self._note("send_error")
            return "send_error"
        self._bus_off_run = 0
        return None

    def _unexpected(self, what: str, exc: Exception) -> None:
        """An exception python-can does not document: kept as last_error, logged once per cause."""
        self.last_error = f"{type(exc).__name__}: {exc}"
        cause = f"{what}:{type(exc).__name__}"
        if cause not in self._logged_causes:
            self._logged_causes.add(cause)
            log.warning("unexpected %s from %s on %s %s (counted, further ones not logged)",
                        type(exc).__name__, what, self.interface, self.channel, exc_info=exc)

    def _note(self, fault: str) -> None:
        if fault == "bus_off":
            self._bus_off_run += 1
        if fault == "bus_closed" or self._bus_off_run >= BUS_OFF_REOPEN_AFTER:
            self.close()

    def bus_state_fault(self) -> str | None:
        """'bus_off' when the interface reports the controller in the error (bus-off) state."""
        if self.bus is None:
            return None
        try:
            return "bus_off" if self.bus.state == can.BusState.ERROR else None
        except Exception:  # noqa: BLE001 - not all interfaces know their state
            return None

    def receive(self, limit: int = 512) -> tuple[list[can.Message], str | None]:
        """Every frame waiting (up to `limit`), without blocking; and a fault name if reading failed."""
        if self.bus is None:
            return [], None
        out = []
        try:
            while len(out) < limit:
                msg = self.bus.recv(timeout=0)
                if msg is None:
                    break
                out.append(msg)
        except can.CanError as exc:
            self.last_error = str(exc)
            fault = classify(exc)
            self._note(fault if fault != "tx_queue_full" else "receive_error")
            return out, "receive_error" if fault == "tx_queue_full" else fault
        except Exception as exc:  # noqa: BLE001 - fail safe: the caller must still send this tick
            self._unexpected("receive", exc)
            return out, "receive_error"
        return out, None

    def close(self) -> None:
        if self.bus is not None:
            try:
                self.bus.shutdown()
            except Exception as exc:  # noqa: BLE001 - the bus is dropped either way
                log.debug("shutdown failed: %s", exc)
            self.bus = None
