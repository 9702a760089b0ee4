"""JSON in and out: one reader with clear errors, one writer, one cleaner.

Reports, rig and board files and evaluation tables all go through here, so NaN, numpy
scalars and arrays are handled the same way everywhere: non-finite numbers become
``null`` (JSON has no NaN), numpy values become Python values.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ._atomic import write_atomic
from .errors import SRDEError

__all__ = ["json_safe", "load_json_source", "dump_json"]


def json_safe(value: Any) -> Any:
    """Return ``value`` with only JSON types: NaN/inf -> None, numpy -> Python, paths -> str.

    Mappings (keys as str), lists, tuples and arrays are cleaned recursively; other
    values are returned as they are (``json.dumps`` then says if they cannot be written).

    Examples
    --------
    >>> import numpy as np
    >>> json_safe({"epe": np.float32(0.5), "rmse": float("nan"), "c": np.array([1.0, np.inf])})
    {'epe': 0.5, 'rmse': None, 'c': [1.0, None]}
    """
    if isinstance(value, Mapping):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, np.ndarray):
        return json_safe(value.tolist())
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, os.PathLike):
        return str(value)
    return value

def load_json_source(source: Any, name: str, error: type[SRDEError]) -> Any:
    """Parse JSON from a file path or from a JSON string (one starting with ``{``).

    Parameters
    ----------
    source : str or os.PathLike
    name : str
        What the JSON describes (``"rig"`` for ``rig.json``), for messages.
    error : type of SRDEError
        Raised for a missing or unreadable file and for invalid JSON.
    """
    if isinstance(source, os.PathLike) or (
        isinstance(source, str) and not source.lstrip().startswith("{")
    ):
        path = Path(source)
        try:
            found = path.is_file()
        except OSError:  # a name the OS refuses to look up (too long, say)
            found = False
        if not found:
            raise error(f"{name} file: expected an existing {name}.json, got {str(path)!r}")
        try:
            text = path.read_text(errors="replace")
        except OSError as exc:
            raise error(f"{path}: expected a readable {name}.json, got {exc}") from None
        where = str(path)
    elif isinstance(source, str):
        text, where = source, f"{name} JSON"
    else:
        raise error(f"{name}: expected a path or a JSON string, got {type(source).__name__}")
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise error(f"{where}: expected valid JSON, got a parse error: {exc}") from None
    except RecursionError:
        raise error(f"{where}: expected JSON nested a few levels deep, got nesting deeper "
                    f"than Python's parser allows") from None
    except ValueError as exc:  # e.g. an integer literal beyond int's digit limit
        raise error(f"{where}: expected valid JSON numbers, got {exc}") from None


def dump_json(data: Any, path: str | os.PathLike | None = None) -> str:
    """Serialise ``data`` as indented JSON; write it to ``path`` if given. Returns the text."""
    text = json.dumps(data, indent=2) + "\n"
    if path is not None:
        write_atomic(path, text)
    return text

