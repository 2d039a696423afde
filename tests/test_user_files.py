"""Every file a user writes goes through touch4d.schema: one ConfigError naming file, key path, expected
and got; YAML syntax errors whole with line and column; did-you-mean for typos; each default in one
place; bad input counted by the nodes while a programming error surfaces."""
import json
import re
from pathlib import Path

import msgspec
import numpy as np
import pytest
import yaml

from touch4d import glovefile, schema
from touch4d.boards.config import load_glove_can
from touch4d.bus.config import BusFile, load_bus_config
from touch4d.bus.launchfile import load_launch
from touch4d.errors import ConfigError, Touch4dError
from touch4d.geometry.polytope import GeometryError
from touch4d.geometry.scene import Scene, SceneObject, load_scene
from touch4d.study.design import load_study
from touch4d.tactile.glove import load_glove
from touch4d.tracking.calibration import load_calibration
from touch4d.tracking.paths import load_paths
from touch4d.web.protocol import PageError, parse_page_message

REPO = Path(__file__).resolve().parents[1]
GLOVE_TEXT = (REPO / "config/glove.yaml").read_text()
SCENE_TEXT = "objects:\n  - shape: tesseract\n    size: 1.0\n    position: [0, 0, 0, 1.5]\n"
CALIBRATION_TEXT = "screen:\n  center_m: [0, 1.2, -0.45]\n  edge_m: 0.5\n"
PATHS_TEXT = "paths:\n  p:\n    kind: hold\n    position: [0, 0, 0]\n"
LAUNCH_TEXT = "nodes:\n  talker:\n    node: example_talker\n    respawn: false\n"
BUS_TEXT = "broker:\n  pub_port: 7710\nhwm: 100\n"
STUDY_TEXT = ("name: s\ntime_limit_s: 20\ntasks:\n  - id: t\n    kind: look-alikes\n    prompt: '?'\n"
              "    options: [convex, flat]\n    stimuli:\n      - {answer: convex, scene: config/scenes/convex-front.yaml}\n"
              "      - {answer: flat, scene: config/scenes/flat-front.yaml}\n")

# Each reader, a good file, a bad line replacing a good one (the same indent), and what the error says.
READERS = {
    "scene": (load_scene, SCENE_TEXT, "    size: 1.0", "    size: -2", "objects[0].size", "a finite number > 0", -2),
    "glove": (load_glove, GLOVE_TEXT, "beta: 0.5", "beta: 2", "beta", "a number in 0..1 (paper eq. 2)", 2),
    "glove can": (load_glove_can, GLOVE_TEXT, "    - {id: 4, channels: 8}", "    - {id: 4, channels: 9}",
                  "can.boards[3].channels", "1..8 channels (one duty frame per board)", 9),
    "bus": (load_bus_config, BUS_TEXT, "  pub_port: 7710", "  pub_port: 70000", "broker.pub_port",
            "a TCP port (0..65535; 0 = any free port)", 70000),
    "calibration": (load_calibration, CALIBRATION_TEXT, "  edge_m: 0.5", "  edge_m: [0.5]", "screen.edge_m",
                    "a finite number > 0", [0.5]),
    "paths": (load_paths, PATHS_TEXT, "    position: [0, 0, 0]", "    position: [0, 0, .nan]", "paths.p.position[2]",
              "a finite number", None),
    "launch": (load_launch, LAUNCH_TEXT, "    respawn: false", "    respawn: 'yes'", "nodes.talker.respawn",
               "true or false", "yes"),
    "study": (load_study, STUDY_TEXT, "time_limit_s: 20", "time_limit_s: -1", "time_limit_s", "a finite number > 0", -1),
}


def write(tmp_path, text, name="f.yaml"):
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.mark.parametrize("kind", READERS)
def test_a_wrong_value_names_file_key_expected_and_got(tmp_path, kind):
    read, good, line, bad, key, expected, got = READERS[kind]
    read(write(tmp_path, good))                       # the good file reads
    assert line in good
    with pytest.raises(ConfigError) as info:
        read(write(tmp_path, good.replace(line, bad)))
    e = info.value
    assert (Path(e.file).name, e.key, e.expected) == ("f.yaml", key, expected)
    if got is None:
        assert np.isnan(e.got)
    else:
        assert e.got == got
    assert str(e).startswith(f"{e.file}: key '{key}': expected {expected}")


