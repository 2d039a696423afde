"""A glove designed (`touch4d glove design --motors K --study STUDY -o NEW.yaml`): K actuator places
among the hand's sample points that maximise the bits one touch tells about the study's stimuli
(`study transfer`'s measure, averaged over the tasks).

A motor drives its sample point's h (paper eq. 1-3; h depends on every sample, not on the motors),
so a layout's patterns are columns of the every-sample glove's patterns: the examples are computed
once, with their noise, and a layout is scored by the held-out information transfer of the
observer's classifier on its columns (`infotransfer.held_out_confusion`). Three independent sets of
examples keep the search honest, since a score picked as the best of many is flattered by its own
noise: greedy forward selection on the search set (each step tries a random sample of the places,
all of them for small K: the stochastic greedy of Mirzasoleiman et al. 2015); then swap passes
judged on the validation set; at the glove's own motor count the search also starts from its own
layout (filled up by greedy steps where two motors share a sample), and the start that ends better
on validation is kept. Every layout (the designed, random ones of K as the baseline, the glove's
own) is reported on the test set, which neither saw. Random draws come from the run's seed: the
same seed, the same glove. Layouts fan out on Dask.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import msgspec
import numpy as np

from touch4d.errors import ConfigError
from touch4d.tactile import Glove

from .design import Study
from .fanout import Cluster, fan_out, seed_of
from .infotransfer import held_out_confusion, information_transfer
from .observer import every_sample_glove, touch_examples
from .plan import stimuli_of
from .psychophysics import motor_noise

DESIGN = "glove-design"
PURPOSES = ("search", "validation", "test")   # independent sets of examples (module docstring)
STEP_EPSILON = 0.01       # stochastic greedy: each step finds a top place with probability ~1 - epsilon


@dataclass
class Examples:
    """Per task the noisy patterns of every sample (rows, samples), each row's stimulus, the held-out
    rows, and the number of stimuli: what a layout is scored on."""

    tasks: dict

    @property
    def samples(self) -> int:
        return next(iter(self.tasks.values()))[0].shape[1]


def examples(glove: Glove, study: Study, tasks: list[str], *, noise: float, scenes: int = 16, positions: int = 12,
             seed: int = 0, purpose: str = "search") -> Examples:
    """The every-sample glove's noisy patterns of each task's stimuli (`noise` the fingertip's, per
    sample as `psychophysics.motor_noise`), half the scenes held out; each `purpose` (`PURPOSES`)
    draws an independent set."""
    every = every_sample_glove(glove)
    out = {}
    for task_id in tasks:
        task = study.task(task_id)
        rng = np.random.default_rng(seed_of(study, f"{DESIGN}-{purpose}", task_id, 0, seed))
        x, k, groups = touch_examples(every, study, task, rng, scenes=scenes, positions=positions)
        x = x + rng.normal(0.0, motor_noise(every, noise), x.shape)   # each sample felt as its skin
        out[task_id] = (x, k, groups % 2 == 1, len(stimuli_of(task)))
    return Examples(out)


def sample_regions(glove: Glove) -> dict[str, list[int]]:
    """The sample points of each region of the hand (`Hand.regions`: palm, back, each finger)."""
    return glove.hand.regions(glove.samples)


def candidates_in(glove: Glove, regions: list[str] | None) -> list[int]:
    """The sample indices of `regions` (all samples if None); an unknown region is a ConfigError."""
    if not regions:
        return list(range(len(glove.samples)))
    known = sample_regions(glove)
    unknown = [r for r in regions if r not in known]
    if unknown:
        raise ConfigError("command line", "--regions", f"regions of the hand: {', '.join(known)}", got=unknown[0])
    return sorted({i for r in regions for i in known[r]})


def layout_bits(data: Examples, places) -> dict:
    """Bits per task (and their mean) of a layout: motors at the sample indices `places`."""
    columns = np.asarray(list(places), dtype=int)
    bits = {task: information_transfer(held_out_confusion(x[:, columns], k, test, n))
            for task, (x, k, test, n) in data.tasks.items()}
    return {"bits": bits, "mean_bits": float(np.mean(list(bits.values())))}


def _mean_bits(data: Examples, places) -> float:
    return layout_bits(data, places)["mean_bits"]


def greedy_layout(data: Examples, motors: int, *, candidates=None, epsilon: float = STEP_EPSILON,
                  rng: np.random.Generator | None = None, start=()) -> list[int]:
    """Forward selection of `motors` places on `data`, from the places `start`: each step adds the
    place that raises the bits most among `step_sample` places drawn at random (all of them when K is
    small); see the module docstring. Deterministic given `rng`."""
    pool = list(range(data.samples) if candidates is None else candidates)
    if motors > len(pool):
        raise ConfigError("command line", "--motors", f"at most {len(pool)} motors (the places to choose from)",
                          got=motors)
    rng = np.random.default_rng(0) if rng is None else rng
    per_step = step_sample(len(pool), motors, epsilon)
    chosen = [int(c) for c in start]
    for _ in range(motors - len(chosen)):
        left = [c for c in pool if c not in chosen]
        tried = left if per_step >= len(left) else sorted(rng.choice(left, per_step, replace=False).tolist())
        chosen.append(max(tried, key=lambda c: _mean_bits(data, chosen + [c])))
    return [int(c) for c in chosen]


def step_sample(pool: int, motors: int, epsilon: float = STEP_EPSILON) -> int:
    """Places tried per greedy step: (pool / K) ln(1 / epsilon), the stochastic greedy's sample
    (Mirzasoleiman et al. 2015), so a design costs about pool ln(1 / epsilon) scorings whatever K."""
    return max(1, min(pool, math.ceil(pool / motors * math.log(1.0 / epsilon))))


def improve_by_swaps(validation: Examples, start, *, candidates, rounds: int, tries: int,
                     rng: np.random.Generator) -> tuple[list[int], float]:
    """Swap passes judged on `validation` (examples the greedy steps never saw): each pass replaces
    each chosen place in turn by `tries` other places drawn at random and keeps a swap only if it
    raises the validation bits. Returns the layout and its validation bits."""
    chosen = [int(c) for c in start]
    current = _mean_bits(validation, chosen)
    for _ in range(rounds):
        improved = False
        for i in range(len(chosen)):
            left = [c for c in candidates if c not in chosen]
            for c in rng.choice(left, min(tries, len(left)), replace=False).tolist() if left else []:
                trial = chosen[:i] + [int(c)] + chosen[i + 1:]
                value = _mean_bits(validation, trial)
                if value > current + 1e-12:
                    chosen, current, improved = trial, value, True
        if not improved:
            break
    return chosen, current


def _design_job(shared, kind: str, motors: int, draw: int, seed: int) -> dict:
    search, validation, test, candidates, rounds, tries, own = shared
    rng = np.random.default_rng(seed)
    if kind == "random":
        places = sorted(int(p) for p in rng.choice(candidates, motors, replace=False))
        return {"places": places, **layout_bits(test, places)}
    start = greedy_layout(search, motors, candidates=candidates, rng=rng, start=() if kind == "designed" else own)
    places, validation_bits = improve_by_swaps(validation, start, candidates=candidates, rounds=rounds, tries=tries,
                                               rng=rng)
    return {"places": places, "start": "greedy" if kind == "designed" else "the glove's own",
            "validation_bits": validation_bits, **layout_bits(test, places)}


class DesignOptions(msgspec.Struct, frozen=True, kw_only=True):
    """What `design_gloves` searches with: the same options give the same layouts (the seed decides every draw)."""
    noise: float                       # the observer's noise on the skin model (psychophysics.HUMAN_NOISE)
    tasks: list[str] | None = None     # the study's tasks scored (None: all of them)
    random_layouts: int = 10           # random layouts per size: the baseline a design must beat
    rounds: int = 2                    # swap rounds on validation after the greedy steps (0: greedy only)
    tries: int = 10                    # places tried per motor and round of swaps
    scenes: int = 16                   # scenes per task in each set of examples (search, validation, test)
    positions: int = 12                # hand positions per scene in each set of examples
    seed: int = 0                      # the examples' and the searches' draws


def design_gloves(glove: Glove, study: Study, sizes: list[int], *, options: DesignOptions, candidates=None,
                  cluster: Cluster = Cluster(), cache=None, progress: bool = True) -> dict:
    """Designed layouts of each size in `sizes` (at the glove's own motor count also one searched from
    its own layout, the better on validation kept; `starts` holds both), `options.random_layouts` random ones of
    each, and the glove's own layout, all scored on the test examples (bits per task and their mean)."""
    o = options
    noise, random_layouts, rounds, tries, seed = o.noise, o.random_layouts, o.rounds, o.tries, o.seed
    tasks = o.tasks or [t.id for t in study.tasks]
    pool = list(range(len(glove.samples))) if candidates is None else list(candidates)
    too_many = [k for k in sizes if k > len(pool)]
    if too_many:
        raise ConfigError("command line", "--motors", f"at most {len(pool)} motors (the glove's sample points "
                          "to place them at, in the regions chosen)", got=too_many[0])
    settings = {"noise": noise, "scenes": o.scenes, "positions": o.positions, "seed": seed}
    search, validation, test = (examples(glove, study, tasks, purpose=p, **settings) for p in PURPOSES)
    own = sorted(set(int(s) for s in glove.motor_sample))
    jobs = {f"designed-{k}": ("designed", k, 0, seed_of(study, DESIGN, f"designed-{k}", 0, seed)) for k in sizes}
    jobs.update({f"from-own-{k}": ("from-own", k, 0, seed_of(study, DESIGN, f"from-own-{k}", 0, seed))
                 for k in sizes if k == len(glove.motor_names) and set(own) <= set(pool)})
    jobs.update({f"random-{k}-{r}": ("random", k, r, seed_of(study, DESIGN, f"random-{k}", r, seed))
                 for k in sizes for r in range(random_layouts)})
    done = fan_out(_design_job, jobs, shared=(search, validation, test, pool, rounds, tries, own), cluster=cluster,
                   cache=cache, label="layouts", progress=progress)
    result = {"study": study.name, "tasks": tasks, "noise": noise, "glove": glove.path,
              "own": {"motors": len(glove.motor_names), "places": own, **layout_bits(test, own)}, "sizes": {}}
    for k in sizes:
        randoms = [done[f"random-{k}-{r}"]["mean_bits"] for r in range(random_layouts)]
        starts = [done[key] for key in (f"designed-{k}", f"from-own-{k}") if key in done]
        result["sizes"][k] = {"designed": max(starts, key=lambda d: d["validation_bits"]),   # first on a tie
                              "starts": {d["start"]: d for d in starts},
                              "random_mean_bits": float(np.mean(randoms)) if randoms else None,
                              "random_sd_bits": float(np.std(randoms, ddof=1)) if len(randoms) > 1 else None,
                              "random_best_bits": float(np.max(randoms)) if randoms else None}
    return result


