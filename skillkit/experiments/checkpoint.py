"""Atomic, self-checking checkpoints for experiment trials.

A file is ``MAGIC + header length + JSON header + pickled payload``; the header binds the
payload to its experiment, settings, trial, seed and code (skillkit version and
:mod:`skillkit.experiments.provenance` fingerprint) and holds its SHA-256. A corrupt file or
one of another run raises :class:`CheckpointError`; writes are renamed into place.
"""

from __future__ import annotations

import hashlib
import json
import os
import pickle
import struct
from pathlib import Path
from typing import Any, NamedTuple

MAGIC = b"SKILLKIT-CKPT-1\n"

START_OVER = "start over with `skillkit reproduce ... --fresh` or `reproduce(..., fresh=True)`"
"""What a refused checkpoint's message tells the user to do."""


class CheckpointError(RuntimeError):
    """A checkpoint exists but cannot be trusted (corrupt, truncated or foreign)."""


def code_fingerprint(func) -> str:
    """skillkit version and the provenance fingerprint of the module defining ``func``."""
    import skillkit
    from skillkit.experiments.provenance import code_fingerprint as fingerprint

    try:
        code = fingerprint(func)
    except (ValueError, OSError, SyntaxError):
        code = hashlib.sha256(getattr(func, "__qualname__", repr(func)).encode()).hexdigest()[:16]
    return f"{skillkit.__version__}:{code}"


def identity(exp_id: str, settings: dict, trial: int, seed: int, code: str) -> dict:
    """What a trial's checkpoint must match to be resumed from."""
    return {
        "experiment": exp_id,
        "settings": json.loads(json.dumps(settings, sort_keys=True, default=str)),
        "trial": int(trial),
        "seed": int(seed),
        "code": code,
    }


def save(
    path: str | Path, ident: dict, payload: Any, kind: str, seconds: float | None = None
) -> None:
    """Write ``payload`` (``kind`` ``"state"`` mid-trial or ``"result"``) to ``path``
    atomically, bound to ``ident`` (:func:`identity`), with the compute ``seconds`` so far."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    body = pickle.dumps(payload, protocol=pickle.HIGHEST_PROTOCOL)
    sha = hashlib.sha256(body).hexdigest()
    fields = {**ident, "kind": kind, "sha256": sha, "size": len(body), "seconds": seconds}
    header = json.dumps(fields, sort_keys=True).encode()
    tmp = path.with_name(path.name + f".tmp{os.getpid()}")
    with open(tmp, "wb") as fh:
        fh.write(MAGIC + struct.pack("<I", len(header)) + header + body)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


class Loaded(NamedTuple):
    """A checkpoint read by :func:`load`."""

    kind: str
    payload: Any
    seconds: float | None  # compute time so far; None in checkpoints written without it


def load(path: str | Path, ident: dict) -> Loaded | None:
    """The checkpoint at ``path`` (:class:`Loaded`), or None if there is none; CheckpointError
    for a truncated or corrupted file, or a header not matching ``ident`` (naming the field)."""
    path = Path(path)
    if not path.exists():
        return None
    raw = path.read_bytes()
    if not raw.startswith(MAGIC) or len(raw) < len(MAGIC) + 4:
        raise CheckpointError(f"{path}: not a skillkit checkpoint (bad magic bytes or truncated)")
    (n,) = struct.unpack("<I", raw[len(MAGIC) : len(MAGIC) + 4])
    start = len(MAGIC) + 4
    try:
        header = json.loads(raw[start : start + n])
    except (ValueError, UnicodeDecodeError):
        raise CheckpointError(f"{path}: unreadable header (file truncated or corrupted)") from None
    body = raw[start + n :]
    if len(body) != header.get("size") or hashlib.sha256(body).hexdigest() != header.get("sha256"):
        raise CheckpointError(
            f"{path}: payload does not match its checksum (truncated or corrupted)"
        )
    for key, value in ident.items():
        if header.get(key) != value:
            raise CheckpointError(
                f"{path}: checkpoint belongs to another run "
                f"({key}: {header.get(key)!r} != {value!r}); {START_OVER}"
            )
    return Loaded(header["kind"], pickle.loads(body), header.get("seconds"))
