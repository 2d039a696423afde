"""A served participant's life as a state machine: the study server drives it with what happens (a
join, the session ready, the page gone and back, the experimenter's buttons, the link revoked) and
sends its trials the command each event returns; the experimenter's page shows `shown()`.

    invited --join--> starting --ready--> running --finished--> done
       ^                 |                  |  ^
       |                 +----stopped-------+--+--> left --join--> starting ...
    revoked <--revoke-- (any)               page gone / back: paused by the server (resumed by the page)
                                            experimenter pause / resume: paused by the experimenter
                                            (only the experimenter resumes it; it outlives a leave)

Two pauses, kept apart: the server's (no page: the page coming back resumes it) and the
experimenter's (the participant's reloads never undo it). A trial is paused while either holds.
Pure: no clock, no I/O; a server restarted on the same folder rebuilds each life with `from_data`.
"""
from __future__ import annotations

import enum
from dataclasses import dataclass

PAUSE, RESUME = "pause", "resume"      # study/command's verbs (touch4d.messages.StudyCommand)


class State(str, enum.Enum):
    INVITED = "invited"      # a link, no session yet
    STARTING = "starting"    # joined: its session is being started
    RUNNING = "running"      # its session runs (paused or not: see Life.paused_by)
    LEFT = "left"            # its session stopped before the last trial (its link resumes it)
    DONE = "done"            # every trial has its row
    REVOKED = "revoked"      # its link ended: no join until a new one


class Refused(Exception):
    """A join that cannot be: the link was revoked, or every trial is done (says which)."""


@dataclass
class Life:
    state: State = State.INVITED
    page_gone: bool = False      # the server's pause: a running session whose page closed
    held: bool = False           # the experimenter's pause

    @classmethod
    def from_data(cls, rows: int, planned: int, invited: bool) -> "Life":
        """A participant as a server starting on an existing folder finds them: by their link and
        how many of their `planned` trials have a row."""
        if not invited:
            return cls(State.REVOKED)
        if planned and rows >= planned:
            return cls(State.DONE)
        return cls(State.LEFT if rows else State.INVITED)

    # ---- what the experimenter sees --------------------------------------------------------------

    @property
    def paused_by(self) -> str | None:
        """Who holds its trial paused now (the experimenter's pause named first), or None."""
        if self.state not in (State.STARTING, State.RUNNING):
            return None
        if self.held:
            return "experimenter"
        return "server (no page)" if self.page_gone else None

    def shown(self) -> str:
        """Its state in a word: `paused` for a running session that either pause holds."""
        return "paused" if self.paused_by is not None and self.state is State.RUNNING else self.state.value

    @property
    def active(self) -> bool:
        return self.state in (State.STARTING, State.RUNNING)

    # ---- events: each returns the command for its trials, or None -----------------------------

    def join(self) -> bool:
        """Its link's Join: True when its session must be started (False: it runs or starts already)."""
        if self.state is State.REVOKED:
            raise Refused("its link was revoked")
        if self.state is State.DONE:
            raise Refused("every trial is done")
        if self.active:
            return False
        self.state, self.page_gone = State.STARTING, False
        return True

    def ready(self) -> str | None:
        """Its session serves its page: running (a session starts unpaused: the experimenter's pause,
        if any, is sent again)."""
        if self.state is not State.STARTING:
            return None
        self.state = State.RUNNING
        return PAUSE if self.held else None

    def page_closed(self) -> str | None:
        """Its last page closed: the server pauses its trial (unless the experimenter's pause holds it)."""
        if self.state is not State.RUNNING or self.page_gone:
            return None
        self.page_gone = True
        return None if self.held else PAUSE

    def page_opened(self) -> str | None:
        """A page of it connected: the server's pause ends (the experimenter's does not)."""
        if not self.page_gone:
            return None
        self.page_gone = False
        return None if self.held or self.state is not State.RUNNING else RESUME

    def experimenter(self, action: str) -> str | None:
        """The experimenter's pause or resume: the command goes out while a running trial has a page
        (with no page the server's pause holds it; the page coming back then resumes it or not)."""
        if action not in (PAUSE, RESUME):
            raise ValueError(f"an experimenter's action: {PAUSE} or {RESUME}, got {action!r}")
        was, self.held = self.held, action == PAUSE
        if was == self.held or self.state is not State.RUNNING or self.page_gone:
            return None
        return action

    def finished(self) -> None:
        """Its session says every trial is done."""
        if self.state is not State.REVOKED:
            self.state, self.page_gone = State.DONE, False

    def stopped(self) -> None:
        """Its session stopped (it left, it failed, the server stops): `left`, unless done or revoked."""
        if self.state in (State.STARTING, State.RUNNING):
            self.state = State.LEFT
        self.page_gone = False

    def revoke(self) -> None:
        self.state, self.page_gone = State.REVOKED, False

    def invited(self, rows: int, planned: int) -> None:
        """A new link for a revoked participant: back to what its data say."""
        if self.state is State.REVOKED:
            self.state = Life.from_data(rows, planned, invited=True).state
