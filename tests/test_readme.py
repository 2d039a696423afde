"""The README as a new user reads it: how to get the `touch4d` command is on its first screen, and
every config/ and launch/ file it names exists (from any directory, in the packaged defaults)."""
import re
from pathlib import Path

from touch4d.configfile import resolve_path

README = (Path(__file__).resolve().parents[1] / "README.md").read_text()


def test_the_first_screen_says_plainly_how_to_get_the_touch4d_command():
    first_screen = README.splitlines()[:40]
    lines = [ln for ln in first_screen if "source .venv/bin/activate" in ln]
    assert lines, "the first 40 lines of the README must say how to get the touch4d command"
    for line in lines:
        before = line[:line.index("source .venv/bin/activate")]
        assert before.count("(") == before.count(")"), f"said in parentheses: {line}"


def test_every_config_and_launch_file_the_readme_names_exists(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)            # not the checkout: the packaged defaults must hold them
    names = set(re.findall(r"\b((?:config|launch)/[\w./-]+\.(?:yaml|dbc))", README))
    assert len(names) > 10
    for name in sorted(names):
        resolve_path(name)


def test_the_commands_before_the_simulated_study_table_name_its_seed():
    seed = re.search(r"simulated participants \(seed (\d+), made by the commands above", README)
    assert seed, "the simulated study's table says which seed made it"
    commands = re.findall(r"touch4d study run \S+ --simulate --offline[^\n]*", README[:seed.start()])
    assert commands and f"--seed {seed.group(1)}" in commands[-1]
