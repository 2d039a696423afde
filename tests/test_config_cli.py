"""`touch4d config`: list the packaged defaults, show where a path resolves, copy them out to edit."""
from pathlib import Path

import pytest

from touch4d.cli import main
from touch4d.configfile import resolve_path
from touch4d.commands.defaults import copy_defaults, default_files
from touch4d.errors import ConfigError

REPO = Path(__file__).resolve().parents[1]


def repo_defaults() -> set[str]:
    """What the repository holds in config/ and launch/, keys aside (derived from the folders)."""
    names = set()
    for folder in ("config", "launch"):
        for file in (REPO / folder).rglob("*"):
            rel = file.relative_to(REPO)
            if file.is_file() and "keys" not in rel.parts and file.suffix in (".yaml", ".dbc"):
                names.add(rel.as_posix())
    return names


def test_copy_writes_every_default_and_the_copies_then_win_from_there(tmp_path, monkeypatch, capsys):
    dest = tmp_path / "lab"
    assert main(["config", "copy", str(dest)]) == 0
    copied = {p.relative_to(dest).as_posix() for p in dest.rglob("*") if p.is_file()}
    assert copied == repo_defaults() and "launch/demo.yaml" in copied and "config/glove.dbc" in copied
    assert (dest / "config/scenes/hypercube.yaml").read_bytes() == (REPO / "config/scenes/hypercube.yaml").read_bytes()
    assert f"copied {len(copied)} file(s)" in capsys.readouterr().out
    monkeypatch.chdir(dest)
    assert resolve_path("config/glove.yaml") == dest / "config/glove.yaml"
    assert main(["config", "where", "config/glove.yaml", "launch/none.yaml"]) == 1
    out = capsys.readouterr().out.splitlines()
    assert out[0] == str(dest / "config/glove.yaml") and "launch/none.yaml: not found; looked in" in out[1]
    assert main(["config", "list"]) == 0
    assert f"config/glove.yaml   (yours here: {dest / 'config/glove.yaml'})" in capsys.readouterr().out


def test_copy_keeps_edited_files_unless_forced_and_copies_only_what_is_named(tmp_path, capsys):
    glove = tmp_path / "config" / "glove.yaml"
    glove.parent.mkdir()
    glove.write_text("# mine\n")
    assert main(["config", "copy", str(tmp_path), "config/glove.yaml", "config/scenes"]) == 0
    assert glove.read_text() == "# mine\n" and "kept 1" in capsys.readouterr().out
    assert sorted(p.name for p in (tmp_path / "config").iterdir()) == ["glove.yaml", "scenes"]
    assert not (tmp_path / "launch").exists()
    assert main(["config", "copy", str(tmp_path), "config/glove.yaml", "--force"]) == 0
    assert glove.read_bytes() == (REPO / "config/glove.yaml").read_bytes()
    assert main(["config", "copy", str(tmp_path), "config/glove.yml"]) == 2
    assert "config/glove.yml" in capsys.readouterr().err


def test_keys_are_never_defaults(tmp_path):
    root = tmp_path / "defaults"
    for name in ("config/bus.yaml", "config/keys/pc.key", "config/keys/pc.key_secret", "config/keys/x.yaml",
                 "launch/demo.yaml", "launch/notes.txt"):
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text("x")
    assert default_files(root) == ["config/bus.yaml", "launch/demo.yaml"]
    with pytest.raises(ConfigError):
        copy_defaults(tmp_path / "out", ["config/keys"], root=root)
