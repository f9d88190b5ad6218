"""Where the shared reference data live (``../shared/data`` beside the project root, or ``$PARTICLESIM_DATA``)."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["data_dir"]


def data_dir() -> Path:
    """The reference-data folder; raises ``FileNotFoundError`` with the places tried."""
    tried = []
    env = os.environ.get("PARTICLESIM_DATA")
    candidates = [Path(env)] if env else []
    root = Path(__file__).resolve().parent.parent
    candidates += [root.parent / "shared" / "data", root / "shared" / "data"]
    for c in candidates:
        tried.append(str(c))
        if (c / "README.md").is_file():
            return c
    raise FileNotFoundError(
        "particlesim reference data not found; set PARTICLESIM_DATA. Tried: " + ", ".join(tried)
    )
