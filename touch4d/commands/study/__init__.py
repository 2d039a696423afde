"""`touch4d study`: check a study file, plan a participant's session, run a study (simulated
participants offline, or through the full stack), analyse its trials."""
from __future__ import annotations

import importlib
import json
import time
from contextlib import ExitStack
from pathlib import Path

from touch4d.configfile import COMMAND_LINE, resolve_path
from touch4d.errors import ConfigError, Unavailable

from .common import clean as _clean, count as _count, count0 as _count0, nonnegative as _nonnegative
from .common import probability as _probability


def register(subparsers) -> None:
    """`touch4d study` and its sub-commands (those before recruiting: .planning)."""
    study = subparsers.add_parser("study", help="studies with many participants: check, plan, run, analyze",
                                  description="Measure what touch adds to vision: study files, participants' "
                                              "plans, simulated participants and the analysis.")
    sub = study.add_subparsers(dest="study_command", metavar="SUBCOMMAND")
    study.set_defaults(func=lambda args: (study.print_help(), 2)[1])
    for add in (_add_check, _add_plan, _add_run, _add_serve, _add_invite, _add_transfer, _add_analyze, _add_export):
        add(sub)

    from . import planning     # power and fit: before recruiting

    planning.register(sub, count=_count, count0=_count0, probability=_probability)


class _Later:
    """A module's constant named in a help text, read only when the help is printed (its module is
    slow to import; argparse formats `%(name)s` from the action's attributes)."""

    def __init__(self, module: str, name: str):
        self.module, self.name = module, name

    def __str__(self) -> str:
        return str(getattr(importlib.import_module(self.module), self.name))




def _add_check(sub) -> None:
    """The parser of `study check`."""
    check = sub.add_parser("check", help="check a study file and summarise it",
                           description="Read a study file (and every scene it names); print what a session holds.")
    check.add_argument("file", metavar="FILE", help="study file (YAML), e.g. config/studies/paper.yaml, or its name (paper)")
    check.add_argument("--glove", metavar="FILE", help="also warn of each task this glove cannot tell by touch "
                       "(its predicted bits, as study transfer --glove, under a tenth of the task's)")
    check.set_defaults(func=run_check)


def _add_plan(sub) -> None:
    """The parser of `study plan`."""
    plan = sub.add_parser("plan", help="one participant's trials, in order",
                          description="The condition order and every trial of a participant's session, from the "
                                      "study and the participant id alone (P01, P02 ... take the counterbalancing "
                                      "rows in turn).")
    plan.add_argument("study", metavar="STUDY", help="study file, or its name in config/studies/ (paper)")
    plan.add_argument("--participant", required=True, metavar="ID", help="participant id, e.g. P01")
    plan.add_argument("--quick", action="store_true", help="one repetition per task x condition cell, no practice")
    plan.add_argument("--order", type=_count, metavar="N", help="counterbalancing row N (from 1) instead of the id's")
    plan.add_argument("--json", action="store_true", help="print JSON (a stable interface for scripts)")
    plan.set_defaults(func=run_plan)