@pytest.mark.parametrize("kind", READERS)
def test_a_tab_names_its_line_and_column_in_every_reader(tmp_path, kind):
    read, good, line, *_ = READERS[kind]
    lines = good.splitlines()
    n = lines.index(line)
    lines[n] = "\t" + line.lstrip()
    with pytest.raises(ConfigError) as info:
        read(write(tmp_path, "\n".join(lines) + "\n"))
    text = str(info.value)
    assert info.value.key.startswith(f"line {n + 1}, column ") and "tab" in text and "f.yaml" in text
    assert "\\n" not in text and "\n" not in text          # one line, no literal \n


@pytest.mark.parametrize("kind", READERS)
def test_a_typo_in_a_key_suggests_the_declared_one(tmp_path, kind):
    read, good, line, *_ = READERS[kind]
    name = line.strip().lstrip("- {").split(":")[0]
    typo = name[:-2] + name[-1] + name[-2]             # two letters swapped: position -> positoin
    with pytest.raises(ConfigError) as info:
        read(write(tmp_path, good.replace(line, line.replace(name, typo, 1))))
    assert info.value.key.endswith(typo) and f"did you mean '{name}'?" in str(info.value)


def test_scene_typos_suggest_the_key_and_the_catalog_shape(tmp_path):
    with pytest.raises(ConfigError) as info:
        load_scene(write(tmp_path, SCENE_TEXT.replace("position", "positon")))
    assert info.value.key == "objects[0].positon" and "(did you mean 'position'?)" in str(info.value)
    with pytest.raises(ConfigError) as info:
        load_scene(write(tmp_path, SCENE_TEXT.replace("tesseract", "tessaract")))
    assert info.value.key == "objects[0].shape" and info.value.got == "tessaract"
    assert "(did you mean 'tesseract'?)" in str(info.value)


def test_a_launch_file_yaml_error_is_whole_on_one_line(tmp_path):
    path = write(tmp_path, "nodes:\n  talker: {node: example_talker\n  other: 1\n")
    with pytest.raises(ConfigError) as info:
        load_launch(path)
    text = str(info.value)
    assert "\\n" not in text and "\n" not in text and "line 3, column" in text and "expected ',' or '}'" in text
    with pytest.raises(ConfigError) as info:
        load_launch(write(tmp_path, LAUNCH_TEXT, "l.yaml"), ["talker.rate:=[1, 2"])
    assert info.value.key == "talker.rate:=[1, 2" and "\\n" not in str(info.value) and "\n" not in str(info.value)


def test_page_messages_name_field_expected_and_got():
    source = {"handedness": "right", "grip": [0, 1, 0, 0, 0, 0, 1], "trigger": 0.5, "buttons": [], "joints": None}
    message = {"type": "input", "time": 1.0, "tracking": True, "head": None, "sources": [source]}
    for change, field, expected, got in [
        ({"trigger": "full"}, "sources[0].trigger", "a number", "full"),
        ({"grip": [0, 1, 0, 0, 0, 0, 2]}, "sources[0].grip", "a unit quaternion (norm 2)", [0, 1, 0, 0, 0, 0, 2]),
        ({"handednes": "left"}, "sources[0].handednes", "one of the keys handedness, trigger, buttons, grip, joints",
         None),
    ]:
        with pytest.raises(PageError) as info:
            parse_page_message(json.dumps({**message, "sources": [{**source, **change}]}))
        e = info.value
        assert (e.cause, e.field, e.expected, e.got) == ("malformed", field, expected, got)
        assert isinstance(e, Touch4dError)
    with pytest.raises(PageError) as info:
        parse_page_message(json.dumps({**message, "type": "inptu"}))
    assert info.value.field == "type" and "did you mean 'input'?" in str(info.value)


