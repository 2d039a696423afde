"""The schema layer: declared file types, one error naming file, key path, expected and got."""
from typing import Annotated

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