def _add_run(sub) -> None:
    """The parser of `study run`."""
    from touch4d.study.psychophysics import HUMAN_NOISE   # the observers' one default touch noise

    run = sub.add_parser("run", help="run a study: simulated participants, or a participant through the stack",
                         description="--simulate --participants N: N model observers (P01 ...) answer every "
                                     "trial; --offline runs them on the library alone (no bus), else through the "
                                     "full stack. --participant ID: a real participant's session.")
    run.add_argument("study", metavar="STUDY", help="study file, or its name in config/studies/ (paper)")
    run.add_argument("items", nargs="*", metavar="ROLE:=NODE",
                     help="full stack: launch overrides, as for touch4d launch (tracker:=webxr, renderer:=none, "
                          "study.iti_s:=1, ...)")
    who = run.add_mutually_exclusive_group(required=True)
    who.add_argument("--simulate", action="store_true", help="simulated participants (model observers)")
    who.add_argument("--participant", metavar="ID", help="a participant's session through the full stack")
    run.add_argument("--participants", type=_count, default=6, metavar="N", help="simulated participants (default 6)")
    run.add_argument("--seed", type=int, default=0, metavar="S", help="the simulation's seed (default 0)")
    run.add_argument("--quick", action="store_true", help="one repetition per task x condition cell, no practice")
    run.add_argument("--out", required=True, metavar="DIR", help="output folder: one session folder per participant")
    run.add_argument("--offline", action="store_true", help="simulate on the library alone, without a bus")
    run.add_argument("--order", type=_count, metavar="N",
                     help="--participant: counterbalancing row N (from 1; default: P01, P02, ... take the rows in turn)")
    run.add_argument("--overwrite", action="store_true",
                     help="replace this run's session folders in --out that ran another study or other settings")
    run.add_argument("--bus", metavar="FILE",
                     help="--participant: the bus config the stack launches with (default: $TOUCH4D_BUS, else "
                          "config/bus.yaml); other ports when another stack holds those")
    sim = run.add_argument_group("model observers (--simulate)")
    sim.add_argument("--glove", metavar="FILE", help="glove file (default: config/glove.yaml)")
    sim.add_argument("--every-sample", action="store_true",
                     help="a motor at every sample point of the glove (the finest actuator resolution)")
    sim.add_argument("--noise", type=_nonnegative, default=HUMAN_NOISE, metavar="X",
                     help=f"sensory noise on a finger's motors, in units of full drive (default {HUMAN_NOISE:.3f}: "
                          "the fingertip's amplitude discrimination; the palm's motors: x0.64, the thenar's)")
    sim.add_argument("--visual-noise", type=_nonnegative, default=0.5, metavar="X",
                     help="noise on the view's features (default 0.5)")
    sim.add_argument("--lapse", type=_probability, default=0.03, metavar="P", help="lapse rate (default 0.03)")
    sim.add_argument("--spread", type=_nonnegative, default=0.25, metavar="X",
                     help="between-participant spread of the noise, sd of its log (default 0.25)")
    run.set_defaults(func=run_run)


def _add_serve(sub) -> None:
    """The parser of `study serve`."""
    serve = sub.add_parser("serve", help="a study server: participants join by a link, many at once",
                           description="Participants join from their own headset's browser by a link "
                                       "(`touch4d study invite`); each is a session in this server's process "
                                       "(their page computes its touch itself), writing DIR/ID/ as `study run` "
                                       "does. Prints the experimenter's link. Behind a reverse proxy with a real "
                                       "certificate: --public-url.")
    serve.add_argument("study", metavar="STUDY", help="study file, or its name in config/studies/ (paper)")
    serve.add_argument("--out", required=True, metavar="DIR", help="output folder: links, one session folder each")
    serve.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1)")
    serve.add_argument("--port", type=int, default=8095, help="TCP port (default 8095; 0: any free one)")
    max_participants = serve.add_argument(
        "--max-participants", type=_count, default=None, metavar="N",
        help="participants running at once; one more gets a page that says so (HTTP 503). Default: "
             "%(server_default)s per CPU core (bench/bench_serve.py)")
    max_participants.server_default = _Later("touch4d.web.studyserver", "PARTICIPANTS_PER_CORE")
    serve.add_argument("--public-url", metavar="URL", help="the address participants use (a reverse proxy's https URL)")
    serve.add_argument("--leave-after", type=_nonnegative, default=30.0, metavar="S",
                       help="a participant without a page this long has left: their session stops (default 30)")
    serve.add_argument("--quick", action="store_true", help="one repetition per task x condition cell, no practice")
    serve.add_argument("--glove", default="config/gloves/quest-controller.yaml", metavar="FILE",
                       help="the participants' glove file (default: the Quest controller as the glove)")
    serve.add_argument("--calibration", default="config/calibration.yaml", metavar="FILE",
                       help="where the screen stands in the room until a participant re-centres it")
    serve.add_argument("--iti", type=_nonnegative, default=0.6, metavar="S", help="blank time between trials (default 0.6)")
    serve.add_argument("--no-glove-check", action="store_true",
                       help="at start, do not say which tasks the glove cannot tell (a process of seconds of simulation "
                            "at the lowest priority; `touch4d study check STUDY --glove FILE` says the same)")
    recruit = serve.add_argument_group("recruiting online (docs/serving.md, \"A remote study from serve to export\")")
    recruit.add_argument("--open-link", action="store_true",
                         help="print one link for many: each visitor becomes a participant of their own (P01, P02, "
                              "...: the least-filled counterbalancing row next)")
    recruit.add_argument("--max-total", type=_count, default=None, metavar="N",
                         help="the open link admits no one once N participants are done or under way")
    recruit.add_argument("--id-param", action="append", default=[], metavar="NAME",
                         help="a platform's query parameter kept in the manifest's `platform` beside PROLIFIC_PID, "
                              "STUDY_ID and SESSION_ID (repeatable; the first given names the person when "
                              "PROLIFIC_PID is absent)")
    recruit.add_argument("--complete-url", metavar="URL", help="where a participant who did every trial goes")
    recruit.add_argument("--completion-code", metavar="CODE", help="appended to --complete-url as ?cc=CODE (Prolific)")
    recruit.add_argument("--return-url", metavar="URL",
                         help="where a participant who quits, or whose device fails the check, goes")
    serve.set_defaults(func=run_serve)


