"""What the chapter notebooks call: one module per chapter (``ch2`` … ``ch5``) of small
functions that run one step of an algorithm with the library's own code and return what the
notebook shows (a figure or a table); :mod:`~skillkit.teaching.tables` (the chapter's claims
beside our verdicts) and :mod:`~skillkit.teaching.animation` (Figs 3.2 and 3.8).

The package sits above :mod:`skillkit.experiments` (it reads stored results and uses the
experiments' settings) and nothing in the library imports it, so changing it never makes a
stored result stale."""
