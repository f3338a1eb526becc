"""The series of a figure, re-exported from :mod:`skillkit.series` (where they are computed,
inside the experiments' code fingerprint) for the modules that import them from here."""

from __future__ import annotations

from skillkit.series import BAND_KINDS, DASHES, Series, band_text, mean_band, trial_band

__all__ = ["BAND_KINDS", "DASHES", "Series", "band_text", "mean_band", "trial_band"]