def _add_invite(sub) -> None:
    """The parser of `study invite`."""
    invite = sub.add_parser("invite", help="a participant's link to a served study (a new token each time)",
                            description="Prints the link (and a QR code) for participant ID of the study "
                                        "served with --out DIR; a second invite replaces the first link (the browsers "
                                        "it opened are refused and its stack stops).")
    invite.add_argument("dir", metavar="DIR", help="the --out folder of `touch4d study serve`")
    invite.add_argument("participant", metavar="ID", nargs="?", help="participant id, e.g. P07")
    invite.add_argument("--experimenter", action="store_true",
                        help="a new experimenter's link instead (the old one and the browsers it opened stop working)")
    invite.add_argument("--public-url", metavar="URL", help="the server's address (default: the one it last served)")
    invite.add_argument("--revoke", action="store_true", help="revoke the participant's link instead")
    invite.add_argument("--no-qr", action="store_true", help="the link only")
    invite.set_defaults(func=run_invite)


def _add_transfer(sub) -> None:
    """The parser of `study transfer`."""
    from touch4d.study.psychophysics import HUMAN_NOISE   # the observers' one default touch noise

    transfer = sub.add_parser("transfer", help="bits one touch tells about each task's stimuli, with a glove",
                              description="Before recruiting anyone: the information transferred (bits, "
                                          "maximum-likelihood from the confusion matrix) per task by an observer "
                                          "trained on the glove's motor patterns at random hand positions, "
                                          "tested on new scenes and positions.")
    transfer.add_argument("study", metavar="STUDY", help="study file, or its name in config/studies/ (paper)")
    transfer.add_argument("--glove", metavar="FILE", action="append",
                          help="glove file (default: config/glove.yaml); repeat to compare gloves side by side")
    transfer.add_argument("--every-sample", action="store_true",
                          help="also a motor at every sample point of the glove, side by side")
    transfer.add_argument("--task", action="append", metavar="ID", help="only this task (repeatable)")
    transfer.add_argument("--noise", type=_nonnegative, default=HUMAN_NOISE, metavar="X",
                          help=f"sensory noise on a finger's motors, in units of full drive (default {HUMAN_NOISE:.3f}; "
                               "the palm's motors: x0.64)")
    transfer.add_argument("--scenes", type=_count, default=20, metavar="N",
                          help="jittered scenes per stimulus, half of them held out (default 20)")
    transfer.add_argument("--positions", type=_count, default=16, metavar="N",
                          help="hand positions per scene (default 16)")
    transfer.add_argument("--seed", type=int, default=0, metavar="S")
    transfer.add_argument("--json", action="store_true", help="print JSON")
    transfer.set_defaults(func=run_transfer)


