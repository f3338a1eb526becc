"""What the chapter notebooks call: per chapter (``ch2`` … ``ch5``, ``own_skill``) functions
that run one step of an algorithm with the library's code and return a figure or a table, the
notebooks' tables and the animations of Figs 3.2, 3.8. Nothing in the library imports it.
"""
