"""A participant's session, planned from (study, participant id) alone: the condition order
(counterbalanced across participants), the trials of each block shuffled under the run constraint,
each trial's jitter and seed. Pure: the same inputs give the same plan on every machine.

Participant ids are strings. `P01`, `P02`, ... (a letter P, any case, then a number) are rows 0,
1, ... of the counterbalancing table, so consecutive participants get consecutive orders; any other
id takes the row of a stable hash (the first 8 bytes of its SHA-256, big-endian) modulo the rows,
unless the row is given (`order`, from 1: `--order N`); `order_note` says which row such an id got.
A participant's random stream is `numpy.random.SeedSequence([study.seed, that hash])`.
"""
from __future__ import annotations

import hashlib
import itertools
import math
import re

import msgspec
import numpy as np

from touch4d import schema

from .design import Stimulus, Study, Task, replace_study

_NUMBERED = re.compile(r"^[Pp](\d+)$")
_MAX_SHUFFLES = 10_000


class Trial(msgspec.Struct, frozen=True):
    """One trial of a session, everything a runner needs to show it and score the answer."""

    index: int                   # 0.. over the session, practice included
    block: int                   # 0.. (one block per condition)
    trial: int                   # 0.. within its block, practice included
    practice: bool
    task: str
    kind: str
    condition: str
    stimulus: str                # e.g. face, tilt+8
    answer: str                  # the correct option
    options: list[str]
    prompt: str
    level: float                 # signed tilt (degrees) of a tilt trial, NaN otherwise
    transform: list[tuple[str, float]]   # the jitter: [plane, degrees], applied in order
    time_limit_s: float
    seed: int                    # this trial's own seed (jitter drawn from it; observers use it)
    break_before: bool = False   # a pause is offered before this trial (break_every; not before a block's first)


def participant_hash(participant: str) -> int:
    """A stable 64-bit number for an id (first 8 bytes of its SHA-256)."""
    return int.from_bytes(hashlib.sha256(str(participant).encode()).digest()[:8], "big")


def participant_index(study: Study, participant: str, order: int | None = None) -> int:
    """The row (from 0) of the counterbalancing table for `participant`: `order - 1` when a row is
    given (from 1), else P01 -> 0, P02 -> 1, ...; other ids by a stable hash; always modulo the rows."""
    rows = len(order_table(study))
    if order is not None:
        if not 1 <= order <= rows:
            raise ValueError(f"counterbalancing row (--order): expected 1..{rows} for study {study.name}, got {order}")
        return order - 1
    if is_numbered(participant):
        return (int(_NUMBERED.match(str(participant)).group(1)) - 1) % rows
    return participant_hash(participant) % rows


def is_numbered(participant: str) -> bool:
    """Whether an id is one of P01, P02, ... (which take the counterbalancing rows in turn)."""
    numbered = _NUMBERED.match(str(participant))
    return bool(numbered) and int(numbered.group(1)) >= 1


def order_note(study: Study, participant: str, order: int | None = None) -> str | None:
    """What to tell the experimenter about an id outside P01, P02, ... given no row: the row its hash
    picked (hashes can unbalance the orders) and how to pick one; None when nothing needs saying."""
    if order is not None or is_numbered(participant):
        return None
    rows = order_table(study)
    row = participant_index(study, participant)
    return (f"participant {participant!r} is not one of P01, P02, ...: it got counterbalancing row {row + 1} of "
            f"{len(rows)} ({' -> '.join(rows[row])}) from a hash of the id, which can unbalance the orders; "
            f"pick its row with --order N (1..{len(rows)})")


def order_table(study: Study) -> list[list[str]]:
    """Every row of the counterbalancing: all orders (lexicographic in the file's order of conditions)
    or a balanced Latin square (Williams design: n rows for even n, 2n for odd n)."""
    conditions = list(study.conditions)
    if study.counterbalancing() == "all":
        return [list(order) for order in itertools.permutations(conditions)]
    return [[conditions[k] for k in row] for row in balanced_latin_square(len(conditions))]


