"""What a run may write where: one writer per session folder (a lock a dead writer does not hold),
runs refused into an --out of another study or other settings (or replaced with --overwrite), no
stale report left, repeated trials refused by the analysis, a participant id outside P01, P02, ...
told its counterbalancing row and given --order, a study found by its name, and the exit status
of a run of many parts."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap

import pytest

from touch4d.cli import main
from touch4d.errors import ConfigError
from touch4d.study.psychophysics import HUMAN_NOISE
from touch4d.study.design import load_study, study_file_path
from touch4d.study.lock import LOCK, WRITER, SessionLock
from touch4d.study.plan import condition_order, order_table, participant_index
from touch4d.study.session import worst_exit
from touch4d.study.store import SessionError
from touch4d.study.table import read_trials

pytestmark = pytest.mark.timeout(300)

OFFLINE = ["study", "run", "paper", "--simulate", "--offline", "--quick", "--participants", "1"]


def hold_lock(folder, name=LOCK):
    """Another process that takes the folder's lock file `name` and waits; returns it once it holds it."""
    code = textwrap.dedent(f"""
        import sys, time
        from touch4d.study.lock import LOCK, WRITER, SessionLock
        with SessionLock({str(folder)!r}, {name!r}):
            print("held", flush=True)
            time.sleep(120)
    """)
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "held"
    return proc


def test_a_session_folder_has_one_writer_and_a_dead_writer_holds_nothing(tmp_path, capsys):
    folder = tmp_path / "P01"
    holder = hold_lock(folder)
    try:
        with pytest.raises(SessionError) as refused:
            SessionLock(folder).acquire()
        assert str(folder) in str(refused.value) and f"pid {holder.pid}" in str(refused.value)
        # a second run on the same --out is refused, naming the folder and the running process
        assert main([*OFFLINE, "--out", str(tmp_path)]) == 2
        err = capsys.readouterr().err
        assert str(folder) in err and f"pid {holder.pid}" in err
        assert not (folder / "trials.csv").exists()
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    with SessionLock(folder):                   # the kernel dropped the dead writer's lock
        with pytest.raises(SessionError):
            SessionLock(folder).acquire()        # ... and one writer holds it again
    assert main([*OFFLINE, "--out", str(tmp_path)]) == 0
    assert (folder / "trials.csv").exists()


def test_a_folder_the_lock_made_goes_with_it_when_nothing_else_was_written(tmp_path):
    with SessionLock(tmp_path / "P01"):
        pass
    assert not (tmp_path / "P01").exists()
    with SessionLock(tmp_path / "P02"):
        (tmp_path / "P02" / "manifest.json").write_text("{}")
    assert sorted(p.name for p in (tmp_path / "P02").iterdir()) == [LOCK, "manifest.json"]
    (tmp_path / "P03").mkdir()                  # a folder that was there before the lock stays
    with SessionLock(tmp_path / "P03"):
        pass
    assert (tmp_path / "P03").is_dir()


def test_a_lock_opened_as_its_holder_removes_the_empty_folder_is_taken_anew(tmp_path, monkeypatch):
    import touch4d.study.lock as lock

    first = SessionLock(tmp_path / "P01").acquire()
    opened, os_open = [], os.open

    def open_then_holder_leaves(*args, **kwargs):    # the holder releases between our open and our flock
        fd = os_open(*args, **kwargs)
        if not opened:
            opened.append(fd)
            first.release()
        return fd

    monkeypatch.setattr(lock.os, "open", open_then_holder_leaves)
    second = SessionLock(tmp_path / "P01").acquire()
    monkeypatch.undo()
    try:
        assert opened and (tmp_path / "P01" / LOCK).exists()
        with pytest.raises(SessionError):          # the lock held is the folder's, not a removed file
            SessionLock(tmp_path / "P01").acquire()
    finally:
        second.release()


def test_a_run_is_refused_while_a_study_node_of_a_killed_run_still_writes(tmp_path, capsys):
    orphan = hold_lock(tmp_path / "P01", WRITER)      # as a study node whose `study run` was SIGKILLed
    try:
        assert main(["study", "run", "paper", "--participant", "P01", "--out", str(tmp_path)]) == 2
        err = capsys.readouterr().err
        assert str(tmp_path / "P01") in err and f"pid {orphan.pid}" in err and "trials.csv" in err
        assert not (tmp_path / "P01" / "session-001.mcap").exists()           # no stack was started
        assert main([*OFFLINE, "--out", str(tmp_path)]) == 2                   # nor does a simulation write
    finally:
        orphan.send_signal(signal.SIGKILL)
        orphan.wait()
    with SessionLock(tmp_path / "P01", WRITER):
        pass                                          # free again once the orphan is gone


