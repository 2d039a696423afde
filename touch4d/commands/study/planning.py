"""`touch4d study power` and `touch4d study fit`: plan a study before recruiting (many simulations,
on Dask: `--workers N` local processes or `--scheduler tcp://HOST:8786`)."""
from __future__ import annotations

import json
import time
from pathlib import Path

from touch4d.configfile import COMMAND_LINE, resolve_path
from touch4d.errors import ConfigError

from .common import clean, count0, nonnegative


def register(sub, *, count, count0, probability) -> None:
    """Add `power` and `fit` to `touch4d study`'s subcommands (`count` etc.: cli's argument types)."""
    power = sub.add_parser("power", help="participants needed: power by simulating whole studies",
                           description="For each number of participants, simulate whole studies (participants "
                                       "drawn from a pilot's fit, or the default observers) and analyse each as "
                                       "`study analyze` does (GEE, mixed model, psychometric fit): the power to "
                                       "find each condition effect per task and the tilt threshold's interval "
                                       "width. Writes DIR/power.json and DIR/report.html; an interrupted run "
                                       "resumes from DIR/cache.")
    power.add_argument("study", metavar="STUDY", help="study file, or its name in config/studies/ (paper)")
    power.add_argument("--fit", metavar="FIT.json", help="the population of a pilot (touch4d study fit --out)")
    power.add_argument("--participants", type=_sizes, default=[4, 8, 12, 16, 24], metavar="N,N,...",
                       help="sample sizes (default 4,8,12,16,24)")
    power.add_argument("--simulations", type=count, default=500, metavar="N",
                       help="simulated studies per size (default 500)")
    power.add_argument("--seed", type=int, default=0, metavar="S")
    power.add_argument("--out", metavar="DIR", help="output folder (default power-<study name>)")
    power.add_argument("--glove", metavar="FILE", help="glove file (default: config/glove.yaml); with --fit it "
                                                      "must be the glove the fit's pilot ran with")
    power.add_argument("--glove-differs-ok", action="store_true",
                       help="draw participants from a --fit made with another glove than --glove (refused otherwise)")
    power.add_argument("--quick", action="store_true", help="quick sessions (one trial per task x condition x "
                                                            "stimulus) and lighter-trained observers")
    power.add_argument("--bootstrap", type=count0, default=100, metavar="N",
                       help="bootstrap resamples for the tilt threshold's interval (default 100)")
    power.add_argument("--alpha", type=probability, default=0.05, metavar="A", help="test level (default 0.05)")
    power.add_argument("--mixed", action="store_true", help="also the mixed-effects model (slow; its variational "
                                                            "intervals are too narrow: plan on the GEE)")
    power.add_argument("--samples", type=count, default=1000, metavar="N",
                       help="simulated trials per stimulus behind the observer's answer shares (default 1000)")
    power.add_argument("--exact", action="store_true", help="run the observer's whole pipeline on every trial of "
                                                            "every participant (slow) instead of its answer shares")
    power.add_argument("--json", action="store_true", help="print the result as JSON")
    add_cluster_options(power)
    power.set_defaults(func=run_power)

    fit = sub.add_parser("fit", help="fit a pilot: each participant's touch noise, visual noise and lapse",
                         description="From a pilot's trials.csv files: each participant's touch noise, visual "
                                     "noise and lapse by maximum likelihood under the model observer (its "
                                     "accuracy simulated on a grid of noises), with 95% profile intervals, and the "
                                     "population's spread. --out FIT.json feeds `study power --fit`.")
    fit.add_argument("dir", metavar="PILOT_DIR", help="folder of the pilot's session folders (trials.csv each)")
    fit.add_argument("--study", metavar="STUDY", help="study file or packaged name (default: the one the sessions' manifest.json names)")
    fit.add_argument("--glove", metavar="FILE", help="glove file (default: the one the sessions' manifest.json "
                                                    "names; another one is refused without --glove-differs-ok)")
    fit.add_argument("--glove-differs-ok", action="store_true",
                     help="fit with a --glove other than the one the pilot ran with (its noises then describe "
                          "that glove's touch, not the pilot's)")
    fit.add_argument("--points", type=count, default=7, metavar="N",
                     help="grid points per noise axis of the simulated accuracy (default 7)")
    fit.add_argument("--trials", type=count, default=60, metavar="N",
                     help="simulated trials per grid point (default 60)")
    fit.add_argument("--seed", type=int, default=0, metavar="S")
    fit.add_argument("--out", metavar="FIT.json", help="write the fit here (for study power --fit)")
    fit.add_argument("--json", action="store_true", help="print the fit as JSON")
    add_cluster_options(fit)
    fit.set_defaults(func=run_fit)


