"""MkDocs hook: the manual's home page is the README, its links made relative to docs/.

One source for the front page (the README a user reads on the repository) and the site's
home; ``docs/index.md`` is only a placeholder the hook replaces.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]


def on_page_read_source(page: Any, config: Any) -> str | None:
    """The README's text for the home page; ``None`` (read the file) for every other page."""
    if page.file.src_uri != "index.md":
        return None
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    # Links into docs/ become site-relative; code spans naming docs/... stay as written.
    return re.sub(r"\]\(docs/", "](", text)