def test_every_error_for_bad_input_is_a_touch4d_error():
    from touch4d.boards.protocol import FrameError
    from touch4d.tactile.pose import PoseError
    from touch4d.tracking.scene_control import SceneCommandError
    for cls in (ConfigError, GeometryError, FrameError, PageError, PoseError, SceneCommandError):
        assert issubclass(cls, Touch4dError), cls


# ---- each default in one place ----------------------------------------------------------------------


def commented_defaults(text: str, section: str | None) -> dict:
    """`# key: value` lines of a packaged file (inside `section:` when given), parsed as YAML."""
    if section is not None:
        text = text[text.index(f"\n{section}:\n"):]
    found = {}
    for m in re.finditer(r"^[ \t]*#[ \t]+(\w+):[ \t]+(\S[^#\n]*?)[ \t]*(?:#.*)?$", text, re.MULTILINE):
        found.setdefault(m.group(1), yaml.safe_load(m.group(2)))
    return found


def test_the_packaged_glove_file_shows_the_declared_defaults_and_sets_none_of_them():
    shown = commented_defaults(GLOVE_TEXT, "can")
    declared = msgspec.to_builtins(glovefile.CanSection())
    assert set(shown) == set(declared) - {"boards"}
    for key, value in shown.items():
        assert value == declared[key], key
    assert set(yaml.safe_load(GLOVE_TEXT)["can"]) == {"boards"}          # nothing repeated, only the hardware
    least = glovefile.convert({"motors": [{"name": "m", "position": [0, 0, 0], "board": 1, "channel": 0}]})
    assert commented_defaults(GLOVE_TEXT, None)["touch_threshold"] == least.touch_threshold == 0.05


def test_the_packaged_bus_file_shows_the_declared_defaults_and_sets_none_of_them():
    text = (REPO / "config/bus.yaml").read_text()
    assert yaml.safe_load(text) is None                                   # comments only
    declared = msgspec.to_builtins(BusFile())
    shown = {k: v for k, v in commented_defaults(text, None).items() if k in ("bind", "pub_port", "sub_port",
                                                                              "connect", "hwm")}
    assert shown == {**declared["broker"], "connect": declared["connect"], "hwm": declared["hwm"]}
    cfg = load_bus_config(REPO / "config/bus.yaml")
    assert (cfg.bind_host, cfg.pub_port, cfg.sub_port, cfg.hwm) == ("127.0.0.1", 7710, 7711, 10000)


def test_one_touched_threshold_for_status_hud_and_page(tmp_path):
    from touch4d.messages import MotorCommand
    from touch4d.render.hud import touched_motors
    from touch4d.status import StackStatus
    from touch4d.web.bridge import BridgeConfig, WebBridge
    from touch4d.web.protocol import unpack_frame
    from touch4d.tracking.calibration import Placement

    glove = load_glove(write(tmp_path, GLOVE_TEXT.replace("# touch_threshold: 0.05", "touch_threshold: 0.3")))
    assert glove.touch_threshold == 0.3
    names = ["a", "b", "c", "d"]
    intensity = np.array([0.0, 0.2, 0.31, 0.9])          # two above 0.3, three above 0.05 (the default)
    assert touched_motors(names, intensity, glove.touch_threshold) == ["d", "c"]
    status = StackStatus(touch_threshold=glove.touch_threshold)
    status.on_motors(MotorCommand(names=names, intensity=intensity), 1.0)
    assert status.touched == 2
    sent = []
    bridge = WebBridge(BridgeConfig(tracker=False), glove, load_calibration(None, "hand_in_grip"), Placement(),
                       publish=lambda *a: None, broadcast=lambda *a: None, send=lambda conn, data: sent.append(data),
                       save_calibration=lambda *a: None, now=lambda: 0.0)
    bridge.connected(1)
    header, _ = unpack_frame(sent[0])
    assert header["kind"] == "setup" and header["touch_threshold"] == 0.3      # what the page counts with
    main_js = (REPO / "touch4d/web/static/main.js").read_text()
    assert "0.05" not in main_js.split("header.kind === 'frame'")[1].split("}")[0]