def register_glove_design(sub) -> None:
    """`touch4d glove design`: K motor places chosen for a study (touch4d.study.glovedesign)."""
    import argparse

    def motors(text):
        value = _workers(text)
        if value < 1:
            raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text}")
        return value

    design = sub.add_parser("design", help="choose K motor places for a study, write a working glove file",
                            description="Choose K actuator places among the hand's sample points to maximise the "
                                        "bits one touch tells about the study's stimuli (study transfer's measure, "
                                        "mean over tasks) by greedy forward selection, then swaps judged on "
                                        "separate validation examples; write the glove "
                                        "file (boards and channels assigned) and its DBC; compare with random "
                                        "layouts of K and the glove's own layout.")
    design.add_argument("--motors", required=True, type=motors, metavar="K", help="number of motors")
    design.add_argument("--study", required=True, metavar="STUDY", help="study file, or its name in config/studies/ (paper)")
    design.add_argument("--glove", metavar="FILE", help="the glove to redesign (default: config/glove.yaml)")
    design.add_argument("--task", action="append", metavar="ID", help="only this task (repeatable)")
    design.add_argument("--regions", nargs="+", metavar="REGION",
                        help="place motors only here: palm, back, thumb, index, middle, ring, little (default: "
                             "anywhere on the hand)")
    design.add_argument("--noise", type=nonnegative, default=None, metavar="X",
                        help="sensory noise of a finger's motors (default: the fingertip's; the palm's: x0.64, "
                             "touch4d.study.psychophysics)")
    design.add_argument("--random", type=count0, default=10, metavar="N",
                        help="random layouts to compare (default 10)")
    design.add_argument("--rounds", type=count0, default=2, metavar="N",
                        help="swap passes after the greedy steps (default 2)")
    design.add_argument("--tries", type=count0, default=10, metavar="N",
                        help="other places tried for each chosen one in a swap pass (default 10)")
    design.add_argument("--scenes", type=motors, default=16, metavar="N",
                        help="jittered scenes per stimulus in each set of examples (default 16)")
    design.add_argument("--positions", type=motors, default=12, metavar="N", help="hand positions per scene (default 12)")
    design.add_argument("--seed", type=int, default=0, metavar="S")
    design.add_argument("-o", "--output", required=True, metavar="NEW.yaml", help="the designed glove file")
    design.add_argument("--json", action="store_true", help="print the comparison as JSON")
    add_cluster_options(design)
    design.set_defaults(func=run_glove_design)


def run_glove_design(args) -> int:
    from touch4d.study.glovedesign import DesignOptions, candidates_in, design_gloves, summary_text, write_glove
    from touch4d.study.infotransfer import POSITIONS, SCENES
    from touch4d.study.psychophysics import HUMAN_NOISE

    study = _study(args.study)
    glove = _glove(args.glove)
    tasks = [study.task(t).id for t in args.task] if args.task else None
    options = DesignOptions(tasks=tasks, noise=HUMAN_NOISE if args.noise is None else args.noise,
                            random_layouts=args.random, rounds=args.rounds, tries=args.tries, scenes=args.scenes,
                            positions=args.positions, seed=args.seed)
    result = design_gloves(glove, study, [args.motors], options=options,
                           candidates=candidates_in(glove, args.regions), cluster=cluster_of(args),
                           progress=not args.json)
    places = result["sizes"][args.motors]["designed"]["places"]
    path, dbc = write_glove(args.output, glove.path, glove, places)
    result.update({"output": str(path), "dbc": str(dbc)})
    noise = result["noise"]
    again = (f"touch4d study transfer {study.path} --glove {path}" + "".join(f" --task {t}" for t in args.task or [])
             + (f" --noise {noise:g}" if args.noise is not None else "") + (f" --seed {args.seed}" if args.seed else ""))
    result["transfer"] = written_transfer(path, study, result["tasks"], noise=noise, seed=args.seed)
    result["transfer_command"] = again
    if args.json:
        print(json.dumps(clean(result)))
    else:
        print(summary_text(result))
        print(f"{again}: " + " ".join(f"{t} {b:.3f}" for t, b in result["transfer"].items())
              + f" (its own {SCENES} scenes x {POSITIONS} positions a stimulus; the table's per-task bits are the "
              f"same measure on the design's test set, {args.scenes} x {args.positions}: other random examples, "
              "so they differ by their sampling error)")
        print(f"glove: {path} (DBC {dbc})")
    return 0