def _add_analyze(sub) -> None:
    """The parser of `study analyze`."""
    analyze = sub.add_parser("analyze", help="analyse a study's trials (accuracy, times, psychometric fit, tests)",
                             description="DIR holds session folders, each with trials.csv (or is one, or is a "
                                         "trials.csv). Prints a summary (or JSON) and writes an HTML report.")
    analyze.add_argument("dirs", nargs="+", metavar="DIR", help="folder of sessions, a session folder or a trials.csv; "
                         "several: analysed together (the --out folders of several servers of one study)")
    analyze.add_argument("--json", action="store_true", help="print the results as JSON")
    analyze.add_argument("--report", metavar="FILE", help="HTML report (default: DIR/report.html)")
    analyze.add_argument("--no-report", action="store_true", help="write no HTML report")
    analyze.add_argument("--plot", metavar="FILE", help="also save the summary plot (accuracy, psychometric functions) "
                                                     "as an image, e.g. results.png")
    analyze.add_argument("--bootstrap", type=_count0, default=200, metavar="N",
                         help="bootstrap resamples for the psychometric intervals (default 200; 0: none)")
    analyze.add_argument("--seed", type=int, default=0, metavar="S", help="the bootstrap's seed")
    analyze.add_argument("--by", metavar="FIELD", help="also analyse each group of sessions whose manifests agree "
                         "on FIELD, dotted (version, condition_order, manifest.device.browser)")
    analyze.set_defaults(func=run_analyze)


def _add_export(sub) -> None:
    """The parser of `study export`."""
    export = sub.add_parser("export", help="a study's sessions as a dataset others can read (Psych-DS)",
                            description="DIR holds session folders (trials.csv, manifest.json, MCAP logs). Writes a "
                                        "Psych-DS dataset: dataset_description.json, data/*_data.csv (one per "
                                        "participant and session), each session's manifest and logs in "
                                        "data/primary_data/.")
    export.add_argument("dir", metavar="DIR", help="folder of sessions, a session folder or a trials.csv")
    export.add_argument("--psych-ds", required=True, metavar="OUT", help="the dataset's folder: new or empty")
    export.add_argument("--force", action="store_true", help="replace OUT if it holds an earlier export")
    export.set_defaults(func=run_export)


def _study(path):
    """The study a command was given: a file, or a packaged study's name (`design.study_file_path`)."""
    from touch4d.study.design import load_study

    return load_study(path or None)


def _study_path(path):
    """The file of the study a command was given (`design.study_file_path`, as `_study` reads it)."""
    from touch4d.study.design import study_file_path

    return study_file_path(path)


def run_check(args) -> int:
    from touch4d.study.design import session_minutes, study_text_warnings
    from touch4d.study.plan import order_table, plan_session, quick_plan

    study = _study(args.file)
    trials = plan_session(study, "P01")
    main = [t for t in trials if not t.practice]
    print(f"{study.path}: study '{study.name}' is valid")
    if study.description:
        print(f"  {study.description.strip()}")
    rows = order_table(study)
    print(f"  conditions: {', '.join(study.conditions)} ({study.counterbalancing()} counterbalancing: "
          f"{len(rows)} orders; participants in multiples of {len(rows)} balance them)")
    for task in study.tasks:
        names = task.stimulus_names()
        count = sum(t.task == task.id for t in main)
        print(f"  task {task.id} ({task.kind}): {len(names)} stimuli ({', '.join(names)}), options "
              f"{'/'.join(task.options)}, {study.repetitions_of(task)} repetitions: {count} trials")
    print(f"  a session: {len(trials)} trials ({len(trials) - len(main)} practice) in {len(study.conditions)} blocks, "
          f"at most {session_minutes(study)} min of trials at the time limit; --quick: "
          f"{len(quick_plan(study, 'P01'))} trials")
    warnings = study_text_warnings(study)
    if args.glove:
        from touch4d.tactile import load_glove

        from touch4d.study.infotransfer import glove_task_warnings

        glove = load_glove(resolve_path(args.glove, COMMAND_LINE, key="--glove", what="glove file"))
        warnings += glove_task_warnings(glove, study)
    for warning in warnings:
        print(f"warning: {warning}")
    return 0


