"""Checkpoints: atomic round trip; corrupted, truncated and foreign files are refused."""

import numpy as np
import pytest

from skillkit.experiments import checkpoint
from skillkit.experiments.checkpoint import CheckpointError


def _ident(**changes):
    base = checkpoint.identity("fig3.3", {"eps": 0.6, "n": 3}, trial=1, seed=7, code="0.1.0:abc")
    base.update(changes)
    return base


def test_round_trip(tmp_path):
    payload = {"policy": np.arange(5.0), "curve": [1.0, 2.0]}
    path = tmp_path / "t.ckpt"
    checkpoint.save(path, _ident(), payload, kind="state")
    kind, back, seconds = checkpoint.load(path, _ident())
    assert kind == "state" and seconds is None
    np.testing.assert_array_equal(back["policy"], payload["policy"])
    assert back["curve"] == payload["curve"]
    assert list(tmp_path.iterdir()) == [path]  # no temporary files left behind


def test_compute_time_is_kept_in_the_header(tmp_path):
    path = tmp_path / "t.ckpt"
    checkpoint.save(path, _ident(), {"a": 1}, kind="result", seconds=12.5)
    assert checkpoint.load(path, _ident()).seconds == 12.5


def test_missing_file_is_none(tmp_path):
    assert checkpoint.load(tmp_path / "none.ckpt", _ident()) is None


def test_truncated_file_is_refused(tmp_path):
    path = tmp_path / "t.ckpt"
    checkpoint.save(path, _ident(), list(range(1000)), kind="result")
    raw = path.read_bytes()
    path.write_bytes(raw[:-10])
    with pytest.raises(CheckpointError, match="checksum"):
        checkpoint.load(path, _ident())
    path.write_bytes(raw[:20])
    with pytest.raises(CheckpointError):
        checkpoint.load(path, _ident())


def test_corrupted_payload_and_foreign_file_are_refused(tmp_path):
    path = tmp_path / "t.ckpt"
    checkpoint.save(path, _ident(), {"a": 1}, kind="result")
    raw = bytearray(path.read_bytes())
    raw[-3] ^= 0xFF
    path.write_bytes(bytes(raw))
    with pytest.raises(CheckpointError, match="checksum"):
        checkpoint.load(path, _ident())
    path.write_bytes(b"not a checkpoint at all")
    with pytest.raises(CheckpointError, match="not a skillkit checkpoint"):
        checkpoint.load(path, _ident())


@pytest.mark.parametrize(
    "field, value",
    [
        ("settings", {"eps": 0.5, "n": 3}),
        ("code", "0.1.0:def"),
        ("trial", 2),
        ("seed", 8),
        ("experiment", "fig3.5"),
    ],
)
def test_other_settings_trial_or_code_are_refused(tmp_path, field, value):
    path = tmp_path / "t.ckpt"
    checkpoint.save(path, _ident(), {"a": 1}, kind="state")
    with pytest.raises(CheckpointError, match=field) as refused:
        checkpoint.load(path, _ident(**{field: value}))
    assert "--fresh" in str(refused.value) and "fresh=True" in str(refused.value)


def test_code_fingerprint_changes_with_the_source(tmp_path, monkeypatch):
    mod = tmp_path / "m.py"
    mod.write_text("def f():\n    return 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    import importlib

    m = importlib.import_module("m")
    before = checkpoint.code_fingerprint(m.f)
    mod.write_text("def f():\n    return 2\n")
    assert checkpoint.code_fingerprint(m.f) != before