def written_transfer(path, study, tasks, *, noise: float, seed: int) -> dict:
    """Per task, the bits `study transfer --glove PATH` predicts for a designed glove's file (its
    defaults: `infotransfer.SCENES` x `POSITIONS` examples), as it would print them."""
    from touch4d.tactile import load_glove

    from touch4d.study.infotransfer import predicted_transfer

    glove = load_glove(path)
    return {task: predicted_transfer(glove, study, task, noise=noise, seed=seed)["bits"] for task in tasks}


def add_cluster_options(parser) -> None:
    group = parser.add_argument_group("where the simulations run (Dask)")
    where = group.add_mutually_exclusive_group()
    where.add_argument("--workers", type=_workers, default=None, metavar="N",
                       help="local worker processes (default: one per core; 0: in this process, no Dask)")
    where.add_argument("--scheduler", metavar="ADDRESS", help="a Dask cluster's scheduler, e.g. tcp://HOST:8786")


def cluster_of(args):
    from touch4d.study.fanout import Cluster

    return Cluster(workers=args.workers, scheduler=args.scheduler)


def _study(path):
    """The study a command was given: a file, or a packaged study's name (`design.load_study`, which
    resolves it by `study_file_path` as every study command does)."""
    from touch4d.study.design import load_study

    return load_study(path or None)


def _glove(path):
    from touch4d.tactile import load_glove

    return load_glove(resolve_path(path, COMMAND_LINE, key="--glove", what="glove file") if path else None)


def read_fit(path) -> dict:
    """A fit file (touch4d study fit --out) as a dict; a file that is not one is a ConfigError naming it."""
    path = resolve_path(path, COMMAND_LINE, key="--fit", what="fit file")
    try:
        fit = json.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ConfigError(path, "(file)", "a JSON fit file written by touch4d study fit --out",
                          got=str(exc).splitlines()[0]) from None
    if not isinstance(fit, dict):
        raise ConfigError(path, "(file)", "a JSON object written by touch4d study fit --out", got=type(fit).__name__)
    return fit


def run_power(args) -> int:
    from touch4d.study.observer import ModelObserver
    from touch4d.study.power import Population, PowerSetup, power_curves, report_html, summary_text

    study = _study(args.study)
    fit = read_fit(args.fit) if args.fit else None
    population = Population.from_fit(fit, study, args.fit) if fit else Population()
    glove = _glove(args.glove)
    if fit:
        check_fit_glove(fit, glove, args.fit, args.glove_differs_ok)
    out = Path(args.out or f"power-{study.name}")
    training = {"train_scenes": 4, "train_positions": 8, "view_scenes": 8} if args.quick else {}
    observer = ModelObserver(glove, study, noise=population.noise, visual_noise=population.visual_noise,
                             lapse=population.lapse, seed=args.seed, **training).train()
    setup = PowerSetup(observer, glove, study, population, quick=args.quick, bootstrap=args.bootstrap,
                       seed=args.seed, alpha=args.alpha, mixed=args.mixed, exact=args.exact, samples=args.samples)
    started = time.perf_counter()
    cluster = cluster_of(args)
    try:
        result = power_curves(setup, args.participants, args.simulations, cluster=cluster, out=out,
                              progress=not args.json)
    except KeyboardInterrupt:
        print(f"interrupted: the finished simulations are kept under {out / 'cache'}; the same command resumes")
        return 130
    result["seconds"] = time.perf_counter() - started
    result["ran_on"] = cluster.describe()
    out.mkdir(parents=True, exist_ok=True)
    (out / "power.json").write_text(json.dumps(clean(result), indent=1) + "\n")
    (out / "report.html").write_text(report_html(result))
    if args.json:
        print(json.dumps(clean(result)))
    else:
        print(summary_text(result))
        print(f"{result['seconds']:.1f} s on {result['ran_on']}; report: {out / 'report.html'}")
    return 0


