"""Backticked public names link to their API entries, so docstrings need no autorefs markup.

Docstrings are read in `help()` as well as on the site, so they name the API as plain code,
`grazejax.Scene`, not `[grazejax.Scene][]`. After each page is converted, an inline code
span that holds exactly a dotted `grazejax.` name (a trailing `()` allowed) becomes an
optional cross-reference, which autorefs resolves to the name's entry in the API reference
or leaves as plain code when there is none (no warning). Headings, links, cross-references
already written and code blocks are left alone.
"""

from __future__ import annotations

import re

_SKIP = re.compile(
    r"(<h[1-6]\b.*?</h[1-6]>|<a\b.*?</a>|<autoref\b.*?</autoref>|<pre\b.*?</pre>)", re.DOTALL
)
_NAME = re.compile(r"<code>(grazejax(?:\.[A-Za-z_]\w*)+)(\(\))?</code>")


def _link(match: re.Match) -> str:
    return f'<autoref identifier="{match.group(1)}" optional>{match.group(0)}</autoref>'


def link_code_names(html: str) -> str:
    """`html` with its `<code>grazejax.X</code>` spans wrapped in optional autorefs."""
    parts = _SKIP.split(html)
    # re.split with one group: even indices are the text between skipped elements.
    return "".join(part if i % 2 else _NAME.sub(_link, part) for i, part in enumerate(parts))


def on_page_content(html, page, config, files):
    return link_code_names(html)
