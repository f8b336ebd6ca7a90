"""Every ```python block of README.md and docs/*.md runs as written.

The blocks of one file run in order in one fresh namespace (later blocks may use what earlier
ones defined, as a reader would), in a temporary working directory (blocks may write files).
Blocks are examples, so they are kept small enough that a whole file runs in about a minute.
"""

import re
import textwrap
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
# A fence may be indented (a block inside a list item): the closing fence has the same indent.
_BLOCK = re.compile(r"^(?P<indent>[ \t]*)```python[ \t]*\n(?P<code>.*?)^(?P=indent)```", re.M | re.S)


def python_blocks(text: str) -> list[tuple[int, str]]:
    """The ```python blocks of a Markdown text: (line number, dedented code)."""
    return [
        (text.count("\n", 0, m.start()) + 1, textwrap.dedent(m.group("code")))
        for m in _BLOCK.finditer(text)
    ]


def test_blocks_are_found():
    # The collector itself: an indented block and a plain one, in order.
    sample = "x\n```python\na = 1\n```\n- item\n   ```python\n   b = a + 1\n   ```\n"
    assert python_blocks(sample) == [(2, "a = 1\n"), (6, "b = a + 1\n")]


def _documents_with_code():
    paths = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    return [p for p in paths if python_blocks(p.read_text(encoding="utf-8"))]


DOCUMENTS = _documents_with_code()


def test_the_readme_and_the_getting_started_page_have_code():
    assert {"README.md", "getting_started.md"} <= {p.name for p in DOCUMENTS}


@pytest.mark.parametrize("path", DOCUMENTS, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_python_blocks_run(path, tmp_path, monkeypatch):
    blocks = python_blocks(path.read_text(encoding="utf-8"))
    monkeypatch.chdir(tmp_path)
    namespace = {"__name__": f"docs_{path.stem}"}
    for line, code in blocks:
        start = time.perf_counter()
        try:
            exec(compile(code, f"{path.name}:{line}", "exec"), namespace)
        except Exception as error:
            raise AssertionError(
                f"the python block at {path.relative_to(ROOT)}:{line} fails: "
                f"{type(error).__name__}: {error}"
            ) from error
        print(f"{path.name}:{line}: {time.perf_counter() - start:.1f} s")


def test_the_tours_continuation_comment_names_the_range_of_its_call():
    # The comment said "to -0.3: across the grazing" above a call that runs from 0.2 to 0.1.
    code = "\n".join(code for _, code in python_blocks((ROOT / "docs" / "tour.md").read_text(
        encoding="utf-8")) if "continue_orbit(" in code)
    call = re.search(r"continue_orbit\([^\n]*, ([-\d.]+), ([-\d.]+)\)", code)
    assert call, code
    assert f"# μ from {call[1]} down to {call[2]}:" in code