def test_a_run_into_an_out_of_other_settings_is_refused_or_replaced_with_overwrite(tmp_path, capsys):
    assert main([*OFFLINE, "--out", str(tmp_path), "--noise", "0.08"]) == 0
    first = (tmp_path / "P01" / "trials.csv").read_text()
    (tmp_path / "report.html").write_text("<html>the sessions before</html>")
    capsys.readouterr()
    # the same settings again: the same seeded session, said so, and the old report is gone
    assert main([*OFFLINE, "--out", str(tmp_path), "--noise", "0.08"]) == 0
    out = capsys.readouterr().out
    assert "written again" in out and "report.html: removed" in out
    assert not (tmp_path / "report.html").exists()
    assert (tmp_path / "P01" / "trials.csv").read_text() == first
    # other noise: refused, naming the folder and what differs; nothing written
    assert main([*OFFLINE, "--out", str(tmp_path), "--noise", "0.3"]) == 2
    err = capsys.readouterr().err
    assert str(tmp_path / "P01") in err and "0.08" in err and "0.3" in err and "--overwrite" in err
    assert json.loads((tmp_path / "P01" / "manifest.json").read_text())["simulation"]["noise"] == 0.08
    # a full (not quick) run, or another study file, differs too
    assert main(["study", "run", "paper", "--simulate", "--offline", "--participants", "1", "--out",
                 str(tmp_path)]) == 2
    assert "quick" in capsys.readouterr().err
    # --overwrite replaces the sessions this run writes
    assert main([*OFFLINE, "--out", str(tmp_path), "--noise", "0.3", "--overwrite"]) == 0
    assert json.loads((tmp_path / "P01" / "manifest.json").read_text())["simulation"]["noise"] == 0.3
    # ... but never another participant's session of other settings (analysed together they would mix)
    assert main([*OFFLINE[:-1], "2", "--out", str(tmp_path), "--noise", "0.08"]) == 2
    capsys.readouterr()
    assert not (tmp_path / "P02").exists()      # the refused run leaves no folder holding only its lock
    (tmp_path / "P02").mkdir()
    (tmp_path / "P02" / "manifest.json").write_text(json.dumps({"study": "other", "study_sha256": "0" * 64}))
    assert main([*OFFLINE, "--out", str(tmp_path), "--noise", "0.3", "--overwrite"]) == 2
    assert str(tmp_path / "P02") in capsys.readouterr().err


def test_analyze_refuses_a_trial_written_twice_naming_it(tmp_path):
    assert main([*OFFLINE, "--out", str(tmp_path / "a")]) == 0
    table = tmp_path / "a" / "P01" / "trials.csv"
    lines = table.read_text().splitlines(keepends=True)
    table.write_text("".join(lines + lines[3:5]))         # trials 2 and 3 again, as two writers left them
    with pytest.raises(ConfigError) as refused:
        read_trials(tmp_path / "a")
    text = str(refused.value)
    assert "participant P01 session 1 block 0 trial 2 (2x" in text and "trial 3 (2x" in text and str(table) in text
    assert main(["study", "analyze", str(tmp_path / "a"), "--no-report"]) == 2


def test_an_id_outside_p01_is_told_its_row_and_order_picks_one(tmp_path, capsys):
    study = load_study("config/studies/paper.yaml")
    rows = order_table(study)
    assert main(["study", "plan", "paper", "--participant", "bob", "--quick"]) == 0
    out = capsys.readouterr().out
    hashed = participant_index(study, "bob")
    assert f"row {hashed + 1} of {len(rows)}" in out and "--order N" in out
    assert main(["study", "plan", "paper", "--participant", "bob", "--quick", "--order", "2", "--json"]) == 0
    plan = json.loads(capsys.readouterr().out)
    assert plan["condition_order"] == rows[1] and plan["order_note"] is None
    assert [t["condition"] for t in plan["trials"]][0] == rows[1][0]
    assert condition_order(study, "P03") == rows[2] and participant_index(study, "P03", order=5) == 4
    assert main(["study", "plan", "paper", "--participant", "bob", "--order", str(len(rows) + 1)]) == 2
    assert f"1..{len(rows)}" in capsys.readouterr().err
    assert main(["study", "plan", "paper", "--participant", "P01"]) == 0
    assert "note:" not in capsys.readouterr().out          # P01, P02, ... need no note
    # a session resumes only in the order it ran: refused before any stack starts
    (tmp_path / "bob").mkdir()
    (tmp_path / "bob" / "manifest.json").write_text(json.dumps({"condition_order": rows[0]}))
    assert main(["study", "run", "paper", "--participant", "bob", "--order", "2", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert " -> ".join(rows[0]) in err and "--order it ran with" in err


def test_a_study_is_found_by_its_name(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)                             # the packaged study, from anywhere
    assert study_file_path("paper").name == "paper.yaml"
    assert load_study(study_file_path("paper")).name == "paper"
    with pytest.raises(ConfigError) as wrong:
        study_file_path("papr")
    assert "did you mean 'paper'" in str(wrong.value) and "paper" in str(wrong.value)
    assert main(["study", "check", "paper"]) == 0


def test_the_exit_status_of_a_run_is_the_worst_of_its_parts():
    assert worst_exit([0, 0]) == 0
    assert worst_exit([0, 1, 0]) == 1
    assert worst_exit([1, 2]) == 2 and worst_exit([2, 1]) == 2       # not the first that failed
    assert worst_exit([0, -signal.SIGTERM]) == 128 + signal.SIGTERM
    assert worst_exit([]) == 0


def test_analyze_refuses_sessions_that_ran_otherwise(tmp_path, capsys):
    assert main([*OFFLINE, "--out", str(tmp_path / "a")]) == 0
    assert main([*OFFLINE, "--out", str(tmp_path / "b"), "--noise", "0.2"]) == 0
    (tmp_path / "b" / "P01").rename(tmp_path / "a" / "P02")     # a session of other noise beside the first
    capsys.readouterr()
    assert main(["study", "analyze", str(tmp_path / "a"), "--no-report"]) == 2
    err = capsys.readouterr().err
    assert str(tmp_path / "a" / "P02") in err and f"simulation.noise 0.2 where P01 has {HUMAN_NOISE}" in err     # P01 ran at the default