# ---- nodes: bad input is counted, a programming error surfaces ------------------------------------


def scene_message(shape="tesseract"):
    obj = SceneObject(name="cube", shape="tesseract", size=1.0, position=np.array([0, 0, 0, 1.5]))
    msg = Scene(objects=[obj]).to_message()
    msg.objects[0]["shape"] = shape
    return msg


def test_the_tactile_node_counts_a_bad_scene_and_goes_on_but_a_bug_surfaces(monkeypatch):
    from touch4d.bus.testing import running_broker
    from touch4d.nodes.tactile import TactileNode

    with running_broker() as bus:
        node = TactileNode(bus=bus, heartbeat=False)
        try:
            node.on_scene(scene_message("hypersphere"))           # not in the catalog
            assert node.counts["bad_scenes"] == 1 and node.counts["scenes_built"] == 0
            node.on_scene(scene_message())
            assert node.counts["scenes_built"] == 1
            monkeypatch.setattr(Scene, "ray_caster", lambda self: (_ for _ in ()).throw(TypeError("a bug")))
            with pytest.raises(TypeError, match="a bug"):
                node.on_scene(scene_message("24-cell"))
            assert node.counts["bad_scenes"] == 1
        finally:
            node.shutdown()


def test_the_webxr_bridge_counts_bad_pages_and_scenes_but_a_bug_surfaces(monkeypatch):
    import touch4d.web.bridge as bridge_module
    from touch4d.render.scene_geometry import SceneGeometry
    from touch4d.tracking.calibration import Placement

    bridge = bridge_module.WebBridge(
        bridge_module.BridgeConfig(tracker=True), load_glove(), load_calibration(None, "hand_in_grip"), Placement(),
        publish=lambda *a: None, broadcast=lambda *a: None, send=lambda *a: None, save_calibration=lambda *a: None,
        now=lambda: 0.0)
    bridge.connected(1)
    bridge.page_message(1, '{"type": "stats", "fps": "fast"}', 0.0)
    bridge.page_message(1, '{"type": "stats", "fps": 60}', 0.0)
    assert bridge.counts["page_malformed"] == 1 and bridge.counts["page_messages"] == 2
    bridge.on_scene(scene_message("hypersphere"))                  # kept out, drawn nothing
    assert bridge.view.scene is None
    bridge.on_scene(scene_message())
    assert bridge.view.scene is not None
    monkeypatch.setattr(bridge_module, "parse_page_message", lambda data: (_ for _ in ()).throw(TypeError("a bug")))
    with pytest.raises(TypeError, match="a bug"):
        bridge.page_message(1, '{"type": "stats", "fps": 60}', 0.0)
    monkeypatch.setattr(SceneGeometry, "build", classmethod(lambda cls, s: (_ for _ in ()).throw(TypeError("bug"))))
    with pytest.raises(TypeError, match="bug"):
        bridge.on_scene(scene_message("24-cell"))


def test_the_glove_file_is_read_once_into_the_parts_tactile_and_boards_own(monkeypatch):
    import subprocess
    import sys

    from touch4d.boards.config import glove_can
    from touch4d.tactile.glove import glove_from_file

    reads = []
    real = schema.read_yaml
    monkeypatch.setattr(schema, "read_yaml", lambda *a, **k: reads.append(a) or real(*a, **k))
    load_glove()
    assert len(reads) == 1
    data, path = glovefile.load(None)
    tactile, boards = glove_from_file(data, path), glove_can(data, path)
    assert tuple(tactile.motor_names) == boards.motor_names
    assert tuple(tactile.motor_board) == boards.motor_board and tuple(tactile.motor_channel) == boards.motor_channel
    for module, other in (("touch4d.tactile.glove", "touch4d.boards"), ("touch4d.boards.config", "touch4d.tactile")):
        code = f"import sys, {module}; print(sorted(m for m in sys.modules if m.startswith('{other}')))"
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
        assert out.strip() == "[]", (module, out)
