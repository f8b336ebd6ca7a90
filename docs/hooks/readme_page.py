"""The site's landing page is the repository's README, so the two cannot drift apart.

`docs/index.md` is a placeholder; at build time its text is replaced by README.md with the
README's links rewritten from the repository's root to the docs folder (`docs/tour.md` →
`tour.md`). A link to a repository path outside `docs/` (the notebooks) has no page on the
site and is written as that path.
"""

from __future__ import annotations

import pathlib
import re

README = pathlib.Path(__file__).resolve().parents[2] / "README.md"
_LINK = re.compile(r"(!?)\[([^\]]*)\]\(([^)\s]+)\)")


def _site_link(match: re.Match) -> str:
    bang, text, target = match.groups()
    if target.startswith(("http://", "https://", "#")):
        return match.group(0)
    if target.startswith("docs/"):
        return f"{bang}[{text}]({target.removeprefix('docs/')})"
    return f"{text} (`{target}` in the repository)"


def readme_as_landing_page(text: str) -> str:
    """README.md's markdown with its links valid from the docs folder."""
    return _LINK.sub(_site_link, text)


def on_page_markdown(markdown, page, config, files):
    if page.file.src_uri != "index.md":
        return markdown
    return readme_as_landing_page(README.read_text(encoding="utf-8"))
