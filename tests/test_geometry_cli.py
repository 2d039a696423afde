"""`touch4d shape list` and `touch4d shape info`."""
import argparse

import pytest

from touch4d.errors import ConfigError
from touch4d.commands import geometry as cli


def run(argv):
    parser = argparse.ArgumentParser(prog="touch4d")
    cli.register(parser.add_subparsers(dest="command"))
    args = parser.parse_args(argv)
    return args.func(args)


def test_shape_list_prints_every_shape_with_counts(capsys):
    assert run(["shape", "list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    rows = {line.split()[0]: line.split()[1:6] for line in lines[1:]}
    assert rows["120-cell"] == ["1", "600", "1200", "720", "120"]
    assert rows["tesseract"] == ["1", "16", "32", "24", "8"]
    assert rows["hollow-front"][0] == "80"
    assert len(rows) == 12


def test_shape_info_with_parameters(capsys):
    assert run(["shape", "info", "prism", "-p", "base=dodecahedron"]) == 0
    out = capsys.readouterr().out
    assert "'base': 'dodecahedron'" in out
    assert "40 vertices, 80 edges, 54 faces, 14 cells (12x7, 2x12); V-E+F-C = 0" in out


def test_shape_info_rejects_unknown_names_and_parameters():
    with pytest.raises(ConfigError, match="catalog shape"):
        run(["shape", "info", "klein-bottle"])
    with pytest.raises(ConfigError, match="unknown parameter"):
        run(["shape", "info", "duoprism", "-p", "r=3"])
    with pytest.raises(ConfigError, match="KEY=VALUE"):
        run(["shape", "info", "duoprism", "-p", "p"])
