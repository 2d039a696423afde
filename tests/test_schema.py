"""The schema layer: declared file types, one error naming file, key path, expected and got."""
from typing import Annotated, Generic, Literal, TypeVar

import msgspec
import pytest

from touch4d import schema
from touch4d.errors import ConfigError, Touch4dError


class Part(msgspec.Struct, forbid_unknown_fields=True):
    size: Annotated[float, msgspec.Meta(gt=0)] = 1.0
    position: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    visible: bool = True


class File(msgspec.Struct, forbid_unknown_fields=True):
    objects: list[Part]
    mode: str = "orthographic"


def error(data) -> ConfigError:
    with pytest.raises(ConfigError) as info:
        schema.convert(data, File, "f.yaml")
    assert isinstance(info.value, Touch4dError)
    return info.value


def test_a_good_file_converts():
    got = schema.convert({"objects": [{"size": 2, "position": [1, 2, 3, 4]}]}, File, "f.yaml")
    assert got.objects[0].size == 2.0 and got.objects[0].position == (1, 2, 3, 4) and got.mode == "orthographic"


def test_unknown_key_names_path_and_suggests():
    e = error({"objects": [{}, {"positon": [0, 0, 0, 1]}]})
    assert e.key == "objects[1].positon"
    assert "did you mean 'position'?" in str(e) and "size, position, visible" in str(e)


def test_wrong_type_and_range_name_expected_and_got():
    e = error({"objects": [{"size": -1}]})
    assert (e.file, e.key, e.got) == ("f.yaml", "objects[0].size", -1) and "> 0" in e.expected
    e = error({"objects": [{"visible": "yes"}]})
    assert e.key == "objects[0].visible" and e.expected == "true or false" and e.got == "yes"
    e = error({"objects": [{"position": [1, 2]}]})
    assert e.key == "objects[0].position" and e.expected == "a list of 4 numbers" and e.got == [1, 2]


def test_missing_required_key():
    e = error({"mode": "perspective"})
    assert e.key == "objects" and "required" in e.expected