def glove_file_of(base_path, glove: Glove, places: list[int]) -> dict:
    """The glove file (as a mapping) of `base_path` with its motors at the sample points `places`:
    motor k on board 1 + k // 8, channel k % 8, and as many 8-channel boards as that takes."""
    import yaml

    data = yaml.safe_load(Path(base_path).read_text())
    data["motors"] = [{"name": f"m{k + 1:02d}-sample-{p}", "position": [round(float(c), 6) for c in glove.samples[p]],
                       "board": 1 + k // 8, "channel": k % 8} for k, p in enumerate(places)]
    can = dict(data.get("can") or {})
    can["boards"] = [{"id": b + 1, "channels": 8} for b in range((len(places) + 7) // 8)]
    data["can"] = can
    return data


def write_glove(path, base_path, glove: Glove, places: list[int]) -> tuple[Path, Path]:
    """Write the designed glove file and its DBC (same name, .dbc); both are checked by loading them."""
    import yaml

    from touch4d.boards.config import load_glove_can
    from touch4d.boards.dbc import dbc_text
    from touch4d.tactile import load_glove

    path = Path(path)
    header = (f"# A glove designed by touch4d glove design: {len(places)} motors at sample points of the hand\n"
              f"# of {base_path}. Its CAN frames: {path.with_suffix('.dbc').name} (touch4d glove dbc).\n")
    path.write_text(header + yaml.safe_dump(glove_file_of(base_path, glove, places), sort_keys=False,
                                                default_flow_style=None))
    load_glove(path)
    dbc = path.with_suffix(".dbc")
    dbc.write_bytes(dbc_text(load_glove_can(path)).encode())
    return path, dbc


def summary_text(result: dict) -> str:
    own = result["own"]
    lines = [f"{result['study']}: bits per touch on test examples, mean over tasks {', '.join(result['tasks'])} (noise "
             f"{result['noise']:.3g}); the glove's own {own['motors']} motors: {own['mean_bits']:.3f}",
             f"{'motors':>6} {'designed':>9} {'random (mean +- sd, best)':>28}  per task (designed)"]
    for k, size in result["sizes"].items():
        sd = size["random_sd_bits"]
        random = "-" if size["random_mean_bits"] is None else (
            f"{size['random_mean_bits']:.3f}" + (f" +- {sd:.3f}" if sd is not None else "")
            + f", {size['random_best_bits']:.3f}")
        tasks = " ".join(f"{t} {b:.2f}" for t, b in size["designed"]["bits"].items())
        start = f" (from {size['designed']['start']})" if len(size.get("starts", {})) > 1 else ""
        lines.append(f"{k:>6} {size['designed']['mean_bits']:>9.3f} {random:>28}  {tasks}{start}")
    return "\n".join(lines)


__all__ = ["Examples", "examples", "sample_regions", "candidates_in", "layout_bits", "greedy_layout", "step_sample",
           "improve_by_swaps", "DesignOptions", "design_gloves",
           "glove_file_of", "write_glove", "summary_text"]
