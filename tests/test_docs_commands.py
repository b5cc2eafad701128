"""Every project CLI command shown in the docs parses with that CLI's own parser.

Nothing runs: a command that no longer parses (a required flag missing, an option renamed) is
a doc that drifted from the code. Read: shell and unlabelled blocks of README.md and docs/**/*.md,
and each CLI's ``--help`` examples. In a ``$`` transcript a refusal shown must be the parser's
own. Usage notation (``[...]``, ``a|b``, ``(A | B)``) is expanded; placeholders (``FILE``,
``<...>``, ``sample:K``) pass as plain values.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import io
import itertools
import re
import shlex
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
FENCE = re.compile(r"^```(\w*)[^\n]*\n(.*?)^```", re.S | re.M)
SHELL = {"", "bash", "sh", "shell", "console"}
SCRIPTS = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
SEPARATORS = {"&&", "||", ";", "|"}
PLACEHOLDER = re.compile(r"[A-Z][A-Z0-9_]*|<[^<>]*>|\.\.\.")


def parser_for(cli: str, argv: list[str]) -> argparse.ArgumentParser:
    """The parser the console script parses ``argv`` with (``parser_for`` where it depends on
    the subcommand, else ``build_parser``)."""
    module = importlib.import_module(SCRIPTS[cli].partition(":")[0])
    if hasattr(module, "parser_for"):
        return module.parser_for(argv)
    return module.build_parser()


def logical_lines(body: str, first: int) -> list[tuple[int, str]]:
    """(line number, text) with ``\\`` continuations joined onto the line they start on."""
    out, lines, i = [], body.split("\n"), 0
    while i < len(lines):
        number, text = first + i, lines[i]
        while text.rstrip().endswith("\\") and i + 1 < len(lines):
            i += 1
            text = text.rstrip()[:-1].rstrip() + " " + lines[i].strip()
        out.append((number, text))
        i += 1
    return out


def _group(tokens: list[str], i: int, close: str | None) -> tuple[list, int]:
    """Alternatives (lists of items) up to ``close``; an item is a word or a nested group."""
    alternatives, current = [], []
    while i < len(tokens):
        token = tokens[i]
        if token in ("[", "("):
            inner, i = _group(tokens, i + 1, "]" if token == "[" else ")")
            current.append(inner)
            continue
        i += 1
        if token == close:
            break
        if token == "|" and close is not None:
            alternatives.append(current)
            current = []
        else:
            current.append(token)
    return [*alternatives, current], i


def _expand(items: list) -> list[list[str]]:
    """Every command the usage notation stands for."""
    choices = []
    for item in items:
        if isinstance(item, list):
            choices.append([words for alt in item for words in _expand(alt)])
        elif "|" in item:
            choices.append([[word] for word in item.split("|")])
        else:
            choices.append([[item]])
    return [sum(combo, []) for combo in itertools.product(*choices)]


def commands(text: str) -> list[list[str]]:
    """The argument vectors of project CLIs in one shell line (pipes, ``&&``, ``;`` split)."""
    if not re.search(rf"(?<![\w/.-])({'|'.join(map(re.escape, SCRIPTS))})(?![\w/.-])", text):
        return []
    text = re.sub(r"<[^<>\n]*>", "PLACEHOLDER", text)
    tokens = []
    for word in shlex.split(text, comments=True):
        lead = len(word) - len(word.lstrip("[("))
        trail = len(word) - len(word.rstrip("])"))
        core = word[lead : len(word) - trail] if lead or trail else word
        tokens += [*word[:lead], *([core] if core else []), *word[len(word) - trail :]]
    out, current, depth = [], [], 0
    for token in [*tokens, ";"]:
        depth += (token in ("[", "(")) - (token in ("]", ")"))
        if token in SEPARATORS and depth == 0:  # inside brackets `|` is an alternative
            out.append(current)
            current = []
        else:
            current.append(token)
    argvs = []
    for command in out:
        while command and re.fullmatch(r"\w+=\S*|\$", command[0]):
            command = command[1:]  # a prompt, VAR=value
        if command and command[0] in SCRIPTS:
            items, _ = _group(command, 0, None)
            argvs += _expand(items[0])
    return argvs


def documented() -> list:
    """One param per command line: (where, the line, the refusal the doc shows after it)."""
    out = []
    for doc in DOCS:
        text = doc.read_text()
        for m in FENCE.finditer(text):
            if m.group(1) not in SHELL:
                continue
            lines = logical_lines(m.group(2), text[: m.start(2)].count("\n") + 1)
            transcript = any(line.startswith("$ ") for _, line in lines)
            for k, (number, line) in enumerate(lines):
                if line.lstrip().startswith("#") or (transcript and not line.startswith("$ ")):
                    continue
                shown = lines[k + 1][1] if transcript and k + 1 < len(lines) else ""
                if commands(line):
                    where = f"{doc.relative_to(ROOT)}:{number}"
                    out.append(pytest.param(where, line, shown, id=where))
    for cli in SCRIPTS:
        epilog = parser_for(cli, []).epilog or ""
        for number, line in logical_lines(epilog, 1):
            if commands(line.strip()):
                where = f"{cli} --help, epilog line {number}"
                out.append(pytest.param(where, line.strip(), "", id=where))
    return out


def placeholder(value) -> bool:
    return isinstance(value, str) and any(
        PLACEHOLDER.fullmatch(part) for part in re.split(r"[:=,]", value)
    )


@pytest.fixture
def lenient(monkeypatch):
    """Placeholders pass through the parser as strings; everything else is converted and
    checked as the CLI does."""
    get_value = argparse.ArgumentParser._get_value
    check_value = argparse.ArgumentParser._check_value

    def _get_value(self, action, arg_string):
        return arg_string if placeholder(arg_string) else get_value(self, action, arg_string)

    def _check_value(self, action, value):
        if not placeholder(value):
            check_value(self, action, value)

    monkeypatch.setattr(argparse.ArgumentParser, "_get_value", _get_value)
    monkeypatch.setattr(argparse.ArgumentParser, "_check_value", _check_value)


def refusal(argv: list[str]) -> str | None:
    """The parser's refusal of ``argv`` (its stderr), or None if it parses."""
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            parser_for(argv[0], argv[1:]).parse_args(argv[1:])
    except SystemExit as exc:
        if exc.code not in (0, None):
            return err.getvalue().strip() or f"exit status {exc.code}"
    return None