def test_yaml_syntax_error_is_whole_with_line_and_column(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("objects:\n  - position: [1, 2, 3\n    size: 2\n" + "x" * 200 + ": 1\n")
    with pytest.raises(ConfigError) as info:
        schema.load(path, File)
    text = str(info.value)
    assert str(path) in text and "line 3, column" in text and "expected ',' or ']'" in text


def test_a_tab_names_its_line(tmp_path):
    path = tmp_path / "tab.yaml"
    path.write_text("objects:\n\t- size: 1\n")
    with pytest.raises(ConfigError) as info:
        schema.load(path, File)
    assert "line 2, column 1" in str(info.value) and "tab" in str(info.value)


def test_fail_suggests_a_near_choice():
    with pytest.raises(ConfigError) as info:
        schema.fail("f.yaml", "objects[0].shape", "a catalog shape", got="tesseract4", choices=["tesseract", "24-cell"])
    assert "did you mean 'tesseract'?" in str(info.value)


def test_numpy_numbers_convert_like_the_python_ones_yaml_gives():
    import numpy as np
    got = schema.convert({"objects": [{"size": np.float64(2.5), "position": np.arange(4.0)}]}, File, "f.yaml")
    assert got.objects[0].size == 2.5 and got.objects[0].position == (0.0, 1.0, 2.0, 3.0)
    e = error({"objects": [{"size": np.float64(-1)}]})
    assert e.key == "objects[0].size" and e.got == -1.0


def test_a_misspelt_required_key_is_named_as_written():
    e = error({"objcts": [{}]})
    assert e.key == "objcts" and "did you mean 'objects'?" in str(e) and "objects, mode" in e.expected


class Checked(msgspec.Struct, forbid_unknown_fields=True):
    """Every kind of mistake a file can hold, for the test below."""

    kind: Literal["sweep", "hold"] = "hold"
    size: Annotated[float, msgspec.Meta(gt=0, le=10)] = 1.0
    at: schema.Finite = 0.0
    described: schema.Fraction = 0.5
    corner: tuple[float, float, float] = (0.0, 0.0, 0.0)
    names: Annotated[list[str], msgspec.Meta(min_length=1)] = msgspec.field(default_factory=lambda: ["a"])
    table: dict[str, float] = msgspec.field(default_factory=dict)
    color: str | list[float] | None = None
    low: float = 0.0
    high: float = 1.0

    def __post_init__(self):
        if self.low > self.high:
            raise schema.Invalid(f"a number <= high ({self.high:g})", self.low, "low")


class Outer(msgspec.Struct, forbid_unknown_fields=True):
    items: list[Checked]


MISTAKES = [   # the second item of `items` (the first is good), and the error: key, expected, got, hint
    ({"kind": "swep"}, ("items[1].kind", "one of sweep, hold", "swep", "did you mean 'sweep'?")),
    ({"size": 0}, ("items[1].size", "a number > 0", 0, None)),
    ({"size": 11.5}, ("items[1].size", "a number <= 10", 11.5, None)),
    ({"size": "big"}, ("items[1].size", "a number", "big", None)),
    ({"at": float("inf")}, ("items[1].at", "a finite number", float("inf"), None)),
    ({"described": 2}, ("items[1].described", "a number in 0..1", 2, None)),
    ({"corner": [1, 2]}, ("items[1].corner", "a list of 3 numbers", [1, 2], None)),
    ({"corner": [1, "x", 3]}, ("items[1].corner[1]", "a number", "x", None)),
    ({"names": []}, ("items[1].names", "a list of length >= 1", [], None)),
    ({"table": {"a": 1, "b": True}}, ("items[1].table.b", "a number", True, None)),
    ({"table": {3: 1.0}}, ("items[1].table.3", "a key that is a name (text)", 3, None)),
    ({"color": [1, None]}, ("items[1].color[1]", "a number", None, None)),
    ({"color": 5}, ("items[1].color", "a string or a list or nothing (null)", 5, None)),
    ({"sise": 2}, ("items[1].sise", "one of the keys " + ", ".join(schema.struct_fields(Checked)), None,
                   "did you mean 'size'?")),
    ({"low": 3, "high": 2}, ("items[1].low", "a number <= high (2)", 3, None)),
]


@pytest.mark.parametrize("item, wanted", MISTAKES, ids=[m[1][0] + ":" + repr(m[0]) for m in MISTAKES])
def test_what_is_wrong_is_read_from_the_declared_types_not_from_msgspecs_words(monkeypatch, item, wanted):
    """msgspec's wording of a refusal may change: the error (key, expected, got, hint) stays the same."""
    real = msgspec.convert

    def reworded(*args, **kwargs):
        try:
            return real(*args, **kwargs)
        except msgspec.ValidationError as exc:
            raise msgspec.ValidationError("Something else entirely - at `$.nowhere[7]`") from exc.__cause__
    monkeypatch.setattr(msgspec, "convert", reworded)
    with pytest.raises(ConfigError) as info:
        schema.convert({"items": [{}, item]}, Outer, "f.yaml")
    e = info.value
    key, expected, got, hint = wanted
    assert (e.file, e.key, e.expected, e.got, e.hint) == ("f.yaml", key, expected, got, hint)


class Sweep(msgspec.Struct, forbid_unknown_fields=True, tag_field="kind", tag="sweep"):
    speed: schema.Positive = 1.0


class Hold(msgspec.Struct, forbid_unknown_fields=True, tag_field="kind", tag="hold"):
    seconds: schema.Positive = 1.0


Step = TypeVar("Step")


class Program(msgspec.Struct, Generic[Step], forbid_unknown_fields=True):
    """A file whose parts' type is a parameter (as a study's tasks are the kinds defined)."""

    steps: list[Step]


@pytest.mark.parametrize("step, wanted", [
    ({"kind": "hold", "seconds": -1}, ("steps[0].seconds", "a finite number > 0", -1)),
    ({"kind": "hold", "speed": 2}, ("steps[0].speed", "no speed for kind hold (speed is a key of kind sweep)", 2)),
    ({"kind": "hold", "sped": 2}, ("steps[0].sped", "one of the keys of kind hold: kind, seconds", None)),
    ({"seconds": 1}, ("steps[0].kind", "one of sweep, hold (the key is required)", None)),
    ({"kind": "swep"}, ("steps[0].kind", "one of sweep, hold", "swep")),
])
def test_a_generic_files_parts_and_a_tagged_unions_keys_are_named(step, wanted):
    with pytest.raises(ConfigError) as info:
        schema.convert({"steps": [step]}, Program[Sweep | Hold], "f.yaml")
    assert (info.value.file, info.value.key, info.value.expected, info.value.got) == ("f.yaml", *wanted)
    assert schema.convert({"steps": [{"kind": "sweep", "speed": 2}]}, Program[Sweep | Hold]).steps == [Sweep(2.0)]
