"""The README's relative links point to files that exist (it once cited a DESIGN.md that
did not), and its test command is the one CI runs."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_every_relative_link_of_the_readme_exists():
    text = (ROOT / "README.md").read_text()
    links = [target for target in re.findall(r"\]\(([^)\s]+)\)", text)
             if not re.match(r"[a-z]+://", target) and not target.startswith("#")]
    assert links  # the README links into the docs
    missing = [link for link in links if not (ROOT / link.split("#")[0]).exists()]
    assert missing == []


def test_what_users_read_cites_no_design_file_outside_the_repository():
    from agents.evaluation.summary import AUDIT_NOTE

    assert "DESIGN.md" not in (ROOT / "README.md").read_text()
    assert "DESIGN.md" not in AUDIT_NOTE  # printed under every summary's audit table


def test_ci_runs_the_readme_set_up_and_test_commands():
    readme, ci = (ROOT / "README.md").read_text(), (ROOT / ".ci" / "run").read_text()
    set_up = next(line for line in readme.splitlines() if line.startswith("python3 -m venv"))
    assert set_up in ci
    assert "\npytest -q\n" in readme and "\npytest -q\n" in ci
