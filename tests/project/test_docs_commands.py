"""The guides cannot go stale silently: every documented ``shapebench`` command is checked against
the command tree, and every path the docs name against the repository.

What is checked, in README.md, leaderboards/README.md and docs/**.md:

* every ``shapebench ...`` command of a fenced ``bash`` / ``sh`` / ``console`` / ``shell`` block,
  and every inline code span of the prose that starts with ``shapebench``: the sub-command exists,
  every ``--flag`` and short option is one that sub-command accepts (the global options
  :data:`GLOBAL_OPTIONS` are accepted anywhere), every ``-O NAME=...`` names an option of the
  method(s) given with ``-m`` (of any installed method when none is given or the name is a
  placeholder) and every ``-D NAME=...`` an option of the dataset(s);
* every relative link target (``[text](path)``) exists;
* every inline code path that starts with a top-level folder of the repository (``configs/``,
  ``scripts/``, ...) exists, and so does every such path in a shell block (outputs of ``--out``
  aside).

The notation of the docs is understood: ``[--split novel]`` (optional), ``-m msc|gauss`` and
``--kind parent\\|training`` (alternatives), ``<placeholder>``, ``M``, ``FILE``, ``...``. A path
with a placeholder is checked up to it; paths the repository ignores (generated outputs such as
``leaderboards/*-report.html``) are not checked.

:func:`check_markdown` is the checker; the tests below run it on the docs, and on a snippet with a
renamed flag to show that it fails.
"""

from __future__ import annotations

import ast
import dataclasses
import difflib
import fnmatch
import re
import shlex
from collections.abc import Iterator
from functools import cache
from pathlib import Path

import click
import pytest
from click.testing import CliRunner

ROOT = Path(__file__).resolve().parents[2]

#: The documents checked.
DOCS = sorted(
    {ROOT / "README.md", ROOT / "leaderboards" / "README.md"}
    | {p for p in (ROOT / "docs").rglob("*.md") if "examples" not in p.relative_to(ROOT).parts}
)

#: Accepted before and after any sub-command; the first four take a value.
GLOBAL_VALUE_OPTIONS = ("--workspace", "--profile", "--tracking-uri", "--cache-dir")
GLOBAL_FLAGS = ("--debug", "--version", "--help", "-h")
GLOBAL_OPTIONS = GLOBAL_VALUE_OPTIONS + GLOBAL_FLAGS

#: Fenced blocks whose lines are shell commands.
SHELL_LANGUAGES = {"bash", "sh", "console", "shell"}

#: Top-level folders: an inline code path that starts with one of them must exist.
TOP_FOLDERS = (
    "configs",
    "scripts",
    "benchmarks",
    "shapebench",
    "plugins",
    "datasets",
    "tests",
    "leaderboards",
    "docs",
)

#: Options whose value is an output the command writes: not checked to exist.
OUTPUT_OPTIONS = {"--out", "-o", "--into"}

_FENCE = re.compile(r"^\s*(```+|~~~+)\s*([\w+-]*)")
_INLINE = re.compile(r"(?<!`)`([^`]+)`(?!`)")
_LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
_PLACEHOLDER = re.compile(r"<[^>]*>?|^[A-Z][A-Z0-9_]*$|\.\.\.|[*?{}\[\]$~]")


@dataclasses.dataclass(frozen=True)
class Finding:
    file: str
    line: int
    command: str
    problem: str

    def __str__(self) -> str:
        return f"{self.file}:{self.line}: {self.problem}\n    in: {self.command}"


# -- reading markdown ----------------------------------------------------------------------------


def _scan(text: str) -> tuple[list[tuple[int, str, str]], list[str]]:
    """The fenced blocks' lines ``(line, language, text)`` and the prose (fenced lines blanked,
    so that line numbers still hold)."""
    block_lines: list[tuple[int, str, str]] = []
    prose: list[str] = []
    fence: str | None = None
    language = ""
    for number, line in enumerate(text.splitlines(), 1):
        m = _FENCE.match(line)
        if fence is None and m:
            fence, language = m.group(1), m.group(2).lower()
            prose.append("")
        elif fence is not None and line.strip().startswith(fence[:3]) and not line.strip()[3:]:
            fence = None
            prose.append("")
        elif fence is not None:
            block_lines.append((number, language, line))
            prose.append("")
        else:
            prose.append(line)
    return block_lines, prose


