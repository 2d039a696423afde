"""`touch4d lesson serve SCENE|LAUNCH --out DIR`: a 4D lesson, one scene that a teacher and a class see
and touch on their own headsets (touch4d.web.lesson); `touch4d lesson command DIR VERB ...`: the
teacher's command from the terminal; `touch4d lesson revoke DIR teacher|class`: a new link, the old
one's pages closed. docs/lesson.md walks through a lesson."""
from __future__ import annotations

import argparse
import asyncio
import sys
import time
from pathlib import Path

from touch4d.configfile import COMMAND_LINE, read_yaml, resolve_path
from touch4d.errors import ConfigError, Touch4dError

DEFAULT_GLOVE = "config/gloves/quest-controller.yaml"   # the held controller: what a headset's owner has
MAX_LOAD = 15000     # bytes of a scene file `load` sends: one page message (touch4d.web.protocol's limit) with room


def register(subparsers) -> None:
    lesson = subparsers.add_parser("lesson", help="a 4D lesson: one scene, a teacher and a class, each on a headset")
    sub = lesson.add_subparsers(dest="lesson_command", metavar="ACTION")
    serve = sub.add_parser("serve", help="serve a lesson; prints the teacher's and the class's links",
                           formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    serve.add_argument("scene", metavar="SCENE|LAUNCH",
                       help="a scene file, or a launch file whose scene node names one (its webxr node's glove too)")
    serve.add_argument("--out", required=True, type=Path, help="the lesson's folder: links, lesson.json, lesson.mcap")
    serve.add_argument("--host", default="127.0.0.1", help="address to listen on (beyond loopback: https)")
    serve.add_argument("--port", type=int, default=8090, help="port (0: any free one)")
    serve.add_argument("--public-url", default=None, help="the address students use, if a reverse proxy serves it")
    serve.add_argument("--max-students", type=int, default=30, help="students connected at once")
    serve.add_argument("--glove", default=None, help=f"glove file (default the launch's, else {DEFAULT_GLOVE})")
    serve.add_argument("--no-record", action="store_true", help="record nothing to DIR/lesson.mcap")
    serve.set_defaults(func=_serve)
    command = sub.add_parser("command", help="the teacher's command to a served lesson")
    command.add_argument("out", type=Path, metavar="DIR", help="the lesson's folder (serve's --out)")
    command.add_argument("verb", help="load FILE | next | select X | view MODE | slice C|up|down | projection P | "
                                      "rotate PLANE DEG | reset | lock | unlock | drive NAME|teacher | spotlight NAME|off | "
                                      "remove NAME")
    command.add_argument("argument", nargs="*", help="the verb's argument (load: a scene file)")
    command.set_defaults(func=_command)
    revoke = sub.add_parser("revoke", help="replace a link: its pages close, the new link is printed")
    revoke.add_argument("out", type=Path, metavar="DIR")
    revoke.add_argument("link", choices=("teacher", "class"))
    revoke.set_defaults(func=_revoke)
    lesson.set_defaults(func=lambda args: (lesson.print_help(), 2)[1])


class Recording:
    """The lesson's MCAP log (touch4d.log.writer): messages as the bus would carry them, flushed every
    second, so that `touch4d replay` plays them."""

    def __init__(self, path: Path):
        from touch4d.log.writer import LogWriter, WallClock

        self.writer = LogWriter(path)
        self.clock = WallClock()
        self.failed = False
        self._flushed = time.monotonic()

    def __call__(self, topic: str, msg) -> None:
        if self.failed:
            return
        try:
            self.writer.write(topic, msg.encode(), self.clock())
            if time.monotonic() - self._flushed >= 1.0:
                self._flushed = time.monotonic()
                self.writer.flush()
        except (OSError, Touch4dError) as exc:   # a full disk: the lesson goes on, unrecorded, and says so
            self.failed = True
            print(f"lesson: recording stopped ({exc}); the lesson goes on", file=sys.stderr, flush=True)

    def close(self) -> None:
        try:
            self.writer.close()
        except (OSError, Touch4dError) as exc:
            print(f"lesson: the recording could not be finished ({exc})", file=sys.stderr, flush=True)


def lesson_inputs(given: str, glove: str | None):
    """(scene, glove path) from a scene file or a launch file (its `scene` node's `scene`, its webxr
    node's `glove`)."""
    from touch4d.geometry.scene import load_scene

    path = resolve_path(given, COMMAND_LINE, key="SCENE|LAUNCH", what="scene or launch file")
    data = read_yaml(path, "scene or launch file")
    if isinstance(data, dict) and isinstance(data.get("nodes"), dict):
        nodes = data["nodes"]
        scene_file = next((n.get("params", {}).get("scene") for n in nodes.values()
                           if isinstance(n, dict) and n.get("node") == "scene"), None)
        if not isinstance(scene_file, str):
            raise ConfigError(path, "nodes.<scene>.params.scene", "a scene node naming its scene file")
        glove = glove or next((n.get("params", {}).get("glove") for n in nodes.values()
                               if isinstance(n, dict) and n.get("node") == "webxr"), None)
        return load_scene(resolve_path(scene_file, path, key="nodes.scene.params.scene", what="scene file")), \
            glove or DEFAULT_GLOVE
    return load_scene(path), glove or DEFAULT_GLOVE


def _serve(args) -> int:
    from touch4d.tactile.glove import load_glove
    from touch4d.tracking.calibration import load_calibration, load_placement
    from touch4d.web.lessonserver import LessonOptions, LessonRun

    if not 1 <= args.max_students <= 500:
        raise ConfigError(COMMAND_LINE, "--max-students", "a number of students 1..500", got=args.max_students)
    if not 0 <= args.port <= 65535:
        raise ConfigError(COMMAND_LINE, "--port", "a port 0..65535", got=args.port)
    if args.public_url and not args.public_url.startswith(("http://", "https://")):
        raise ConfigError(COMMAND_LINE, "--public-url", "an http:// or https:// address", got=args.public_url)
    scene, glove = lesson_inputs(args.scene, args.glove)
    options = LessonOptions(host=args.host, port=args.port, public_url=args.public_url,
                            max_students=args.max_students)
    run = LessonRun(scene, load_glove(glove), load_calibration(None, "hand_in_grip"), load_placement(None),
                    args.out, options, None if args.no_record else Recording)
    return run.run()


def _command(args) -> int:
    from touch4d.web.lesson import VERBS
    from touch4d.web.lessonserver import send_command

    if args.verb not in VERBS:
        raise ConfigError(COMMAND_LINE, "VERB", f"one of {', '.join(VERBS)}", got=args.verb)
    argument = " ".join(args.argument)
    if args.verb == "load":
        if len(args.argument) != 1:
            raise ConfigError(COMMAND_LINE, "load FILE", "one scene file", got=argument)
        argument = resolve_path(args.argument[0], COMMAND_LINE, key="load FILE", what="scene file").read_text()
        if len(argument.encode()) > MAX_LOAD:
            raise ConfigError(COMMAND_LINE, "load FILE", f"a scene file of at most {MAX_LOAD} bytes (what one page "
                              "message carries)", got=f"{len(argument.encode())} bytes")
    ok, text = asyncio.run(send_command(args.out, args.verb, argument))
    print(f"lesson: {text}" if ok else f"touch4d lesson command: {text}")
    return 0 if ok else 2


def _revoke(args) -> int:
    from touch4d.web.invites import Invites
    from touch4d.web.lessonserver import lesson_links, served

    invites = Invites(args.out)
    if args.link not in invites.load():
        raise ConfigError(invites.path, args.link, "a lesson's links (touch4d lesson serve made none here)")
    invites.issue(args.link)
    tokens = invites.load()
    base = served(args.out)["url"]
    teacher, klass = lesson_links(base, tokens)
    print(f"the old {args.link} link is refused now; its pages close within a second")
    print(f"teacher link: {teacher}" if args.link == "teacher" else f"class link: {klass}")
    return 0
