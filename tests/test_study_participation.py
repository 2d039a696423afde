"""A served participant's life (touch4d.study.participation), without a server: each event's
command to the study node, what the experimenter sees, and over any sequence of events a running
trial paused exactly while the server's or the experimenter's pause holds it."""
from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from touch4d.study.participation import PAUSE, RESUME, Life, Refused, State


def running() -> Life:
    life = Life()
    assert life.join() is True and life.shown() == "starting"
    assert life.ready() is None and life.shown() == "running"
    return life


def test_the_page_gone_and_back_pauses_and_resumes():
    life = running()
    assert life.page_closed() == PAUSE and life.shown() == "paused" and life.paused_by == "server (no page)"
    assert life.page_closed() is None                  # said once
    assert life.page_opened() == RESUME and life.shown() == "running" and life.paused_by is None
    assert life.page_opened() is None


def test_the_experimenters_pause_outlives_the_participants_reloads():
    life = running()
    assert life.experimenter(PAUSE) == PAUSE and life.paused_by == "experimenter"
    assert life.page_closed() is None and life.page_opened() is None      # a reload: still paused
    assert life.shown() == "paused" and life.paused_by == "experimenter"
    assert life.experimenter(RESUME) == RESUME and life.shown() == "running"


def test_resumed_by_the_experimenter_while_the_page_is_gone_the_page_back_resumes_it():
    life = running()
    assert life.experimenter(PAUSE) == PAUSE
    assert life.page_closed() is None
    assert life.experimenter(RESUME) is None and life.paused_by == "server (no page)"
    assert life.page_opened() == RESUME and life.paused_by is None


def test_a_held_participant_who_leaves_and_rejoins_is_paused_again_at_once():
    life = running()
    life.experimenter(PAUSE)
    life.stopped()
    assert life.shown() == "left" and life.held
    assert life.join() is True
    assert life.ready() == PAUSE and life.shown() == "paused"


def test_revoked_and_done_refuse_a_join_and_a_new_link_restores_the_datas_state():
    life = running()
    life.revoke()
    assert life.shown() == "revoked" and life.paused_by is None
    with pytest.raises(Refused, match="revoked"):
        life.join()
    life.invited(rows=7, planned=42)
    assert life.shown() == "left" and life.join() is True
    life.ready()
    life.finished()
    assert life.shown() == "done"
    with pytest.raises(Refused, match="every trial"):
        life.join()


@pytest.mark.parametrize("rows, planned, invited, shown", [
    (0, 42, True, "invited"), (7, 42, True, "left"), (42, 42, True, "done"), (7, 42, False, "revoked"),
    (0, 42, False, "revoked")])
def test_a_restarted_server_reads_each_life_from_the_data(rows, planned, invited, shown):
    assert Life.from_data(rows, planned, invited).shown() == shown


def test_an_unknown_experimenter_action_is_an_error_naming_it():
    with pytest.raises(ValueError, match="'stop'"):
        Life().experimenter("stop")


EVENTS = ("join", "ready", "page_closed", "page_opened", "pause", "resume", "stopped", "finished", "revoke",
          "invited")


@settings(max_examples=300, deadline=None)
@given(st.lists(st.sampled_from(EVENTS), max_size=40))
def test_a_running_trial_is_paused_exactly_while_a_pause_holds_it(events):
    """The study node as a flag the commands set (a new node, at `ready`, starts unpaused): after any
    sequence, a running stack's trial is paused iff the experimenter or the page's absence holds it."""
    life, node = Life(), None          # node: None (no stack) or whether its trial is paused
    for event in events:
        if event == "join":
            try:
                life.join()
            except Refused:
                assert life.state in (State.REVOKED, State.DONE)
            continue
        if event == "ready" and life.state is State.STARTING:
            node = False
        command = {"ready": life.ready, "page_closed": life.page_closed, "page_opened": life.page_opened,
                   "pause": lambda: life.experimenter(PAUSE), "resume": lambda: life.experimenter(RESUME),
                   "stopped": life.stopped, "finished": life.finished, "revoke": life.revoke,
                   "invited": lambda: life.invited(3, 10)}[event]()
        if command is not None:
            assert node is not None, f"{command} sent to no stack after {events}"
            node = command == PAUSE
        if not life.active and life.state is not State.DONE:
            node = None
        if life.state is State.RUNNING:
            assert node == (life.held or life.page_gone), events
            assert (life.shown() == "paused") == node
