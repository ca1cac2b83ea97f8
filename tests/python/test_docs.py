"""The documentation: the site builds warning-free (`mkdocs build --strict`: every internal link, anchor and
image it names resolves, every docstring the API reference shows parses), the generated pages are what the code
and the benchmarks' JSON give, and the README stays short with links that resolve."""

from __future__ import annotations

import importlib.util
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _load(path: Path, name: str):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow
def test_site_builds_strict(tmp_path):
    pytest.importorskip("mkdocs", reason="needs the docs toolchain (pip install 'm3c[docs]')")
    pytest.importorskip("material", reason="needs mkdocs-material (pip install 'm3c[docs]')")
    pytest.importorskip("mkdocstrings", reason="needs mkdocstrings (pip install 'm3c[docs]')")
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(ROOT / "mkdocs.yml"),
                           "-d", str(tmp_path / "site")], capture_output=True, text=True, cwd=ROOT,
                          env={**__import__("os").environ, "NO_MKDOCS_2_WARNING": "1"}, timeout=600)
    assert done.returncode == 0, done.stderr[-4000:]
    cli = (tmp_path / "site" / "reference" / "cli" / "index.html").read_text()
    assert "m3c run" in cli and "--force-intrinsics" in cli
    api = (tmp_path / "site" / "reference" / "api" / "index.html").read_text()
    assert "load_torch_checkpoint" in api and "BodyModel" in api


def test_cli_reference_lists_every_command():
    from m3c.cli.parser import build_parser

    hook = _load(ROOT / "docs" / "hooks" / "cli_reference.py", "cli_reference_hook")
    text = hook.cli_reference()
    parser = build_parser()
    commands = [name for name, _, _ in hook._subcommands(parser)]
    assert {"run", "info", "view", "export", "batch", "eval"} <= set(commands)
    for name in commands:
        assert f"`m3c {name}`" in text, name
    for _, _, sub in hook._subcommands(parser):
        for action in sub._actions:
            for option in action.option_strings:
                if option.startswith("--") and option != "--help":
                    assert f"`{option}`" in text, option
    page = (ROOT / "docs" / "reference" / "cli.md").read_text()
    assert hook.MARKER in page


def test_benchmark_tables_are_generated_from_the_json():
    tables = _load(ROOT / "tools" / "benchmark_tables.py", "benchmark_tables")
    sources = sorted((ROOT / "docs" / "benchmarks").glob("*.json"))
    assert sources, "docs/benchmarks holds no benchmark JSON"
    page = ROOT / "docs" / "notes" / "benchmarks.md"
    assert tables.main([*map(str, sources), "--check", str(page)]) == 0, \
        "docs/notes/benchmarks.md is stale: python tools/benchmark_tables.py docs/benchmarks/*.json --out " \
        "docs/notes/benchmarks.md"
    for source in sources:  # every table names its command and code version
        assert f"`{source.name}`" in page.read_text()
    assert "m3c eval" in page.read_text() and "M3C " in page.read_text()


def test_readme_is_short_and_its_links_resolve():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 250
    for target in re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", text):
        if "://" in target:
            continue
        assert (ROOT / target).exists(), target
    assert "bash scripts/setup.sh && python3 -m m3c run examples/pexels_walking_moving_camera.mp4 --out out" in text
    assert "bash scripts/setup.sh && bash scripts/test.sh" in text


def test_version_has_one_source(capsys):
    tomllib = pytest.importorskip("tomllib", reason="Python 3.11+")

    import m3c
    from m3c.cli import main

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert "version" not in project and "version" in project["dynamic"]
    with pytest.raises(SystemExit) as done:
        main(["--version"])
    assert done.value.code == 0 and capsys.readouterr().out.strip() == f"m3c {m3c.__version__}"
    changelog = (ROOT / "CHANGELOG.md").read_text()
    assert f"## {m3c.__version__} " in changelog
