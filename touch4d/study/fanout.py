"""Many simulations on Dask: the same code on this machine's worker processes (`--workers N`) or on a
cluster (`--scheduler tcp://HOST:8786`).

A simulation is a pure function of (study, design, participant, simulation): its seed comes from
numpy's `SeedSequence` of those four (`seed_of`), never from which worker ran it or when, so one
worker, many or a cluster give the same answers. Each finished simulation is kept as a JSON file in
a cache folder (`cache/<run signature>/<key>.json` under the output folder): Ctrl+C keeps what
finished, and the same command resumes from it; another command (other parameters) gets another
signature and so another folder.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from touch4d.atomic import write_atomic
from touch4d.errors import ConfigError, Unavailable


def _hash64(text: str) -> int:
    return int.from_bytes(hashlib.sha256(str(text).encode()).digest()[:8], "big")


def seed_of(study, design: str, participant: str, simulation: int, seed: int = 0) -> int:
    """The seed of one simulated participant (or study) of one simulation: SeedSequence of the study
    (name and seed), the design (what is simulated: a glove, a power curve ...), the participant, the
    simulation's number and the run's seed, as a 63-bit integer."""
    entropy = [int(seed) & 0xFFFFFFFF, int(study.seed) & 0xFFFFFFFF, _hash64(study.name), _hash64(design),
               _hash64(participant), int(simulation)]
    return int(np.random.SeedSequence(entropy).generate_state(2, np.uint64)[0] >> np.uint64(1))


def signature(parameters: dict) -> str:
    """A short, stable name for a run's parameters (its cache folder)."""
    return hashlib.sha256(json.dumps(parameters, sort_keys=True, default=str).encode()).hexdigest()[:16]


@dataclass(frozen=True)
class Cluster:
    """Where simulations run: `scheduler` (a Dask scheduler's address) or local worker processes
    (`workers`, default one a core); `workers=0` runs them in this process, without Dask."""

    workers: int | None = None
    scheduler: str | None = None

    def describe(self) -> str:
        if self.scheduler:
            return f"the Dask cluster at {self.scheduler}"
        if self.workers == 0:
            return "this process"
        return f"{self.workers or os.cpu_count()} local worker processes"


@contextlib.contextmanager
def dask_client(cluster: Cluster, *, timeout: str = "20s"):
    """A distributed.Client for `cluster` (a local cluster of processes, one thread each, if no scheduler);
    `timeout`: how long to try reaching a scheduler."""
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise Unavailable("many simulations need Dask: pip install 'touch4d[study]'") from None
    if cluster.scheduler:
        try:
            client = Client(cluster.scheduler, timeout=timeout)
        except (OSError, TimeoutError) as exc:
            raise ConfigError("command line", "--scheduler", "the address of a running Dask scheduler "
                              "(tcp://HOST:8786)", got=cluster.scheduler, detail=str(exc)) from None
        with client:
            yield client
        return
    workers = cluster.workers or os.cpu_count() or 1
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0",
                      silence_logs=logging.ERROR) as local, Client(local) as client:
        yield client


def fan_out(function: Callable, jobs: dict[str, tuple], *, shared=None, cluster: Cluster = Cluster(),
            cache: Path | None = None, label: str = "simulations", progress: bool = True, client=None
            ) -> dict[str, dict]:
    """`function(shared, *args)` for every `key: args` of `jobs`, on `cluster` (through `client`, a
    distributed.Client already open on it, if given); returns {key: result} (each result a JSON-ready
    dict). With `cache`, finished results are read from and written to `cache/<key>.json`: an
    interrupted run (Ctrl+C) keeps them and the next one skips them."""
    results: dict[str, dict] = {}
    if cache is not None:
        cache = Path(cache)
        cache.mkdir(parents=True, exist_ok=True)
        for key in jobs:
            path = cache / f"{key}.json"
            if path.is_file():
                try:
                    results[key] = json.loads(path.read_text())
                except (OSError, json.JSONDecodeError):
                    pass                     # a half-written file from a killed run: simulate it again
    todo = {key: args for key, args in jobs.items() if key not in results}
    with _progress(progress, label, len(jobs), len(results)) as advance:
        def keep(key: str, result: dict) -> None:
            text = json.dumps(result)
            results[key] = json.loads(text)          # as a resumed run reads it: the same types either way
            if cache is not None:
                write_atomic(cache / f"{key}.json", text)     # a file is whole or absent
            advance()

        if cluster.workers == 0 and not cluster.scheduler:
            for key, args in todo.items():
                keep(key, function(shared, *args))
        elif todo:
            from distributed import as_completed

            with (contextlib.nullcontext(client) if client is not None else dask_client(cluster)) as client:
                # In a list: a dict would be scattered as named pieces. hash=False: a key of its own, so that
                # the same `shared` scattered again on this client (a second call) is not the key the first
                # call's release is deleting.
                handle = client.scatter([shared], broadcast=True, hash=False)[0] if shared is not None else None
                run = uuid.uuid4().hex[:8]   # this call's: a task of an earlier call may still be being released
                futures = {client.submit(function, handle, *args, key=f"{label}-{key}-{run}",
                                         pure=False): key for key, args in todo.items()}
                try:
                    for future in as_completed(futures):
                        keep(futures[future], future.result())
                except BaseException:
                    client.cancel(list(futures))
                    raise
    return {key: results[key] for key in jobs}


@contextlib.contextmanager
def _progress(enabled: bool, label: str, total: int, done: int):
    if not enabled:
        yield lambda: None
        return
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    with Progress(TextColumn(f"{label}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                  transient=True) as bar:
        task = bar.add_task(label, total=total, completed=done)
        yield lambda: bar.advance(task)


__all__ = ["Cluster", "seed_of", "signature", "fan_out", "dask_client"]