def run_plan(args) -> int:
    import msgspec

    from touch4d.study.plan import condition_order, order_note, order_table, plan_session, quick_plan

    study = _study(args.study)
    row = _row(study, args.participant, args.order)
    trials = (quick_plan if args.quick else plan_session)(study, args.participant, args.order)
    order = condition_order(study, args.participant, args.order)
    if args.json:
        out = {"study": study.name, "study_file": study.path, "participant": args.participant,
               "row": row, "order": row + 1, "condition_order": order,
               "order_note": order_note(study, args.participant, args.order),
               "trials": msgspec.to_builtins(trials)}
        print(json.dumps(_clean(out)))
        return 0
    print(f"{study.name}, participant {args.participant} (counterbalancing row {row + 1} of "
          f"{len(order_table(study))}, --order {row + 1}): {' -> '.join(order)}")
    note = order_note(study, args.participant, args.order)
    if note:
        print(f"note: {note}")
    print(f"{'index':>5} {'block':>5} {'trial':>5}  {'condition':<13} {'task':<12} {'stimulus':<10} {'answer':<8} "
          f"jitter (deg)")
    for t in trials:
        jitter = " ".join(f"{p}{d:+.1f}" for p, d in t.transform)
        flags = (" practice" if t.practice else "") + (" [break before]" if t.break_before else "")
        print(f"{t.index:>5} {t.block:>5} {t.trial:>5}  {t.condition:<13} {t.task:<12} {t.stimulus:<10} "
              f"{t.answer:<8} {jitter}{flags}")
    return 0


def _row(study, participant: str, order: int | None) -> int:
    """The counterbalancing row (from 0) of a participant, `--order` checked against the study's rows."""
    from touch4d.study.plan import order_table, participant_index

    rows = len(order_table(study))
    if order is not None and order > rows:
        raise ConfigError(COMMAND_LINE, "--order", f"a counterbalancing row 1..{rows} (study {study.name})", got=order)
    return participant_index(study, participant, order)


def run_run(args) -> int:
    if args.offline and args.items:
        raise ConfigError(COMMAND_LINE, args.items[0], "no launch overrides with --offline (no stack runs)")
    if args.participant is not None:   # a folder under --out: never outside it
        from touch4d.study.store import PARTICIPANT_ID_RULE, check_participant_id
        try:
            check_participant_id(args.participant)
        except ValueError:
            raise ConfigError(COMMAND_LINE, "--participant", PARTICIPANT_ID_RULE, got=args.participant) from None
    if args.bus is not None and args.simulate:
        raise ConfigError(COMMAND_LINE, "--bus", "--participant ID with --bus (simulations run on a private bus)")
    if args.order is not None and not args.participant:
        raise ConfigError(COMMAND_LINE, "--order", "--participant ID with --order (simulated participants P01, "
                          "P02, ... take the rows in turn)")
    if args.simulate and args.offline:
        return run_offline(args)
    if args.offline:
        raise ConfigError(COMMAND_LINE, "--offline", "--simulate with --offline (a participant needs the stack)")
    return run_full_stack(args)


