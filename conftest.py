"""Repository-wide pytest configuration: the notebooks under ``notebooks/`` are executed by
nbmake as part of ``python -m pytest``; their kernels inherit this environment, so every live
re-run in them uses the ``smoke`` scale (seconds) unless ``SKILLKIT_SCALE`` says otherwise, and
writes under ``SKILLKIT_RUNS``."""

import os
import shutil
import tempfile

os.environ.setdefault("SKILLKIT_SCALE", "smoke")
# The notebooks' live runs go to a fresh folder per test session, so checkpoints left in
# notebooks/runs/ by a user (or by older code) are neither resumed nor refused here.
_RUNS = tempfile.mkdtemp(prefix="skillkit-notebook-runs-")
os.environ.setdefault("SKILLKIT_RUNS", _RUNS)
os.environ.setdefault("MUJOCO_GL", "disable")  # headless: never probe for an OpenGL backend
os.environ.setdefault("MPLBACKEND", "Agg")
# The tests work on small matrices, where multi-threaded BLAS/OpenMP only adds overhead (5–25×
# slower on a loaded 2-core machine) and makes results depend on the thread count.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")


def pytest_unconfigure(config):
    shutil.rmtree(_RUNS, ignore_errors=True)


# --------------------------------------------------------------------------- notebooks
# Every notebook nbmake executes must write nothing to stderr (a warning is either fixed at its
# cause or explained and captured on purpose): a stderr output fails the notebook's test like
# an error would. The execution time of each notebook is printed at the end of the run. With
# SKILLKIT_SITE_NOTEBOOKS set, each executed notebook is kept in that folder.
_NOTEBOOK_SECONDS: dict[str, float] = {}


def _checked(execute):
    def run(self):
        from nbmake.nb_result import NotebookError

        from skillkit.viz.nbcheck import execution_seconds, stderr_outputs

        result = execute(self)
        _NOTEBOOK_SECONDS[self.filename.name] = sum(execution_seconds(result.nb).values())
        keep = os.environ.get("SKILLKIT_SITE_NOTEBOOKS")
        if keep and result.error is None:  # the site test (tests/viz/test_site.py) reads them
            import nbformat

            nbformat.write(result.nb, os.path.join(keep, self.filename.name))
        found = stderr_outputs(result.nb)
        if result.error is None and found:
            lines = [f"cell {i}: {text}" for i, text in found]
            result.error = NotebookError(
                summary=f"{len(found)} stderr output(s); first in cell {found[0][0]}",
                trace="stderr outputs (fix the cause, or capture it on purpose):\n"
                + "\n".join(lines),
                failing_cell_index=found[0][0],
            )
        return result

    run.skillkit_checked = True
    return run


def pytest_configure(config):
    try:
        from nbmake.nb_run import NotebookRun
    except ImportError:  # nbmake not installed: no notebooks run
        return
    if not getattr(NotebookRun.execute, "skillkit_checked", False):
        NotebookRun.execute = _checked(NotebookRun.execute)


def pytest_terminal_summary(terminalreporter):
    if _NOTEBOOK_SECONDS:
        terminalreporter.write_sep("-", "notebook execution (s, sum of cell times)")
        for name, seconds in sorted(_NOTEBOOK_SECONDS.items()):
            terminalreporter.write_line(f"{name:40s} {seconds:7.1f}")