def balanced_latin_square(n: int) -> list[list[int]]:
    """Williams' balanced Latin square: each item once per row and column, and each ordered pair of
    neighbours equally often (once for even n; for odd n the square is followed by its mirror)."""
    first, low, high = [], 0, n - 1
    for j in range(n):                  # 0, 1, n-1, 2, n-2, ...
        if j == 0:
            first.append(0)
            low = 1
        elif j % 2 == 1:
            first.append(low)
            low += 1
        else:
            first.append(high)
            high -= 1
    rows = [[(x + r) % n for x in first] for r in range(n)]
    if n % 2 == 1:
        rows += [row[::-1] for row in rows]
    return rows


def condition_order(study: Study, participant: str, order: int | None = None) -> list[str]:
    """The conditions in the order `participant` meets them (one block each); `order`: the row, from 1."""
    return list(order_table(study)[participant_index(study, participant, order)])


def participant_seed(study: Study, participant: str) -> np.random.SeedSequence:
    """The random stream of (study, participant)."""
    return np.random.SeedSequence([int(study.seed), participant_hash(participant)])


def plan_session(study: Study, participant: str, order: int | None = None) -> list[Trial]:
    """Every trial of `participant`'s session, in order: per block (condition) the practice trials,
    then each task's stimuli x repetitions, shuffled so that no more than `max_run` trials in a row
    share a correct answer (over practice and main trials alike). `order`: the counterbalancing row
    (from 1), when not the participant id's."""
    conditions = condition_order(study, participant, order)
    block_seeds = participant_seed(study, participant).spawn(len(conditions))
    trials: list[Trial] = []
    for block, (condition, seed) in enumerate(zip(conditions, block_seeds)):
        rng = np.random.default_rng(seed)
        items = [(task, stim, level, answer) for task in study.tasks
                 for stim, level, answer in task.stimulus_set() for _ in range(study.repetitions_of(task))]
        sequence = _practice(items, study.practice, study.max_run, rng)
        start = len(sequence)
        last = sequence[-1][3] if sequence else None
        run = _tail_run([it[3] for it in sequence])
        main = constrained_shuffle(items, study.max_run, rng, key=lambda it: it[3], last=last, run=run,
                                   file=study.path)
        breaks = break_positions(len(sequence) + len(main), study.break_every)
        for position, item in enumerate(sequence + main):
            trials.append(_trial(study, len(trials), block, position, position < start, condition, item, rng,
                                 position in breaks))
    return trials


def break_positions(length: int, every: int) -> set[int]:
    """The positions in a block of `length` trials before which a pause is offered: every `every`
    trials, never before the first, and not where fewer than half a stretch remain (the break between
    blocks comes soon enough; 34 of 71 trials would otherwise pause 3 trials before it)."""
    if every <= 0:
        return set()
    return {p for p in range(every, length, every) if 2 * (length - p) >= every}


def quick_plan(study: Study, participant: str, order: int | None = None) -> list[Trial]:
    """A quick session (`--quick`): one repetition per task x condition cell, i.e. every stimulus once
    per condition, no practice, otherwise as `plan_session` (same order, constraint and seeds)."""
    tasks = [msgspec.structs.replace(t, repetitions=1) for t in study.tasks]
    return plan_session(replace_study(study, tasks=tasks, repetitions=1, practice=0), participant, order)


def participant_ids(n: int) -> list[str]:
    """P01, P02, ... Pnn: the ids of n participants, in counterbalancing order."""
    width = max(2, len(str(n)))
    return [f"P{k:0{width}d}" for k in range(1, n + 1)]


def _practice(items: list, count: int, max_run: int, rng: np.random.Generator) -> list:
    """`count` practice trials drawn at random from a block's items, one by one among those whose
    answer keeps runs within `max_run`."""
    out: list = []
    for _ in range(count):
        run = _tail_run([it[3] for it in out]) if out else 0
        allowed = [it for it in items if not (out and it[3] == out[-1][3] and run >= max_run)]
        out.append(allowed[int(rng.integers(len(allowed)))])
    return out


