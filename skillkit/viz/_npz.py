"""Reading the viewer's ``.npz`` files (policy histories, prediction layers) in one place."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np


def read_npz(path: str | Path, name: str) -> dict[str, np.ndarray]:
    """Every array of an ``.npz`` file (read without pickles), or a ``ValueError`` naming
    the argument ``name`` when the file is not a readable archive."""
    try:
        with np.load(Path(path), allow_pickle=False) as data:
            return {k: data[k] for k in data.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise ValueError(f"{name}: {path} is not a readable .npz file ({exc})") from None
