"""Where a benchmark's tables go: ``<name>.md`` for people, ``<name>.json`` for scripts."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any


def write_results(folder: Path, name: str, lines: list[str], payload: Any, *,
                  default: Callable[[Any], Any] | None = None) -> None:
    """Write ``name.md`` (the lines) and ``name.json`` (the payload) and print the lines.

    ``default`` converts what ``json`` cannot write itself (numpy scalars, say).
    """
    folder.mkdir(parents=True, exist_ok=True)
    text = "\n".join(lines)
    (folder / f"{name}.md").write_text(text)
    (folder / f"{name}.json").write_text(json.dumps(payload, indent=1, default=default))
    print(text)