def _trial(study: Study, index: int, block: int, position: int, practice: bool, condition: str, item,
           rng: np.random.Generator, break_before: bool) -> Trial:
    task, stimulus, level, answer = item
    seed = int(rng.integers(0, 2**63 - 1))
    transform = draw_jitter(task, np.random.default_rng(seed))
    return Trial(index=index, block=block, trial=position, practice=practice, task=task.id, kind=task.kind,
                 condition=condition, stimulus=stimulus, answer=answer, options=list(task.options),
                 prompt=task.prompt, level=level, transform=transform, time_limit_s=study.time_limit_of(task),
                 seed=seed, break_before=break_before)


def draw_jitter(task: Task, rng: np.random.Generator) -> list[tuple[str, float]]:
    """A task's small random turn: each jitter plane by a uniform angle in [-jitter_deg, +jitter_deg]
    (degrees, rounded to 0.001 so that a written plan reproduces it exactly)."""
    if task.jitter_deg <= 0:
        return []
    return [(plane, round(float(rng.uniform(-task.jitter_deg, task.jitter_deg)), 3)) for plane in task.jitter_planes]


def stimuli_of(task: Task) -> list[Stimulus]:
    """(name, level, answer) of each stimulus of a task, in the task's order: what its kind makes
    (`Task.stimulus_set`)."""
    return task.stimulus_set()


def constrained_shuffle(items: list, max_run: int, rng: np.random.Generator, *, key, last=None, run: int = 0,
                        file=None) -> list:
    """`items` in a random order in which no more than `max_run` neighbours share `key(item)`; `last`
    and `run` continue a run from before the first item. Draws item by item among those allowed (an
    answer weighted by how many of it remain) and starts again on a dead end; an impossible demand
    is a ConfigError naming `max_run`."""
    if not items:
        return []
    keys = [key(it) for it in items]
    counts: dict = {}
    for k in keys:
        counts[k] = counts.get(k, 0) + 1
    most = max(counts.values())
    # The most frequent answer needs a different one between its runs of max_run.
    if most > max_run * (len(items) - most + 1):
        schema.fail(file, "max_run", f"a run limit the block can meet ({most} of {len(items)} trials share an "
                    f"answer: max_run >= {math.ceil(most / (len(items) - most + 1))})", got=max_run)
    by_key: dict = {}
    for it, k in zip(items, keys):
        by_key.setdefault(k, []).append(it)
    names = list(by_key)
    for _ in range(_MAX_SHUFFLES):
        pools = {k: [by_key[k][i] for i in rng.permutation(len(by_key[k]))] for k in names}
        out, prev, length = [], last, run
        while len(out) < len(items):
            left = {k: len(pools[k]) for k in names if pools[k]}
            total = sum(left.values())
            allowed = [k for k in left if not (k == prev and length >= max_run)]
            # Only answers after which the rest can still be ordered (keeps dead ends rare).
            choices = [k for k in allowed if _feasible(left, k, prev, length, max_run)] or allowed
            if not choices:
                break
            weights = np.array([left[k] for k in choices], dtype=float)
            pick = choices[int(rng.choice(len(choices), p=weights / weights.sum()))]
            out.append(pools[pick].pop())
            length = length + 1 if pick == prev else 1
            prev = pick
        if len(out) == len(items):
            return out
    schema.fail(file, "max_run", "a run limit a random order can meet", got=max_run)


def _feasible(left: dict, pick, prev, length: int, max_run: int) -> bool:
    """Whether, after `pick` is placed, every answer's remaining trials can still be separated: an
    answer needs one other trial between runs of max_run (less room for the run in progress)."""
    after = dict(left)
    after[pick] -= 1
    run = length + 1 if pick == prev else 1
    total = sum(after.values())
    for k, n in after.items():
        others = total - n
        room = max_run * others + (max_run - run if k == pick else max_run)
        if n > room:
            return False
    return True


def _tail_run(keys: list) -> int:
    """How many of the last `keys` are equal to the last one."""
    run = 0
    for k in reversed(keys):
        if k != keys[-1]:
            break
        run += 1
    return run