def run_offline(args) -> int:
    """Simulated participants on the library alone (touch4d.study.simulate)."""
    from touch4d.tactile import load_glove

    from touch4d.study.lock import claim_session
    from touch4d.study.manifest import MANIFEST, prepare_out, sha256_file
    from touch4d.study.observer import every_sample_glove
    from touch4d.study.plan import participant_ids
    from touch4d.study.store import session_dir

    study = _study(args.study)
    glove = load_glove(resolve_path(args.glove, COMMAND_LINE, key="--glove", what="glove file") if args.glove else None)
    settings = {"mode": "offline", "seed": args.seed, "noise": args.noise, "visual_noise": args.visual_noise,
                "lapse": args.lapse, "spread": args.spread, "every_sample": bool(args.every_sample),
                "glove_sha256": sha256_file(glove.path)}
    if args.every_sample:
        glove = every_sample_glove(glove)
    participants = participant_ids(args.participants)
    with ExitStack() as locks:
        for participant in participants:
            locks.enter_context(claim_session(session_dir(args.out, participant)))
        prepare_out(args.out, participants, _settings(study, args.quick, settings), overwrite=args.overwrite)
        again = [p for p in participants if (session_dir(args.out, p) / MANIFEST).exists()]
        if again:
            print(f"{', '.join(again)}: written again (the same study and settings, so the same seeded trials)")
        return _simulate_offline(args, study, glove, participants, settings)


def _simulate_offline(args, study, glove, participants, settings) -> int:
    from touch4d.study.observer import ModelObserver
    from touch4d.study.simulate import simulate_study

    started = time.perf_counter()
    # --quick checks every cell quickly: a lighter-trained observer (its accuracy is not the point)
    training = {"train_scenes": 4, "train_positions": 8, "view_scenes": 8} if args.quick else {}
    observer = ModelObserver(glove, study, noise=args.noise, visual_noise=args.visual_noise, lapse=args.lapse,
                             seed=args.seed, **training)
    folders = simulate_study(study, participants, args.out, glove=glove, seed=args.seed, quick=args.quick,
                             spread=args.spread, observer=observer, settings=settings, echo=print)
    print(f"{len(folders)} simulated sessions in {time.perf_counter() - started:.1f} s under {args.out}; "
          f"next: touch4d study analyze {args.out}")
    return 0


def run_full_stack(args) -> int:
    """A study through the bus: a participant's session, or simulated participants (touch4d.study.session)."""
    try:
        session = importlib.import_module("touch4d.study.session")
    except ModuleNotFoundError as exc:
        if exc.name != "touch4d.study.session":
            raise
        raise Unavailable("running a study through the full stack needs touch4d.study.session; "
                          "--simulate --offline runs simulated participants without it") from None
    from touch4d.study.design import study_file_path
    from touch4d.study.lock import claim_session
    from touch4d.study.manifest import prepare_out, read_manifest
    from touch4d.study.plan import condition_order, order_note, participant_ids
    from touch4d.study.store import session_dir

    study_path = study_file_path(args.study)
    study = _study(study_path)
    participants = participant_ids(args.participants) if args.simulate else [args.participant]
    simulation = None
    if args.simulate:   # what the observers ran with: the tracker's settings (noise, lapse and any override)
        observer = [f"tracker.noise:={args.noise}", f"tracker.lapse:={args.lapse}"]
        simulation = {"mode": "full stack", "seed": args.seed, "noise": args.noise, "lapse": args.lapse,
                      "tracker": sorted(i for i in args.items if i.lstrip("+").startswith("tracker."))}
    else:
        _row(study, args.participant, args.order)
        note = order_note(study, args.participant, args.order)
        if note:
            print(f"note: {note}")
        ran = read_manifest(session_dir(args.out, args.participant)).get("condition_order")
        planned = condition_order(study, args.participant, args.order)
        if ran is not None and ran != planned:
            raise ConfigError(COMMAND_LINE, "--order", f"the order this session ran ({' -> '.join(ran)}) to resume it",
                              got=f"{args.order} ({' -> '.join(planned)})" if args.order else "none",
                              hint="resume with the --order it ran with, or use a new --out")
    try:
        with ExitStack() as locks:
            for participant in participants:
                locks.enter_context(claim_session(session_dir(args.out, participant)))
            prepare_out(args.out, participants, _settings(study, args.quick, simulation), overwrite=args.overwrite)
            if args.simulate:
                options = session.SessionOptions(seed=args.seed, quick=args.quick, simulation=simulation, locked=True)
                return session.run_simulation(study_path, args.participants, args.out, [*observer, *args.items],
                                              options=options)
            options = session.SessionOptions(quick=args.quick, order=args.order, locked=True, bus=args.bus)
            return session.run_session(study_path, args.participant, args.out, args.items, options=options)
    except session.Stopped as exc:
        print(f"touch4d study run: {exc}; the stack is stopped")
        return exc.code