def shell_commands(text: str) -> Iterator[tuple[int, str]]:
    """``(line, command)`` of each shell line of a fenced shell block, continuation lines
    (``\\``) joined."""
    block_lines, _ = _scan(text)
    pending: tuple[int, str] | None = None
    for number, language, line in block_lines:
        if language not in SHELL_LANGUAGES:
            continue
        if pending is None and language == "console":
            if not line.lstrip().startswith("$"):
                continue  # output, not a command
            line = line.lstrip()[1:]
        if pending is not None:
            start, prefix = pending
            line = prefix + " " + line.strip()
        else:
            start = number
        if line.rstrip().endswith("\\"):
            pending = (start, line.rstrip()[:-1])
            continue
        pending = None
        if line.strip():
            yield start, line.strip()


def inline_spans(text: str) -> Iterator[tuple[int, str]]:
    """``(line, code)`` of every inline code span of the prose (a span may wrap a line)."""
    _, prose = _scan(text)
    joined = "\n".join(prose)
    for m in _INLINE.finditer(joined):
        code = m.group(1)
        if "\n\n" in code or len(code) > 400:
            continue
        yield joined.count("\n", 0, m.start()) + 1, " ".join(code.split())


def links(text: str) -> Iterator[tuple[int, str]]:
    _, prose = _scan(text)
    for number, line in enumerate(prose, 1):
        for m in _LINK.finditer(line):
            yield number, m.group(1)


# -- the command tree ----------------------------------------------------------------------------


@cache
def _cli() -> click.Group:
    from shapebench.cli import cli

    return cli


@cache
def _plugin_options(kind: str) -> dict[str, frozenset[str]]:
    """Every installed method's (``kind="method"``) or dataset's option names."""
    from shapebench.registry.discovery import get_registry

    registry = get_registry()
    out = {}
    for name in registry.names(kind):
        try:
            cls = registry.load(kind, name)
        except Exception:  # a broken plugin is not the docs' fault
            continue
        out[name] = frozenset(f.name for f in dataclasses.fields(cls.Options))
    return out


@dataclasses.dataclass(frozen=True)
class _Option:
    takes_value: bool
    names: frozenset[str]


def _options_of(cmd: click.Command) -> dict[str, _Option]:
    """The option strings ``cmd`` accepts, with whether each takes a value; the global options
    are added (a command that does not use one is the command's business, not the docs')."""
    table: dict[str, _Option] = {}
    for param in cmd.params:
        if not isinstance(param, click.Option):
            continue
        flag = param.is_flag or param.count
        entry = _Option(not flag, frozenset(param.opts + param.secondary_opts))
        for opt in param.opts:
            table[opt] = entry
        for opt in param.secondary_opts:  # --no-x of a --x/--no-x pair
            table[opt] = _Option(False, entry.names)
    for opt in cmd.get_help_option_names(click.Context(cmd)):
        table.setdefault(opt, _Option(False, frozenset({opt})))
    for opt in GLOBAL_VALUE_OPTIONS:
        table.setdefault(opt, _Option(True, frozenset({opt})))
    for opt in GLOBAL_FLAGS:
        table.setdefault(opt, _Option(False, frozenset({opt})))
    return table


def _closest(name: str, valid) -> str:
    close = difflib.get_close_matches(name, sorted(valid), n=1, cutoff=0.5)
    return f" (did you mean {close[0]}?)" if close else ""


def _is_placeholder(token: str) -> bool:
    return bool(_PLACEHOLDER.search(token))


# -- checking one command ------------------------------------------------------------------------


def _tokens(command: str) -> list[str]:
    """The words of a command, the docs' notation undone: ``[--split novel]`` -> ``--split``,
    ``novel``; ``\\|`` (a table's escaped bar) -> ``|``."""
    command = command.replace("\\|", "|")
    try:
        words = shlex.split(command, comments=True)
    except ValueError:  # an unbalanced quote in prose
        words = command.split()
    out = []
    for word in words:
        word = word.lstrip("[")
        while word.endswith("]") and word.count("]") > word.count("["):
            word = word[:-1]
        if word:
            out.append(word)
    return out


