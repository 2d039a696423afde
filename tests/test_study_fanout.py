"""Many simulations on Dask: answers depend on seeds, never on scheduling (a real scheduler and two
workers on loopback, local processes, one worker, this process); an interrupted run keeps what
finished and the same call resumes."""
import hashlib
import json
import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from touch4d.study.design import load_study
from touch4d.study.fanout import Cluster, fan_out, seed_of
from touch4d.study.observer import ModelObserver
from touch4d.study.power import Population, PowerSetup, power_curves
from touch4d.tactile import load_glove


@pytest.fixture(scope="module")
def paper():
    return load_study("config/studies/paper.yaml")


@pytest.fixture(scope="module")
def lookalikes():
    return load_study("tests/data/studies/lookalikes.yaml")


def test_a_seed_depends_on_each_of_study_design_participant_and_simulation_and_on_nothing_else(paper):
    base = seed_of(paper, "power", "P01", 3)
    assert base == seed_of(paper, "power", "P01", 3)
    others = {seed_of(paper, "glove", "P01", 3), seed_of(paper, "power", "P02", 3), seed_of(paper, "power", "P01", 4),
              seed_of(paper, "power", "P01", 3, seed=1)}
    assert base not in others and len(others) == 4
    digest = [int.from_bytes(hashlib.sha256(t.encode()).digest()[:8], "big") for t in ("paper", "power", "P01")]
    expected = np.random.SeedSequence([0, paper.seed, *digest, 3]).generate_state(2, np.uint64)[0] >> np.uint64(1)
    assert base == int(expected)


def _square(shared, x):
    if shared and x in shared["fail"]:
        raise KeyboardInterrupt
    return {"value": x * x}


def test_an_interrupted_run_keeps_what_finished_and_the_same_call_resumes(tmp_path):
    jobs = {f"j{i}": (i,) for i in range(5)}
    with pytest.raises(KeyboardInterrupt):
        fan_out(_square, jobs, shared={"fail": {3}}, cluster=Cluster(workers=0), cache=tmp_path, progress=False)
    kept = sorted(p.name for p in tmp_path.glob("*.json"))
    assert kept == ["j0.json", "j1.json", "j2.json"]
    # the kept results are read, not recomputed: this run would fail on 0..2 and does not
    done = fan_out(_square, jobs, shared={"fail": {0, 1, 2}}, cluster=Cluster(workers=0), cache=tmp_path,
                   progress=False)
    assert done == {f"j{i}": {"value": i * i} for i in range(5)}
    (tmp_path / "j4.json").write_text('{"val')            # a half-written file is simulated again
    assert fan_out(_square, jobs, shared={"fail": set()}, cluster=Cluster(workers=0), cache=tmp_path,
                   progress=False)["j4"] == {"value": 16}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _dask_processes(port):
    dask = str(Path(sys.executable).parent / "dask")
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    started = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", str(port),
                                 "--no-dashboard"], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                start_new_session=True)]
    for _ in range(2):
        started.append(subprocess.Popen([dask, "worker", f"tcp://127.0.0.1:{port}", "--nthreads", "1",
                                         "--no-dashboard"], env=env, stdout=subprocess.DEVNULL,
                                        stderr=subprocess.DEVNULL, start_new_session=True))
    return started


@pytest.mark.timeout(400)
def test_power_is_the_same_on_a_dask_cluster_on_a_local_worker_and_in_process(lookalikes, tmp_path):
    from distributed import Client

    glove = load_glove()
    observer = ModelObserver(glove, lookalikes, train_scenes=3, train_positions=6, view_scenes=6).train()
    setup = PowerSetup(observer, glove, lookalikes, Population(), bootstrap=0, samples=20)
    sizes, simulations = [2, 3], 2
    port = _free_port()
    processes = _dask_processes(port)
    try:
        with Client(f"tcp://127.0.0.1:{port}", timeout="60s") as client:
            client.wait_for_workers(2, timeout=120)
        on_cluster = power_curves(setup, sizes, simulations, cluster=Cluster(scheduler=f"tcp://127.0.0.1:{port}"),
                                  progress=False)
    finally:
        for process in processes:
            os.killpg(process.pid, signal.SIGTERM)
        for process in processes:
            try:
                process.wait(20)
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGKILL)
                process.wait()
    in_process = power_curves(setup, sizes, simulations, cluster=Cluster(workers=0), out=tmp_path, progress=False)
    one_worker = power_curves(setup, sizes, simulations, cluster=Cluster(workers=1), progress=False)
    assert json.dumps(on_cluster) == json.dumps(in_process) == json.dumps(one_worker)
    effect = in_process["curves"]["lookalikes"]["effects"]["touch"]
    assert effect["sizes"] == sizes and all(p["simulations"] == simulations for p in effect["gee"])
    cached = sorted(p.name for p in next((tmp_path / "cache").iterdir()).glob("*.json"))
    assert cached == ["n2-s0.json", "n2-s1.json", "n3-s0.json", "n3-s1.json"]


def test_one_client_runs_the_same_shared_data_twice():
    """Two fan-outs in a row on one open client with equal shared data (a bench's warm-up, then its run)."""
    from touch4d.study.fanout import dask_client

    jobs = {f"k{i}": (i,) for i in range(4)}
    with dask_client(Cluster(workers=1)) as client:
        runs = [fan_out(_square, jobs, shared={"fail": set()}, cluster=Cluster(workers=1), client=client,
                        progress=False) for _ in range(3)]
    assert runs == [{f"k{i}": {"value": i * i} for i in range(4)}] * 3


def test_a_scheduler_that_is_not_there_is_a_clear_error(paper):
    from touch4d.errors import ConfigError
    from touch4d.study.fanout import dask_client

    with pytest.raises(ConfigError, match="--scheduler.*Dask scheduler"):
        with dask_client(Cluster(scheduler=f"tcp://127.0.0.1:{_free_port()}"), timeout="3s"):
            pass