def _settings(study, quick: bool, simulation: dict | None) -> dict:
    """What this run's sessions must share with those already in --out (manifest.run_settings)."""
    from touch4d.study.manifest import sha256_file

    return {"study": study.name, "study_sha256": sha256_file(study.path), "quick": bool(quick),
            "simulation": simulation}


def run_transfer(args) -> int:
    from touch4d.tactile import load_glove

    from touch4d.study.infotransfer import predicted_transfer
    from touch4d.study.observer import every_sample_glove
    from touch4d.study.psychophysics import THENAR_RATIO

    study = _study(args.study)
    files = [resolve_path(g, COMMAND_LINE, key="--glove", what="glove file") for g in args.glove] if args.glove \
        else [None]
    loaded = [load_glove(f) for f in files]
    gloves = [g for glove in loaded for g in [glove] + ([every_sample_glove(glove)] if args.every_sample else [])]
    tasks = [study.task(t).id for t in args.task] if args.task else [t.id for t in study.tasks]
    results = [{**predicted_transfer(g, study, task, noise=args.noise, scenes=args.scenes, positions=args.positions,
                                     seed=args.seed), "glove": g.path} for task in tasks for g in gloves]
    if args.json:
        print(json.dumps(_clean({"study": study.name, "glove": loaded[0].path, "gloves": [g.path for g in loaded],
                                 "noise": args.noise, "results": results})))
        return 0
    print(f"{study.name}: information transferred by one touch ({', '.join(g.path for g in loaded)}; "
          f"noise {args.noise:.3g} per finger motor, {args.noise * THENAR_RATIO:.3g} per palm motor)")
    print(transfer_table(results, named=len(gloves) > 1))
    return 0


def _glove_name(path: str) -> str:
    """A glove's short name in a table: its file's name, and what was made of it."""
    file, _, made = path.partition(" (")
    return Path(file).stem + (" (every sample)" if made else "")


def run_serve(args) -> int:
    from touch4d.web.served import ServedOptions
    from touch4d.web.studyserver import ServeOptions, StudyServer, recruit_options

    study_path = _study_path(args.study)
    session = ServedOptions(quick=args.quick, iti_s=args.iti,
                            glove=str(resolve_path(args.glove, COMMAND_LINE, key="--glove", what="glove file")),
                            calibration=str(resolve_path(args.calibration, COMMAND_LINE, key="--calibration",
                                                         what="calibration file")))
    options = ServeOptions(host=args.host, port=args.port, max_participants=args.max_participants,
                           public_url=args.public_url, leave_after_s=args.leave_after, session=session,
                           glove_check=not args.no_glove_check, **recruit_options(args))
    server = StudyServer(_study(args.study), study_path, Path(args.out), options)
    return server.run()


def run_invite(args) -> int:
    from touch4d.errors import ConfigError
    from touch4d.web.access import qr_text
    from touch4d.web.invites import Invites, check_participant
    from touch4d.web.studyserver import participant_link, served_url

    from touch4d.web.invites import EXPERIMENTER

    if args.experimenter:
        if args.participant is not None or args.revoke:
            raise ConfigError(COMMAND_LINE, "--experimenter", "no participant ID and no --revoke with --experimenter "
                              "(its link is replaced, never left without one)", got=args.participant or "--revoke")
        args.participant = EXPERIMENTER
    else:
        try:
            check_participant(args.participant)
        except ValueError as exc:
            raise ConfigError(COMMAND_LINE, "ID", str(exc).split(", got")[0], got=args.participant) from None
    invites = Invites(Path(args.dir))
    if args.revoke:
        print(f"{args.participant}: link revoked" if invites.revoke(args.participant)
              else f"{args.participant}: had no link")
        return 0
    base = args.public_url or served_url(Path(args.dir))
    if not base:
        raise ConfigError(COMMAND_LINE, "--public-url", f"the server's address (no server has served {args.dir} yet)")
    link = participant_link(base.rstrip("/"), args.participant, invites.issue(args.participant))
    print(link)
    if not args.no_qr:
        print(qr_text(link))
    return 0