def pilot_manifests(where) -> list[tuple[Path, dict]]:
    """Each session's manifest.json of a pilot (those that read as a JSON object) with its path."""
    from touch4d.study.table import find_tables

    out = []
    for table in find_tables(where):
        manifest = table.parent / "manifest.json"
        try:
            data = json.loads(manifest.read_text())
        except (OSError, ValueError):
            continue
        if isinstance(data, dict):
            out.append((manifest, data))
    return out


def pilot_study(where, given):
    """The study of a pilot: `given`, or the study file its sessions' manifest.json names; a pilot of
    another study than `given` is a ConfigError."""
    from touch4d.study.design import load_study

    named = {str(data["study"]): data.get("study_file") for _, data in pilot_manifests(where) if "study" in data}
    if given:
        study = _study(given)
        if named and study.name not in named:
            raise ConfigError(given, "name", f"the study of the pilot's sessions ({', '.join(sorted(named))})",
                              got=study.name)
        return study
    if len(named) != 1 or not next(iter(named.values())):
        raise ConfigError(COMMAND_LINE, "--study", "the pilot's study file (its sessions' manifest.json name "
                          + ("several studies" if len(named) > 1 else "none") + ")")
    return load_study(next(iter(named.values())))


EVERY_SAMPLE = " (a motor at every sample)"      # observer.every_sample_glove's mark on a glove's path


def glove_record(glove) -> dict:
    """What a result records of the glove it was computed with: its file, the file's sha256, and
    whether it was given a motor at every sample (`every_sample_glove`)."""
    from touch4d.study.manifest import sha256_file

    base = str(glove.path).removesuffix(EVERY_SAMPLE)
    return {"glove": str(glove.path), "glove_sha256": sha256_file(base) if Path(base).is_file() else None,
            "every_sample": str(glove.path).endswith(EVERY_SAMPLE)}


def pilot_glove(where, given, differs_ok: bool = False):
    """The glove a pilot ran with, as its sessions' manifest.json name it (`glove_file`,
    `glove_sha256`); `given` (--glove) that is another glove is a ConfigError unless `differs_ok`
    (then a warning). Sessions that name no glove: `given`, or the default, with a note."""
    import sys

    from touch4d.study.observer import every_sample_glove

    ran = {}
    for manifest, data in pilot_manifests(where):
        if isinstance(data.get("glove_file"), str) and data["glove_file"]:
            ran.setdefault((data["glove_file"], data.get("glove_sha256")), manifest)
    if len(ran) > 1:
        raise ConfigError(where, "manifest.json: glove_file", "a pilot whose sessions ran with one glove",
                          got="; ".join(f"{file} ({manifest.parent.name})" for (file, _), manifest in ran.items()))
    if not ran:
        glove = _glove(given)
        print(f"note: the pilot's sessions name no glove (manifest.json glove_file): fitting with {glove.path}",
              file=sys.stderr)
        return glove
    (file, sha), manifest = next(iter(ran.items()))
    if given:
        glove = _glove(given)
        record = glove_record(glove)
        ran_as = {"glove_sha256": sha or _sha256_or_none(file.removesuffix(EVERY_SAMPLE)),
                  "every_sample": file.endswith(EVERY_SAMPLE)}
        if record["glove_sha256"] == ran_as["glove_sha256"] and not ran_as["every_sample"]:
            return glove
        if not differs_ok:
            raise ConfigError(COMMAND_LINE, "--glove", f"the glove the pilot ran with ({file}, {manifest})",
                              got=given, hint="leave --glove out to fit with the pilot's glove, or add "
                                              "--glove-differs-ok to fit it with another glove on purpose")
        print(f"warning: fitting with {glove.path}, not the glove the pilot ran with ({file}): --glove-differs-ok",
              file=sys.stderr)
        return glove
    glove = _glove_at(file.removesuffix(EVERY_SAMPLE), manifest)
    if sha and glove_record(glove)["glove_sha256"] != sha:
        print(f"warning: {glove.path} changed since the pilot ran with it ({manifest}: glove_sha256)", file=sys.stderr)
    return every_sample_glove(glove) if file.endswith(EVERY_SAMPLE) else glove


