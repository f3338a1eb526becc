"""What the chapter notebooks call: per chapter (``ch2`` … ``ch5``, ``own_skill``) small
functions that run one step of an algorithm with the library's code and return a figure or a
table; :mod:`~skillkit.teaching.tables` and :mod:`~skillkit.teaching.animation` (Figs 3.2, 3.8).

Nothing in the library imports this package, so changing it never makes a stored result
stale.
"""