def transfer_table(results: list[dict], named: bool = False) -> str:
    """`study transfer`'s table: bits and their maximum rounded alike (a perfect score reads x of x);
    `named`: a glove column (several gloves side by side)."""
    glove = (lambda r: f"{_glove_name(r['glove']):<24} ") if named else (lambda r: "")
    lines = [f"{'task':<12} " + (f"{'glove':<24} " if named else "") + f"{'motors':>6} {'bits':>6} {'of':>6} {'accuracy':>8}"]
    lines += [f"{r['task']:<12} {glove(r)}{r['motors']:>6} {r['bits']:>6.3f} {r['max_bits']:>6.3f} {r['accuracy']:>8.2f}"
              for r in results]
    return "\n".join(lines)


def run_analyze(args) -> int:
    from touch4d.study.analysis import analyze, load, report_html, summary_text
    from touch4d.study.manifest import check_one_study
    from touch4d.study.table import find_tables

    tables = [t for where in args.dirs for t in find_tables(where)]
    check_one_study(tables)    # one study, run alike: never two mixed in one analysis
    _one_folder_each(tables)
    data = load(args.dirs[0]) if len(args.dirs) == 1 else _load_all(args.dirs)
    result = analyze(data, bootstrap=args.bootstrap, seed=args.seed)
    if args.by:
        from touch4d.study.splits import analyze_by

        result["by"] = analyze_by(data, args.by, bootstrap=args.bootstrap, seed=args.seed)
    report = None
    if not args.no_report:
        where = Path(args.dirs[0])
        report = Path(args.report) if args.report else (where if where.is_dir() else where.parent) / "report.html"
        report.write_text(report_html(result, data, title=f"touch4d study: {', '.join(args.dirs)}"))
        result["report"] = str(report)
    if args.plot:
        from touch4d.study.analysis import figure_summary

        figure_summary(result).savefig(args.plot, dpi=110)
        result["plot"] = str(args.plot)
    if args.json:
        print(json.dumps(_clean(result)))
    else:
        print(summary_text(result))
        for group in result.get("by", {}).get("groups", []):
            print(f"\n{args.by} = {group['value']} ({', '.join(group['participants'])}; {group['trials']} trials)")
            print(summary_text(group["result"]) if group["result"] else "no trials to analyse")
        if report is not None:
            print(f"report: {report}")
    return 0


def _load_all(dirs):
    """The trials of several folders as one table (touch4d.study.analysis.load of each)."""
    import pandas as pd

    from touch4d.study.analysis import load

    return pd.concat([load(where) for where in dirs], ignore_index=True)


def _one_folder_each(tables) -> None:
    """Folders analysed together hold each participant once: two servers that made the same id would
    mix two people (a ConfigError naming both tables)."""
    import csv

    seen: dict[str, Path] = {}
    for table in tables:
        with open(table, newline="") as f:
            ids = {row.get("participant", "") for row in csv.DictReader(f)}
        for participant in ids:
            if participant in seen and seen[participant].parent != Path(table).parent:
                raise ConfigError(COMMAND_LINE, "DIR", "each participant in one session folder", got=participant,
                                  detail=f"{participant} in {seen[participant].parent} and {Path(table).parent}: "
                                         "give each server its own participant ids")
            seen.setdefault(participant, Path(table))


def run_export(args) -> int:
    from touch4d.study.psychds import export_psychds

    done = export_psychds(args.dir, args.psych_ds, force=args.force)
    print(f"{done['out']}: Psych-DS dataset of {len(done['participants'])} participants "
          f"({len(done['data_files'])} data files, {len(done['records'])} manifests and logs in data/primary_data/)")
    return 0