def _glove_at(path, manifest):
    from touch4d.tactile import load_glove

    return load_glove(resolve_path(path, manifest, key="glove_file", what="glove file"))


def _sha256_or_none(path):
    from touch4d.study.manifest import sha256_file

    return sha256_file(path) if Path(path).is_file() else None


def check_fit_glove(fit: dict, glove, path, differs_ok: bool = False) -> None:
    """`study power --fit`: the fit's participants felt the study's glove, or `differs_ok` says
    otherwise is meant (a warning); a fit that records no glove is used with a warning."""
    import sys

    if not fit.get("glove_sha256") and not fit.get("glove"):
        print(f"warning: {path} records no glove (written before fits did): its noises may be another glove's",
              file=sys.stderr)
        return
    ours = glove_record(glove)
    if fit.get("glove_sha256") == ours["glove_sha256"] and bool(fit.get("every_sample")) == ours["every_sample"]:
        return
    if not differs_ok:
        raise ConfigError(path, "glove", f"a fit made with the study's glove ({glove.path})", got=fit.get("glove"),
                          hint="--glove the fit's glove, or --glove-differs-ok to draw participants fitted "
                               "with another glove on purpose")
    print(f"warning: {path} was fitted with {fit.get('glove')}, the study runs {glove.path}: --glove-differs-ok",
          file=sys.stderr)


def run_fit(args) -> int:
    from touch4d.study.analysis import load
    from touch4d.study.observer import ModelObserver
    from touch4d.study.pilotfit import accuracy_surface, fit_pilot, summary_text
    from touch4d.study.psychophysics import HUMAN_NOISE

    data = load(args.dir)
    if len(data) == 0:
        raise ConfigError(args.dir, "trials.csv", "a pilot with trials (not only practice trials)", got="none")
    study = pilot_study(args.dir, args.study)
    glove = pilot_glove(args.dir, args.glove, args.glove_differs_ok)
    observer = ModelObserver(glove, study, noise=HUMAN_NOISE, seed=args.seed).train()
    cache = (Path(args.out).parent if args.out else Path(args.dir)) / "cache"
    try:
        surface = accuracy_surface(observer, glove, study, points=args.points, trials=args.trials, seed=args.seed,
                                   cluster=cluster_of(args), cache=cache, progress=not args.json)
    except KeyboardInterrupt:
        print(f"interrupted: the finished simulations are kept under {cache}; the same command resumes")
        return 130
    fit = fit_pilot(surface, data, seed=args.seed)
    fit.update({"study_file": study.path, **glove_record(glove), "pilot": str(args.dir), "surface": surface.to_json()})
    if args.out:
        Path(args.out).write_text(json.dumps(clean(fit), indent=1) + "\n")
    if args.json:
        print(json.dumps(clean(fit)))
    else:
        print(summary_text(fit))
        if args.out:
            print(f"fit: {args.out}; next: touch4d study power {study.path} --fit {args.out}")
    return 0


def _sizes(text: str) -> list[int]:
    import argparse

    try:
        sizes = [int(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected sizes such as 4,8,12, got {text!r}") from None
    if not sizes or min(sizes) < 2:
        raise argparse.ArgumentTypeError(f"expected sizes of 2 or more participants, got {text!r}")
    return sorted(set(sizes))


def _workers(text: str) -> int:
    import argparse

    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text}")
    return value
