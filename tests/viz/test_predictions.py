"""Prediction-layer files (skillkit.viz.predictions): round trip, documented keys, format
versions and bad input."""

from __future__ import annotations

import numpy as np
import pytest

from skillkit.viz.predictions import PREDICTIONS_FORMAT, load_predictions, save_predictions


def test_prediction_file_round_trip(tmp_path):
    x = np.random.default_rng(0).random((3, 6, 2))
    y = np.random.default_rng(1).random((2, 4, 3))
    path = save_predictions(
        tmp_path / "pred",
        {"gp": x, "emb": y},
        colors={"gp": (1, 2, 3)},
        opacities={"gp": 0.2},
        times={"emb": [0.0, 0.1, 0.2, 0.3]},
    )
    assert path == tmp_path / "pred.npz" and path.exists()
    emb, gp = load_predictions(path)  # sorted by name
    assert gp["name"] == "gp" and gp["space"] == "state"
    np.testing.assert_array_equal(gp["trajectories"], x)
    np.testing.assert_array_equal(gp["color"], [1, 2, 3])
    assert float(gp["opacity"]) == 0.2 and "times" not in gp
    np.testing.assert_array_equal(emb["trajectories"], y)
    np.testing.assert_array_equal(emb["times"], [0.0, 0.1, 0.2, 0.3])
    assert set(emb) == {"name", "trajectories", "times", "space"}


def test_the_file_holds_the_documented_keys(tmp_path):
    x = np.zeros((2, 3, 3))
    path = save_predictions(tmp_path / "p.npz", {"gp": x}, space="points")
    with np.load(path, allow_pickle=False) as data:
        assert set(data.files) == {"gp", "gp__space", "__format__"}
        assert str(data["__format__"]) == PREDICTIONS_FORMAT == "skillkit-predictions-v1"
        assert str(data["gp__space"]) == "points"
        assert data["gp"].shape == (2, 3, 3) and data["gp"].dtype == np.float64


def test_other_format_versions_are_refused_and_unversioned_files_read(tmp_path):
    x = np.ones((1, 2, 2))
    np.savez(tmp_path / "v2.npz", gp=x, __format__=np.asarray("skillkit-predictions-v2"))
    with pytest.raises(ValueError, match="predictions: .* format 'skillkit-predictions-v2'"):
        load_predictions(tmp_path / "v2.npz")
    np.savez(tmp_path / "old.npz", gp=x)  # written before __format__ existed
    (spec,) = load_predictions(tmp_path / "old.npz")
    assert spec["name"] == "gp" and "space" not in spec


def test_bad_prediction_files_and_layers(tmp_path):
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="predictions: .* not a readable"):
        load_predictions(tmp_path / "bad.npz")
    np.savez(tmp_path / "empty.npz", __format__=np.asarray(PREDICTIONS_FORMAT))
    with pytest.raises(ValueError, match="holds no layers"):
        load_predictions(tmp_path / "empty.npz")
    for name in ("", "a__b"):
        with pytest.raises(ValueError, match="layer names"):
            save_predictions(tmp_path / "x", {name: np.zeros((1, 2, 2))})
    with pytest.raises(ValueError, match=r"layers\['gp'\]"):
        save_predictions(tmp_path / "x", {"gp": np.zeros((2, 2))})
    with pytest.raises(ValueError, match="space"):
        save_predictions(tmp_path / "x", {"gp": np.zeros((1, 2, 2))}, space="joint")
