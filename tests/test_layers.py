"""Layers only point down: every import under touch4d/, messages/ and nodes/ is checked against the
table of docs/code-map.md (parsed here, so the document is the rule)."""
import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = {"touch4d": "touch4d", "messages": "touch4d.messages", "nodes": "touch4d.nodes"}
FOUNDATION = "touch4d"
COMMANDS = "commands"


def layer_table() -> dict[str, set[str]]:
    """package -> the packages it may import, from the 'may import' table of docs/code-map.md."""
    text = (ROOT / "docs/code-map.md").read_text()
    section = text.split("## Layers point down", 1)[1].split("\n## ", 1)[0]
    table = {}
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) != 2 or not cells[0] or set(cells[0]) <= {"-"} or cells[0] == "package":
            continue
        name = cells[0].strip("`")
        table[name] = set(re.findall(r"`([\w.]+)`", cells[1]))
    return table


TABLE = layer_table()


def package_of(module: str) -> str | None:
    """The layer a module belongs to: a package of the table, the foundation or the commands."""
    parts = module.split(".")
    if parts[0] != "touch4d":
        return None
    if "cli" in parts[1:3]:   # touch4d.cli, touch4d.bus.cli and what they hold
        return COMMANDS
    if len(parts) == 1 or parts[1] == "defaults":
        return FOUNDATION
    name = "touch4d." + parts[1]
    if (ROOT / "touch4d" / f"{parts[1]}.py").exists() and name not in TABLE:
        return FOUNDATION   # a module at the top of touch4d/ (errors, configfile, schema, ...) unless listed
    return name


def module_name(path: Path) -> str:
    folder = path.relative_to(ROOT).parts[0]
    rel = path.relative_to(ROOT / folder).with_suffix("")
    name = ".".join([FOLDERS[folder], *rel.parts])
    return name.removesuffix(".__init__")


def imports(path: Path):
    """(imported module, line) for every import statement of a file, relative ones made absolute."""
    module = module_name(path)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, node.lineno
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                target = f"{base}.{node.module}" if node.module else base
            else:
                target = node.module
            yield target, node.lineno
            for alias in node.names:   # `from touch4d import nodes` imports touch4d.nodes
                if package_of(f"{target}.{alias.name}") not in (None, package_of(target), FOUNDATION):
                    yield f"{target}.{alias.name}", node.lineno


def upward_imports() -> list[str]:
    table = layer_table()
    wrong = []
    for folder in FOLDERS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            mine = package_of(module_name(path))
            allowed = table[mine] | {mine, FOUNDATION}
            for target, line in imports(path):
                theirs = package_of(target)
                if theirs is not None and theirs not in allowed:
                    wrong.append(f"{path.relative_to(ROOT)}:{line}: {mine} imports {target} ({theirs})")
    return wrong


def test_the_table_names_every_package_and_only_known_ones():
    table = layer_table()
    found = {package_of(module_name(p)) for folder in FOLDERS for p in (ROOT / folder).rglob("*.py")}
    assert found == set(table), "docs/code-map.md's layer table and the packages differ"
    for name, allowed in table.items():
        assert allowed <= set(table) - {COMMANDS, "touch4d.nodes"}, f"{name} may import a node or a command"


def test_no_library_package_imports_upward():
    assert upward_imports() == []


def test_the_check_sees_an_upward_import(tmp_path, monkeypatch):
    """The checker itself: a bus module importing the command layer or a node is reported."""
    bad = ROOT / "touch4d/bus/_layer_probe.py"
    monkeypatch.setattr(Path, "rglob", lambda self, pattern: [bad] if self == ROOT / "touch4d" else [])
    monkeypatch.setattr(Path, "read_text", lambda self, *a, **k: (
        "from touch4d.cli import main\nfrom touch4d import nodes\nfrom ..tracking import paths\n"
        if self == bad else Path.open(self).read()))
    wrong = upward_imports()
    assert [w.split(": ", 1)[1] for w in wrong] == [
        "touch4d.bus imports touch4d.cli (commands)", "touch4d.bus imports touch4d.nodes (touch4d.nodes)",

        "touch4d.bus imports touch4d.tracking (touch4d.tracking)"]


def test_no_node_has_an_init_of_its_own():
    """Construction is the base class's: a node builds itself in setup() (anything a test hands it is
    set between Node(..., start=False) and start())."""
    own = [f"{path.name}: {cls.name}" for path in sorted((ROOT / "nodes").glob("*.py"))
           for cls in ast.walk(ast.parse(path.read_text())) if isinstance(cls, ast.ClassDef)
           for item in cls.body if isinstance(item, ast.FunctionDef) and item.name == "__init__"]
    assert own == []
