"""The chapter notebooks' step-through pieces: one module per chapter (``ch2`` … ``ch5``),
each a set of small functions that run one step of an algorithm with the library's own code
and return what the notebook shows (a figure or a table). Nothing here is used by an
experiment, so changing it never makes a stored result stale."""