def _segments(words: list[str], split_on_bar: bool) -> Iterator[list[str]]:
    """The simple commands of a shell line: split at ``&&``, ``||``, ``;`` and (in a shell
    block) ``|``."""
    seps = {"&&", "||", ";"} | ({"|"} if split_on_bar else set())
    current: list[str] = []
    for word in words:
        if word in seps:
            yield current
            current = []
        elif word.endswith(";") and len(word) > 1:
            current.append(word[:-1])
            yield current
            current = []
        elif word == "|":  # an alternative in the docs' notation (inline spans)
            continue
        else:
            current.append(word)
    yield current


def _shapebench_args(words: list[str]) -> list[str] | None:
    """The arguments after ``shapebench`` when ``words`` runs it (``shapebench``,
    ``.venv/bin/shapebench``, ``python -m shapebench``, ``torchrun ... -m shapebench``,
    after ``VAR=value``), else None."""
    for i, word in enumerate(words):
        if word == "shapebench" or word.endswith("/shapebench"):
            before = words[:i]
            if all(re.match(r"^\w+=", w) or w in ("time", "exec", "nohup") for w in before):
                return words[i + 1 :]
            if before and before[-1] == "-m":
                return words[i + 1 :]
            return None
    return None


def check_command(args: list[str], file: str, line: int, shown: str) -> list[Finding]:
    """The problems of ``shapebench <args>``: an unknown sub-command, option, ``-O`` or ``-D``
    name, each with the closest valid one."""
    cli = _cli()
    findings: list[Finding] = []

    def problem(text: str) -> None:
        findings.append(Finding(file, line, shown, text))

    root = _options_of(cli)
    i = 0
    # global options before the sub-command
    while i < len(args) and args[i].startswith("-"):
        opt = args[i].split("=", 1)[0]
        if opt not in root:
            problem(f"unknown global option {opt}{_closest(opt, root)}")
            return findings
        i += 2 if root[opt].takes_value and "=" not in args[i] else 1
    if i >= len(args):
        return findings
    name = args[i]
    if _is_placeholder(name) or name in ("|",):
        return findings
    cmd = cli.commands.get(name)
    if cmd is None:
        problem(f"unknown sub-command {name!r}{_closest(name, cli.commands)}")
        return findings
    table = _options_of(cmd)
    methods: list[str] = []
    datasets: list[str] = []
    method_opts: list[str] = []
    dataset_opts: list[str] = []
    rest = args[i + 1 :]
    j = 0
    while j < len(rest):
        word = rest[j]
        j += 1
        if word == "--":
            break
        if not word.startswith("-") or word == "-" or re.match(r"^-\d", word):
            continue
        if _is_placeholder(word):  # "-...", "-<x>"
            continue
        opt, eq, attached = word.partition("=")
        value = attached if eq else None
        if opt not in table and not opt.startswith("--") and len(opt) > 2 and opt[:2] in table:
            opt, value = opt[:2], opt[2:]  # -Osigma=0, -j2
        if opt not in table:
            valid = {o for o in table if o.startswith("--")} if opt.startswith("--") else table
            problem(f"'{name}' has no option {opt}{_closest(opt, valid)}")
            continue
        entry = table[opt]
        if not entry.takes_value:
            continue
        if value is None:
            if j >= len(rest):  # prose naming the option itself: `shapebench prepare -m`
                break
            value = rest[j]
            j += 1
        if entry.names & {"-m", "--method", "--methods"}:
            methods += [m for m in re.split(r"[|,]", value) if m]
        elif entry.names & {"-d", "--dataset", "--datasets"}:
            datasets += [d for d in re.split(r"[|,]", value) if d]
        elif "-O" in entry.names:
            method_opts.append(value)
        elif "-D" in entry.names:
            dataset_opts.append(value)
    for kind, flag, given, assignments in (
        ("method", "-O", methods, method_opts),
        ("dataset", "-D", datasets, dataset_opts),
    ):
        declared = _plugin_options(kind)
        named = [n for n in given if not _is_placeholder(n)]
        if named and not all(n in declared for n in named):
            continue  # a plugin the docs install first (docs/plugins.md's examples)
        for assignment in assignments:
            key = assignment.partition("=")[0]
            if _is_placeholder(key) or key.lower() in ("key", "name"):
                continue
            owners = named or sorted(declared)
            if named:
                wrong = [n for n in named if key not in declared[n]]
                if wrong:
                    valid = set().union(*(declared[n] for n in wrong))
                    problem(
                        f"{flag} {key}: not an option of {kind} {', '.join(wrong)}"
                        f"{_closest(key, valid)}"
                    )
            elif not any(key in declared[n] for n in owners):
                valid = set().union(*declared.values())
                problem(f"{flag} {key}: no installed {kind} has this option{_closest(key, valid)}")
    return findings


