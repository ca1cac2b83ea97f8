"""MkDocs hook: the command-line reference (docs/reference/cli.md) written from m3c's own argument parser at build
time, so the page cannot drift from the code. The page holds the marker line below; the hook replaces it."""

from __future__ import annotations

import argparse

MARKER = "<!-- generated: m3c command line -->"


def _subcommands(parser: argparse.ArgumentParser):
    for action in parser._actions:  # argparse keeps subparsers only here
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help for a in action._choices_actions}
            for name, sub in action.choices.items():
                yield name, helps.get(name) or "", sub


def _arguments_table(parser: argparse.ArgumentParser) -> list[str]:
    rows = []
    for action in parser._actions:
        if isinstance(action, (argparse._HelpAction, argparse._SubParsersAction)):
            continue
        if action.option_strings:
            name = ", ".join(f"`{o}`" for o in action.option_strings)
            if action.nargs != 0:
                metavar = action.metavar if action.metavar is not None else action.dest.upper()
                if isinstance(metavar, tuple):
                    metavar = " ".join(metavar)
                name += f" `{metavar}`"
        else:
            name = f"`{action.metavar or action.dest}`"
        text = (action.help or "").replace("|", "\\|").replace("\n", " ")
        if action.default not in (None, False, argparse.SUPPRESS) and action.option_strings \
                and "default" not in text:
            text += f" (default: `{action.default}`)"
        rows.append(f"| {name} | {text} |")
    if not rows:
        return []
    return ["| argument | meaning |", "|---|---|", *rows, ""]


def _section(path: list[str], help_text: str, parser: argparse.ArgumentParser, level: int) -> list[str]:
    lines = [f"{'#' * min(level, 6)} `{' '.join(path)}`", ""]
    if help_text:
        lines += [help_text[0].upper() + help_text[1:] + ("" if help_text.endswith(".") else "."), ""]
    usage = parser.format_usage().strip().removeprefix("usage: ")
    lines += ["```text", usage, "```", ""]
    lines += _arguments_table(parser)
    for name, sub_help, sub in _subcommands(parser):
        lines += _section([*path, name], sub_help, sub, level + 1)
    return lines


def cli_reference() -> str:
    from m3c import __version__
    from m3c.cli.parser import build_parser

    parser = build_parser()
    lines = [f"Generated from `m3c.cli.parser.build_parser()` of M3C {__version__}. Every command also takes "
             "`-h` / `--help`.", ""]
    for name, help_text, sub in _subcommands(parser):
        lines += _section(["m3c", name], help_text, sub, 2)
    return "\n".join(lines)


def on_page_markdown(markdown: str, page, config, files) -> str:  # noqa: ARG001 - MkDocs' hook signature
    if MARKER in markdown:
        return markdown.replace(MARKER, cli_reference())
    return markdown
