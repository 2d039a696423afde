"""Files written whole or not at all (touch4d.atomic), and every place that writes one that way: a file
planted under the name a writer once used for its half-written copy (a symlink to someone else's file)
is neither written through nor left behind as the target."""
import json
import os
import stat

import numpy as np
import pytest
from PIL import Image

from touch4d import atomic
from touch4d.atomic import write_atomic


def plant(folder, name):
    """A victim file and a symlink to it named `name` in folder: what an attacker or a stale run leaves."""
    victim = folder / "victim.txt"
    victim.write_text("untouched")
    (folder / name).symlink_to(victim)
    return victim


def leftovers(folder, *expected):
    """What else lies in folder than the expected names, the victim and the planted link."""
    return sorted(p.name for p in folder.iterdir() if p.name not in {*expected, "victim.txt"} and not p.is_symlink())


def test_write_atomic_replaces_a_link_at_the_target_never_the_file_it_points_to(tmp_path):
    victim = plant(tmp_path, "out.txt")
    write_atomic(tmp_path / "out.txt", "new\n")
    assert victim.read_text() == "untouched"
    assert not (tmp_path / "out.txt").is_symlink() and (tmp_path / "out.txt").read_text() == "new\n"
    assert leftovers(tmp_path, "out.txt") == []


def test_write_atomic_keeps_the_replaced_files_mode_and_gives_a_new_one_the_mode_asked(tmp_path):
    path = tmp_path / "key"
    write_atomic(path, b"1", mode=0o600)
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    write_atomic(path, b"2")
    assert stat.S_IMODE(path.stat().st_mode) == 0o600 and path.read_bytes() == b"2"


def test_a_failed_write_leaves_the_old_file_and_no_temporary_one(tmp_path, monkeypatch):
    path = tmp_path / "out.txt"
    path.write_text("old")

    def full(fd):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(atomic.os, "fsync", full)
    with pytest.raises(OSError):
        write_atomic(path, "new")
    assert path.read_text() == "old" and leftovers(tmp_path, "out.txt") == []


def test_durable_flushes_the_file_and_its_folder_and_not_durable_neither(tmp_path, monkeypatch):
    synced = []
    real = os.fsync
    monkeypatch.setattr(atomic.os, "fsync", lambda fd: (synced.append(os.fstat(fd).st_mode), real(fd)))
    write_atomic(tmp_path / "a", "x")
    assert [stat.S_ISREG(m) for m in synced] == [True, False]     # the file, then the folder
    synced.clear()
    write_atomic(tmp_path / "b", "x", durable=False)
    assert synced == [] and (tmp_path / "b").read_text() == "x"


def test_a_rendered_frame_is_written_atomically(tmp_path):
    from touch4d.render.context import save_png

    victim = plant(tmp_path, ".frame.png.partial")
    image = np.zeros((4, 5, 4), np.uint8)
    image[1, 2] = (10, 20, 30, 255)
    save_png(image, tmp_path / "frame.png")
    assert victim.read_text() == "untouched"
    assert np.array_equal(np.asarray(Image.open(tmp_path / "frame.png")), image)
    assert leftovers(tmp_path, "frame.png") == []


def test_a_sessions_manifest_is_written_atomically(tmp_path):
    from touch4d.study.manifest import read_manifest, write_manifest

    victim = plant(tmp_path, "manifest.json.tmp")
    write_manifest(tmp_path, {"participant": "P01", "trials": 3})
    assert victim.read_text() == "untouched"
    assert read_manifest(tmp_path) == {"participant": "P01", "trials": 3}
    assert leftovers(tmp_path, "manifest.json") == []


def test_a_fanned_out_result_is_cached_atomically(tmp_path):
    from touch4d.study.fanout import Cluster, fan_out

    victim = plant(tmp_path, ".k1.json.tmp")
    got = fan_out(lambda shared, x: {"twice": 2 * x}, {"k1": (4,)}, cluster=Cluster(workers=0), cache=tmp_path,
                  progress=False)
    assert got == {"k1": {"twice": 8}}
    assert victim.read_text() == "untouched"
    assert json.loads((tmp_path / "k1.json").read_text()) == {"twice": 8}
    assert leftovers(tmp_path, "k1.json") == []


def test_a_containers_ready_file_is_written_atomically(tmp_path):
    from touch4d.bus.container import Container

    ready = tmp_path / "g.ready"
    victim = plant(tmp_path, "g.ready.tmp")
    Container._tell(str(ready), "ready")
    assert victim.read_text() == "untouched"
    assert ready.read_text() == "ready\n" and leftovers(tmp_path, "g.ready") == []
