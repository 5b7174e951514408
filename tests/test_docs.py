"""The docs say what the code does, where a machine can check it (issue 28, item 5): every
`crowdteleop ...` command quoted in README.md and docs/ exists with the flags it is given, every
flag quoted alone is one of the CLI's (or of the tool named for it below), every `make` target
is the Makefile's, every path of the repository or the package that is named exists (a test
named `file.py::test_x` too, and a test module named alone), and every link between the pages
reaches its page and heading."""

from __future__ import annotations

import re
from collections.abc import Iterator
from functools import cache
from pathlib import Path

import pytest
import typer.main
from typer.core import TyperCommand, TyperGroup

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "src" / "crowdteleop"
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]

# Flags of other tools that the docs quote on their own, and the file that shows them used.
OTHER_FLAGS = {
    "--no-deps": ROOT / "scripts" / "setup-venv.sh",  # pip's, for robomimic and LeRobot
    "--trace": ROOT / "benchmarks" / "network.py",  # the network experiment's
}

FENCE = re.compile(r"^```[^\n]*\n(.*?)^```", re.S | re.M)
SPAN = re.compile(r"(?<!`)`([^`\n]+)`(?!`)")
# `crowdteleop` where a shell would run it: a snippet's start, after a venv's bin/, `-m` or a
# shell operator; not the package (`crowdteleop.x`, `crowdteleop/`) nor a database user.
COMMAND = re.compile(r"(?:^|(?<=bin/)|(?<=-m )|(?<=\$ )|(?<=&& )|(?<=; ))crowdteleop(?![\w./@\[-])")
MAKE = re.compile(r"(?:^|(?<=\$ )|(?<=&& ))make ([a-z][\w-]*)")
FLAG = re.compile(r"^-{1,2}[a-z][a-z0-9-]*$")
SHELL_STOP = {"#", "&&", "||", "|", ";", ">", ">>", "2>&1", "&"}
# Paths from the repository's root, and paths inside the package (`coord/x.py`, `web/static/`).
REPO_PATH = re.compile(r"(?<![\w/.:~-])(?:src|tests|benchmarks|scripts|docs)/[\w./*-]*(?:::\w+)?")
PACKAGE_DIRS = sorted(p.name for p in PACKAGE.iterdir() if p.is_dir() and p.name != "__pycache__")
PACKAGE_PATH = re.compile(
    rf"(?<![\w/.:~-])(?:crowdteleop/)?(?:{'|'.join(PACKAGE_DIRS)})/[\w./-]*\.(?:py|js|html|css)\b"
)
TEST_FILE = re.compile(r"(?<![\w/.-])test_\w+\.py\b")  # a test module named without its folder
LINK = re.compile(r"\]\(([^)\s]+)\)")


def _code(text: str) -> Iterator[str]:
    """Inline code spans, and the lines of fenced blocks (a trailing backslash continues one)."""
    for block in FENCE.findall(text):
        yield from block.replace("\\\n", " ").splitlines()
    yield from SPAN.findall(FENCE.sub("", text))


Command = TyperCommand | TyperGroup


@cache
def _cli() -> Command:
    from crowdteleop.cli import app

    return typer.main.get_command(app)


def _subcommand(group: TyperGroup, name: str) -> Command | None:
    """A group's command; a group listed by name and imported on use is loaded here."""
    command = group.commands.get(name)
    load = getattr(command, "load", None)
    return load() if load is not None else command


def _options(command: Command) -> set[str]:
    names = {"--help"}
    for param in command.params:
        if param.param_type_name == "option":
            names.update(param.opts, param.secondary_opts)
    return names


@cache
def _all_options() -> frozenset[str]:
    def walk(command: Command) -> Iterator[str]:
        yield from _options(command)
        if isinstance(command, TyperGroup):
            for name in command.commands:
                sub = _subcommand(command, name)
                if sub is not None:
                    yield from walk(sub)

    return frozenset(walk(_cli()))


def _check_command(words: list[str]) -> list[str]:
    """The words after `crowdteleop`: subcommands (`a / b` for either), then arguments and
    flags, each flag one of the last command's."""
    level, path, problems, i = [_cli()], ["crowdteleop"], [], 0
    while i < len(words) and words[i] not in SHELL_STOP and words[i] != "...":
        word = words[i].strip("[]()")
        groups = [command for command in level if isinstance(command, TyperGroup)]
        if groups and not word.startswith("-"):
            names = [word]
            while i + 2 < len(words) and words[i + 1] == "/":
                names.append(words[i + 2])
                i += 2
            found = [(name, _subcommand(group, name)) for group in groups for name in names]
            problems += [f"no command `{' '.join(path)} {name}`" for name, sub in found if not sub]
            level = [sub for _, sub in found if sub is not None]
            path.append(" / ".join(names))
        elif FLAG.match(word.split("=")[0]):
            flag = word.split("=")[0]
            problems += [
                f"`{' '.join(path)}` has no {flag}" for c in level if flag not in _options(c)
            ]
        i += 1
    return problems


