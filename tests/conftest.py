"""Shared test configuration."""

import os

os.environ.setdefault("MUJOCO_GL", "disable")  # headless: never probe for an OpenGL backend
os.environ.setdefault("MPLBACKEND", "Agg")
