"""Layers only point down: every import under touch4d/, messages/ and nodes/ is checked against the
table of docs/code-map.md (parsed here, so the document is the rule), and the modules of a package
import each other one way only (no circle, a function's or a type checker's import included)."""
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
    if len(parts) > 1 and parts[1] in ("cli", "commands"):   # touch4d.cli and touch4d.commands.*
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


def module_files() -> dict[str, Path]:
    """Every module of touch4d/, messages/ and nodes/: its dotted name -> its file."""
    return {module_name(path): path for folder in FOLDERS for path in sorted((ROOT / folder).rglob("*.py"))}


def import_graph(modules: dict[str, Path]) -> dict[str, dict[str, int]]:
    """module -> the modules of ours it imports (-> the line of the first such import). `from P import
    m` is an import of the module P.m where there is one, else of P (a name its __init__ gives)."""
    graph = {}
    for module, path in modules.items():
        edges = graph[module] = {}
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = _absolute(module, path, node)
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]
            else:
                continue
            for target in targets:
                if target in modules and target != module:
                    edges.setdefault(target, node.lineno)
    return graph


def _absolute(module: str, path: Path, node: ast.ImportFrom) -> str:
    if not node.level:
        return node.module
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
    return f"{base}.{node.module}" if node.module else base


def import_circles(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """The modules that import each other in a circle: each strongly connected part of `graph` of more
    than one module (Tarjan's algorithm), sorted."""
    index, low, stack, on_stack, parts = {}, {}, [], set(), []

    def visit(module):
        index[module] = low[module] = len(index)
        stack.append(module)
        on_stack.add(module)
        for target in graph[module]:
            if target not in index:
                visit(target)
                low[module] = min(low[module], low[target])
            elif target in on_stack:
                low[module] = min(low[module], index[target])
        if low[module] == index[module]:
            part = []
            while not part or part[-1] != module:
                part.append(stack.pop())
                on_stack.discard(part[-1])
            if len(part) > 1:
                parts.append(sorted(part))

    for module in sorted(graph):
        if module not in index:
            visit(module)
    return sorted(parts)


def circle_text(part: list[str], graph: dict[str, dict[str, int]], modules: dict[str, Path]) -> str:
    """One circle of `part`, each import with its file and line: a -> b (a.py:12) -> ... -> a."""
    members, path, seen = set(part), [part[0]], {part[0]}
    while True:   # follow imports within the part until one comes back to a module already on the path
        here = path[-1]
        target = next(t for t in sorted(graph[here]) if t in members and (t == part[0] or t not in seen))
        path.append(target)
        if target in seen:
            break
        seen.add(target)
    path = path[path.index(path[-1]):]
    return " -> ".join(f"{a} ({modules[a].relative_to(ROOT)}:{graph[a][b]})" for a, b in zip(path, path[1:])) \
        + f" -> {path[-1]}"


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


def test_no_modules_import_each_other_in_a_circle():
    """Imports inside a package point one way too: a piece two modules share goes down into the lower
    one (or a module of its own), never a lazy import back up."""
    modules = module_files()
    graph = import_graph(modules)
    assert [circle_text(part, graph, modules) for part in import_circles(graph)] == []


def test_the_circle_check_sees_a_lazy_and_a_type_checking_import(monkeypatch):
    """The checker itself: a circle closed by an import inside a function, or under TYPE_CHECKING,
    is one; imports one way only are none."""
    graph = {"p.a": {"p.b": 3}, "p.b": {"p.c": 5}, "p.c": {"p.a": 9}, "p.d": {"p.a": 1}}
    assert import_circles(graph) == [["p.a", "p.b", "p.c"]]
    assert import_circles({"p.a": {"p.b": 3}, "p.b": {"p.c": 5}, "p.c": {}}) == []

    files = {f"touch4d.bus._probe_{x}": ROOT / f"touch4d/bus/_probe_{x}.py" for x in "ab"}
    files["touch4d.bus"] = ROOT / "touch4d/bus/__init__.py"
    sources = {files["touch4d.bus._probe_a"]: "from touch4d.bus import _probe_b\n",
               files["touch4d.bus._probe_b"]: "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
                                              "    from ._probe_a import X\ndef f():\n    from . import Node\n",
               files["touch4d.bus"]: ""}
    monkeypatch.setattr(Path, "read_text", lambda self, *a, **k: sources[self])
    graph = import_graph(files)
    assert graph["touch4d.bus._probe_a"] == {"touch4d.bus._probe_b": 1}
    assert graph["touch4d.bus._probe_b"] == {"touch4d.bus._probe_a": 3, "touch4d.bus": 5}
    assert circle_text(import_circles(graph)[0], graph, files) == (
        "touch4d.bus._probe_a (touch4d/bus/_probe_a.py:1) -> touch4d.bus._probe_b (touch4d/bus/_probe_b.py:3) "
        "-> touch4d.bus._probe_a")


def test_the_check_sees_an_upward_import(tmp_path, monkeypatch):
    """The checker itself: a bus module importing the command layer or a node is reported."""
    bad = ROOT / "touch4d/bus/_layer_probe.py"
    monkeypatch.setattr(Path, "rglob", lambda self, pattern: [bad] if self == ROOT / "touch4d" else [])
    monkeypatch.setattr(Path, "read_text", lambda self, *a, **k: (
        "from touch4d.commands.study import main\nfrom touch4d import nodes\nfrom ..tracking import paths\n"
        if self == bad else Path.open(self).read()))
    wrong = upward_imports()
    assert [w.split(": ", 1)[1] for w in wrong] == [
        "touch4d.bus imports touch4d.commands.study (commands)", "touch4d.bus imports touch4d.nodes (touch4d.nodes)",

        "touch4d.bus imports touch4d.tracking (touch4d.tracking)"]


def test_no_node_has_an_init_of_its_own():
    """Construction is the base class's: a node builds itself in setup() (anything a test hands it is
    set between Node(..., start=False) and start())."""
    own = [f"{path.name}: {cls.name}" for path in sorted((ROOT / "nodes").glob("*.py"))
           for cls in ast.walk(ast.parse(path.read_text())) if isinstance(cls, ast.ClassDef)
           for item in cls.body if isinstance(item, ast.FunctionDef) and item.name == "__init__"]
    assert own == []


def test_the_commands_live_on_top():
    """Every sub-command is in touch4d/commands/ (the top layer): no library package holds a cli module."""
    inside = sorted(str(p.relative_to(ROOT)) for p in (ROOT / "touch4d").glob("*/*")
                    if p.name in ("cli.py", "cli") and p.parent.name != "commands")
    assert inside == []
