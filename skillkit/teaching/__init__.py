"""What the chapter notebooks call (``ch2`` … ``ch5``, ``own_skill``): one step of an algorithm
with the library's code as a figure or a table, the notebooks' tables and the animations of
Figs 3.2, 3.8. Nothing in the library imports it."""
