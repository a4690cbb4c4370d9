"""The README's Python snippets run as written (a newcomer copies them first)."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
SNIPPETS = re.findall(r"```python\n(.*?)```", README.read_text(encoding="utf-8"), flags=re.DOTALL)


def test_readme_has_python_snippets():
    assert SNIPPETS, "README.md has no ```python block"


@pytest.mark.parametrize("index", range(len(SNIPPETS)))
def test_readme_snippet_runs(index, capsys):
    code = SNIPPETS[index]
    exec(compile(code, f"README.md python block {index + 1}", "exec"), {"__name__": "readme_snippet"})
    out = capsys.readouterr().out
    if "print(" in code:
        assert out.strip(), "the snippet prints nothing"