def command_problems(text: str) -> list[str]:
    problems = []
    for snippet in _code(text):
        for match in COMMAND.finditer(snippet.strip()):
            problems += _check_command(snippet.strip()[match.end() :].split())
    return problems


def flag_problems(text: str) -> list[str]:
    """Flags quoted on their own (`--port`, `--sim ours | both`): the CLI's or another tool's."""
    problems = []
    for span in SPAN.findall(FENCE.sub("", text)):
        if not span.startswith("--"):
            continue
        for flag in (word.split("=")[0] for word in span.split() if FLAG.match(word)):
            other = OTHER_FLAGS.get(flag)
            if other is not None:
                known = flag in other.read_text() or flag[2:].replace("-", "_") in other.read_text()
            else:
                known = flag in _all_options()
            if not known:
                problems.append(f"no command has {flag}")
    return problems


def make_problems(text: str) -> list[str]:
    targets = set(re.findall(r"^([a-z][\w-]*):", (ROOT / "Makefile").read_text(), re.M))
    return [
        f"no `make {target}`"
        for snippet in _code(text)
        for target in MAKE.findall(snippet.strip())
        if target not in targets
    ]


def _exists(path: str, base: Path) -> bool:
    if "*" in path:
        return any(base.glob(path))
    return (base / path).exists()


def path_problems(text: str) -> list[str]:
    """Paths in the repository (`tests/x.py::test_y` names a test in it) or in the package."""
    prose = re.sub(r"https?://\S+", "", text)
    problems = []
    for match in REPO_PATH.finditer(prose):
        path, _, name = match.group(0).rstrip(".,:;").partition("::")
        if not _exists(path, ROOT):
            problems.append(f"no {path}")
        elif name and not re.search(
            rf"^\s*(?:async )?(?:def|class) {name}\b", (ROOT / path).read_text(), re.M
        ):
            problems.append(f"no {name} in {path}")
    for match in PACKAGE_PATH.finditer(prose):
        path = match.group(0).removeprefix("crowdteleop/")
        if not _exists(path, PACKAGE):
            problems.append(f"no src/crowdteleop/{path}")
    for name in TEST_FILE.findall(prose):
        if not any((ROOT / "tests").rglob(name)):
            problems.append(f"no test module {name}")
    return problems


def _anchors(page: Path) -> set[str]:
    """GitHub's heading anchors: lower case, punctuation dropped, spaces as dashes."""
    headings = re.findall(r"^#+\s+(.*)$", FENCE.sub("", page.read_text()), re.M)
    return {re.sub(r"[^\w\- ]", "", heading.lower()).replace(" ", "-") for heading in headings}


def link_problems(text: str, page: Path) -> list[str]:
    problems = []
    for target in LINK.findall(text):
        if re.match(r"[a-z]+:", target):  # https:, mailto:
            continue
        file, _, anchor = target.partition("#")
        linked = (page.parent / file).resolve() if file else page
        if not linked.exists():
            problems.append(f"link to a missing {file}")
        elif anchor and linked.suffix == ".md" and anchor not in _anchors(linked):
            problems.append(f"link to a missing heading {target}")
    return problems


def problems(page: Path, text: str | None = None) -> list[str]:
    text = page.read_text() if text is None else text
    return [
        *command_problems(text),
        *flag_problems(text),
        *make_problems(text),
        *path_problems(text),
        *link_problems(text, page),
    ]


@pytest.mark.parametrize("page", DOCS, ids=lambda page: page.relative_to(ROOT).as_posix())
def test_the_page_names_only_commands_flags_paths_and_links_that_exist(page):
    found = problems(page)
    assert not found, f"{page.relative_to(ROOT)} has drifted from the code:\n" + "\n".join(found)


PLANTED = {
    "`crowdteleop serve --campaigns FILE`": "`crowdteleop serve` has no --campaigns",
    "`crowdteleop dataset build / rebuild`": "no command `crowdteleop dataset rebuild`",
    "```\n.venv/bin/crowdteleop learn rl \\\n  --budget 2h --epochs 3\n```": "has no --epochs",
    "the option `--frobnicate`": "no command has --frobnicate",
    "`make deploy`": "no `make deploy`",
    "see tests/coord/test_gone.py": "no tests/coord/test_gone.py",
    "`tests/test_docs.py::test_nothing`": "no test_nothing in tests/test_docs.py",
    "the pages in `web/static/gone.js`": "no src/crowdteleop/web/static/gone.js",
    "| `test_coord_gone.py` | the gone part |": "no test module test_coord_gone.py",
    "[deploy](deploy.md#a-heading-nobody-wrote)": "missing heading deploy.md#a-heading-nobody",
    "[the old page](gone.md)": "link to a missing gone.md",
}


@pytest.mark.parametrize("planted", PLANTED, ids=list(PLANTED.values()))
def test_a_planted_drift_is_found(planted):
    found = problems(ROOT / "docs" / "deploy.md", f"# A page\n\n{planted}\n")
    assert len(found) == 1 and PLANTED[planted] in found[0], found