# -- checking paths ------------------------------------------------------------------------------


@cache
def _ignored_patterns() -> tuple[str, ...]:
    lines = (ROOT / ".gitignore").read_text().splitlines()
    return tuple(s.strip() for s in lines if s.strip() and not s.startswith("#"))


def _ignored(rel: str) -> bool:
    return any(
        fnmatch.fnmatch(rel, pattern.strip("/")) or rel.startswith(pattern.rstrip("/") + "/")
        for pattern in _ignored_patterns()
    )


def _concrete_prefix(path: str) -> str:
    """``path`` up to its first placeholder segment (``<family>``, ``FAMILY``, ``*.db``)."""
    parts = []
    for part in path.split("/"):
        if _is_placeholder(part):
            break
        parts.append(part)
    return "/".join(parts)


def _check_repo_path(path: str, file: str, line: int, shown: str) -> list[Finding]:
    path = path.split("::", 1)[0]
    path = re.sub(r":\d+(-\d+)?$", "", path).rstrip(".,;:)")
    if _ignored(path):
        return []
    concrete = _concrete_prefix(path)
    if not concrete or concrete in TOP_FOLDERS:
        return []
    if not (ROOT / concrete).exists():
        parent = (ROOT / concrete).parent
        siblings = [p.name for p in parent.iterdir()] if parent.is_dir() else []
        name = Path(concrete).name
        close = difflib.get_close_matches(name, siblings, n=1, cutoff=0.5)
        hint = f" (did you mean {Path(concrete).parent / close[0]}?)" if close else ""
        return [Finding(file, line, shown, f"no such path {concrete}{hint}")]
    return []


def _repo_paths(words: list[str]) -> Iterator[str]:
    skip = False
    for word in words:
        if skip:
            skip = False
            continue
        if word.split("=")[0] in OUTPUT_OPTIONS:
            skip = "=" not in word
            continue
        for piece in word.split("="):
            if piece.split("/")[0] in TOP_FOLDERS and "/" in piece:
                yield piece


@cache
def _site_pages() -> dict[Path, Path]:
    """The documentation site's pages that live outside docs/ (``docs/results.md`` is
    leaderboards/README.md): the site's hook (mkdocs.yml) names them in ``PAGES``."""
    hook = ROOT / "docs" / "reference" / "_hooks.py"
    found = (
        re.search(r"^PAGES\s*=\s*(\{[^}]*\})", hook.read_text(), re.M) if hook.exists() else None
    )
    pages = ast.literal_eval(found.group(1)) if found else {}
    return {ROOT / "docs" / page: ROOT / source for page, source in pages.items()}


def _link_exists(target: Path) -> bool:
    return target.exists() or target.resolve() in {p.resolve() for p in _site_pages()}


def check_markdown(text: str, file: str, base: Path | None = None) -> list[Finding]:
    """Every problem of one markdown document (``file`` names it in the findings; ``base`` is
    its folder, for relative links)."""
    base = base if base is not None else (ROOT / file).parent
    findings: list[Finding] = []
    variables: dict[str, str] = {}  # R=shapebench/reference_checkpoints, then $R/msc/...
    for line, command in shell_commands(text):
        cwd_moved = False
        for words in _segments(_tokens(command), split_on_bar=True):
            if words[:1] == ["cd"]:
                cwd_moved = True  # paths after "cd x &&" are relative to x
                continue
            if len(words) == 1 and re.fullmatch(r"[A-Za-z_]\w*=\S+", words[0]):
                name, _, value = words[0].partition("=")
                variables[name] = value
            words = [
                re.sub(
                    r"\$\{?([A-Za-z_]\w*)\}?",
                    lambda m: variables.get(m.group(1), m.group(0)),
                    w,
                )
                for w in words
            ]
            args = _shapebench_args(words)
            if args is not None:
                findings += check_command(args, file, line, command)
            if not cwd_moved:
                for path in _repo_paths(words):
                    findings += _check_repo_path(path, file, line, command)
    for line, code in inline_spans(text):
        words = _tokens(code)
        if words[:1] == ["shapebench"] and len(words) > 1:
            for segment in _segments(words, split_on_bar=False):
                args = _shapebench_args(segment)
                if args is not None:
                    findings += check_command(args, file, line, f"`{code}`")
        elif words and words[0].split("/")[0] in TOP_FOLDERS and "/" in words[0]:
            findings += _check_repo_path(words[0], file, line, f"`{code}`")
    for line, target in links(text):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target) or target.startswith("#"):
            continue  # a URL, a mail address, an anchor on this page
        rel = target.split("#", 1)[0]
        if not rel:
            continue
        if not _link_exists(base / rel):
            findings.append(Finding(file, line, target, f"the link target {rel} does not exist"))
    return findings


