"""The README is what it says it is: the two commands (the test command exactly what
``.ci/run`` runs), a figure that exists, and links that resolve. Its former examples
live in the user guide, where ``tests/test_docs_site.py`` runs every one of them."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"


def _bash_lines() -> list[str]:
    return [line.strip() for block in re.findall(r"```bash\n(.*?)```", README.read_text(),
                                                 flags=re.S)
            for line in block.splitlines() if line.strip()]


def test_the_readme_gives_the_two_commands():
    lines = _bash_lines()
    assert any(line.endswith(".venv/bin/tunnelsim demo") for line in lines), lines
    assert any(line.endswith(".venv/bin/python -m pytest") for line in lines), lines


def test_the_readme_test_command_is_what_ci_runs():
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    i = ci.index("# --- the README's test command, verbatim ---")
    tests = [line for line in _bash_lines() if "pytest" in line]
    assert tests == [ci[i + 1].strip()]


def test_readme_figures_exist():
    links = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", README.read_text())
    assert links
    for link in links:
        p = README.parent / link
        assert p.is_file() and p.read_bytes()[:4] == b"\x89PNG", link


def test_readme_links_resolve():
    """Every relative link (the docs pages, RESULTS.md) names a file of the repository."""
    links = [link.split("#")[0] for link in
             re.findall(r"(?<!!)\[[^\]]*\]\(([^)]+)\)", README.read_text())
             if "://" not in link]
    assert len(links) > 10
    missing = [link for link in links if not (README.parent / link).exists()]
    assert not missing, missing
