"""Experiment tests (a package, so its test_contract.py and tests/tasks/test_contract.py can share
a basename)."""