def test_the_notation_is_read():
    assert commands("leaderboard render --out site/ && leaderboard serve site/  # preview") == [
        ["leaderboard", "render", "--out", "site/"],
        ["leaderboard", "serve", "site/"],
    ]
    assert commands("benchmark evaluate --data D (--model m:C | --predictions FILE) --out r") == [
        ["benchmark", "evaluate", "--data", "D", "--model", "m:C", "--out", "r"],
        ["benchmark", "evaluate", "--data", "D", "--predictions", "FILE", "--out", "r"],
    ]
    assert commands("radar-sim label --data D [--config a|FILE] | tee log") == [
        ["radar-sim", "label", "--data", "D", "--config", "a"],
        ["radar-sim", "label", "--data", "D", "--config", "FILE"],
    ]
    assert commands("$ leaderboard seed --from X --data <the dir>") == [
        ["leaderboard", "seed", "--from", "X", "--data", "PLACEHOLDER"]
    ]
    assert commands("make demo   # basic-shapes") == []
    assert logical_lines("a \\\n    b\nc", 5) == [(5, "a b"), (7, "c")]


def test_the_docs_show_commands_of_every_cli():
    found = {commands(p.values[1])[0][0] for p in documented()}
    assert set(SCRIPTS) <= found
    assert len(documented()) >= 50


def test_a_missing_required_flag_is_caught(lenient):
    (argv,) = commands("leaderboard submit r.json --predictions p.h5 --data D")
    assert "--entries" in refusal(argv)


@pytest.mark.parametrize(("where", "line", "shown"), documented())
def test_documented_command_parses(where, line, shown, lenient):
    for argv in commands(line):
        message = refusal(argv)
        if message is None:
            continue
        if re.match(rf"{re.escape(argv[0])}\b.*: error: ", shown):
            assert message == shown.strip(), f"{where}: the refusal shown is not the parser's"
        else:
            pytest.fail(f"{where}: `{shlex.join(argv)}` does not parse:\n{message}")