def check_docs(paths=DOCS) -> list[Finding]:
    findings = []
    for path in paths:
        findings += check_markdown(path.read_text(), path.relative_to(ROOT).as_posix())
    return findings


# -- the tests -----------------------------------------------------------------------------------


def test_documented_commands_options_and_paths_exist():
    findings = check_docs()
    assert not findings, f"{len(findings)} stale fact(s) in the docs:\n" + "\n".join(
        str(f) for f in findings
    )


def test_the_checker_reports_a_renamed_flag_and_the_closest_valid_one(tmp_path):
    doc = tmp_path / "guide.md"
    doc.write_text(
        "Run one method:\n\n"
        "```bash\n"
        "shapebench run --method gauss --dataset synthetic\n"
        "shapebench run --methd gauss -d synthetic -O sigmaa=0.02 -D test_per_categry=2\n"
        "shapebench leaderbord -d synthetic\n"
        "R=shapebench/reference_checkpoints\n"
        "python benchmarks/thin_parts.py field --checkpoint $R/msc/0123456789abcdef/model.ckpt\n"
        "```\n\n"
        "Then `shapebench report -d synthetic --refrence gauss`, see [the guide](missing.md) and\n"
        "`configs/sweeps/nonexistent.yaml`.\n"
    )
    findings = check_markdown(doc.read_text(), "guide.md", base=tmp_path)
    problems = [(f.line, f.problem) for f in findings]
    assert (5, "'run' has no option --methd (did you mean --method?)") in problems
    # --methd's value is not known to be a method, so -O is checked against every method's
    assert (5, "-O sigmaa: no installed method has this option (did you mean sigma?)") in problems
    assert (
        5,
        "-D test_per_categry: not an option of dataset synthetic (did you mean test_per_category?)",
    ) in problems
    assert (6, "unknown sub-command 'leaderbord' (did you mean leaderboard?)") in problems
    assert any(
        f.line == 8
        and "no such path shapebench/reference_checkpoints/msc/0123456789abcdef" in f.problem
        for f in findings
    ), problems
    assert (11, "'report' has no option --refrence (did you mean --reference?)") in problems
    assert (11, "the link target missing.md does not exist") in problems
    assert any(f.line == 12 and "configs/sweeps/nonexistent.yaml" in f.problem for f in findings)
    assert len(findings) == 8, problems
    assert "guide.md:5:" in str(findings[0]) and "--methd" in str(findings[0])


def test_the_checker_accepts_the_docs_notation_and_global_options():
    doc = (
        "```bash\n"
        "shapebench --workspace W run -m gauss -d synthetic [--split novel] -O sigma=0 \\\n"
        "    --profile quick --debug   # a comment --not-an-option\n"
        "cd my-study && shapebench sweep configs/sweeps/default.yaml | tail -3\n"
        "shapebench run -m msc|gauss -d synthetic -O KEY=VALUE\n"
        "```\n"
        "`shapebench runs [--kind parent\\|training] [-m M[,M...]]` and `shapebench <cmd> --help`\n"
    )
    assert check_markdown(doc, "guide.md", base=ROOT) == []


def _help_commands() -> list[list[str]]:
    return [["--help"], ["plugins"]] + [[name, "--help"] for name in sorted(_cli().commands)]


def test_cheap_documented_commands_run():
    """``shapebench --help``, ``shapebench plugins`` and every ``<cmd> --help`` run (in this
    process: the CLI's import is the cost)."""
    runner = CliRunner()
    for args in _help_commands():
        result = runner.invoke(_cli(), args, prog_name="shapebench")
        assert result.exit_code == 0, (args, result.output, result.exception)


@pytest.mark.parametrize("token", ["<family>", "FILE", "M[,M...]", "*.db", "...", "$HOME"])
def test_placeholders(token):
    assert _is_placeholder(token)
