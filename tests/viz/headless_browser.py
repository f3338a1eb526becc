"""Headless Chromium driven over the DevTools protocol: a helper of the browser tests
(``tests/viz/test_browser.py``, ``tests/viz/test_live_widgets.py``, which also start JupyterLab
with :class:`JupyterLab`) and of the ``docs/make_*screenshot*.py`` scripts, not part of the
package.

Needs Debian's Chromium (``apt-get install chromium``) and the ``websockets`` package (a viser
dependency). Import it as ``from headless_browser import HeadlessBrowser`` with this folder on
``sys.path`` (pytest puts it there for the tests beside it).
"""

from __future__ import annotations

import base64
import json
import shutil
import subprocess
import tempfile
import time
import urllib.request
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest

__all__ = ["HeadlessBrowser", "JupyterLab"]

CHROMIUM = Path("/usr/bin/chromium")
"""Debian's headless Chromium, which the browser tests drive."""

NEEDS_CHROMIUM = [
    pytest.mark.browser,
    pytest.mark.skipif(
        not CHROMIUM.exists(),
        reason="needs Debian's headless Chromium at /usr/bin/chromium (apt-get install chromium)",
    ),
]
"""``pytestmark`` of a browser test module."""


class HeadlessBrowser:
    """Headless Chromium driven over the DevTools protocol (for screenshots and browser tests).

    Starts ``chromium --headless`` with a fresh profile and a DevTools port chosen by the OS,
    then talks to the page over its websocket (the ``websockets`` package viser depends on).

    Parameters
    ----------
    size : tuple of int
        Viewport (width, height) in CSS pixels.
    executable : str, optional
        Chromium binary (default: ``chromium`` on the PATH, else ``/usr/bin/chromium``).
    timeout : float
        Seconds to wait for Chromium to start.
    """

    FLAGS = (
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--hide-scrollbars",
        "--mute-audio",
    )

    def __init__(
        self,
        size: tuple[int, int] = (1024, 700),
        executable: str | None = None,
        timeout: float = 30.0,
    ) -> None:
        exe = executable or shutil.which("chromium") or "/usr/bin/chromium"
        if not Path(exe).exists() and shutil.which(exe) is None:
            raise ValueError(f"executable: no Chromium at {exe!r} (apt-get install chromium)")
        width, height = (int(v) for v in size)
        self.size = (width, height)
        self._profile = tempfile.mkdtemp(prefix="skillkit-chromium-")
        self._proc = subprocess.Popen(
            [
                exe,
                *self.FLAGS,
                f"--user-data-dir={self._profile}",
                f"--window-size={width},{height}",
                "--remote-debugging-port=0",
                "about:blank",
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        self._ws = None
        self._id = 0
        try:
            port_file = Path(self._profile) / "DevToolsActivePort"
            deadline = time.monotonic() + timeout
            while not (port_file.exists() and port_file.read_text().strip()):
                if self._proc.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(f"chromium did not start (exit code {self._proc.poll()})")
                time.sleep(0.05)
            devtools_port = int(port_file.read_text().split()[0])
            with urllib.request.urlopen(
                f"http://127.0.0.1:{devtools_port}/json", timeout=timeout
            ) as r:
                pages = [t for t in json.load(r) if t.get("type") == "page"]
            from websockets.sync.client import connect

            self._ws = connect(
                pages[0]["webSocketDebuggerUrl"], max_size=2**28, open_timeout=timeout
            )
            self.call(
                "Emulation.setDeviceMetricsOverride",
                width=width,
                height=height,
                deviceScaleFactor=1,
                mobile=False,
            )
        except BaseException:
            self.close()
            raise

    def call(self, method: str, timeout: float = 60.0, **params) -> dict:
        """Send one DevTools command and return its ``result``."""
        self._id += 1
        self._ws.send(json.dumps({"id": self._id, "method": method, "params": params}))
        deadline = time.monotonic() + timeout
        while True:
            message = json.loads(self._ws.recv(timeout=max(deadline - time.monotonic(), 0.01)))
            if message.get("id") == self._id:
                if "error" in message:
                    raise RuntimeError(f"{method}: {message['error']}")
                return message.get("result", {})

    def open(self, url: str) -> None:
        """Navigate to ``url``."""
        self.call("Page.navigate", url=url)

    def text(self) -> str:
        """The page's whole text content (hidden elements included)."""
        result = self.call(
            "Runtime.evaluate", expression="document.body ? document.body.textContent : ''"
        )
        return str(result.get("result", {}).get("value", ""))

    def hide(self, selector: str) -> int:
        """Hide the elements matching CSS ``selector`` (e.g. notifications); return how many."""
        script = (
            f"(() => {{ const found = document.querySelectorAll({json.dumps(selector)}); "
            "found.forEach(e => e.style.setProperty('display', 'none', 'important')); "
            "return found.length; })()"
        )
        result = self.call("Runtime.evaluate", expression=script)
        return int(result.get("result", {}).get("value", 0))

    def wait_for_text(self, needles: Sequence[str], timeout: float = 60.0) -> str:
        """Poll the page until its text contains every needle; return the text."""
        deadline = time.monotonic() + timeout
        while True:
            text = self.text()
            missing = [n for n in needles if n not in text]
            if not missing:
                return text
            if time.monotonic() > deadline:
                raise TimeoutError(f"page text still lacks {missing} after {timeout:g} s")
            time.sleep(0.25)

    def screenshot(self, timeout: float = 300.0) -> np.ndarray:
        """The viewport as an RGB array of shape (height, width, 3), uint8."""
        from io import BytesIO

        from PIL import Image

        result = self.call("Page.captureScreenshot", timeout=timeout, format="png")
        data = base64.b64decode(result["data"])
        return np.asarray(Image.open(BytesIO(data)).convert("RGB"))

    def wait_frames(self, n: int = 3, timeout: float = 120.0) -> None:
        """Wait until the page has rendered ``n`` more animation frames."""
        script = (
            f"new Promise(done => {{ let k = {int(n)}; const f = () => "
            "(--k > 0 ? requestAnimationFrame(f) : done(true)); requestAnimationFrame(f); })"
        )
        self.call("Runtime.evaluate", timeout=timeout, expression=script, awaitPromise=True)

    def settled_screenshot(
        self, timeout: float = 120.0, tolerance: float = 0.05, frames: int = 3
    ) -> np.ndarray:
        """A screenshot once the page has stopped changing.

        Takes screenshots ``frames`` rendered animation frames apart (so a renderer that is
        still busy loading is not mistaken for a settled one) until two consecutive
        comparisons differ by less than ``tolerance`` grey levels on average.
        """
        deadline = time.monotonic() + timeout
        self.wait_frames(frames, timeout)
        previous, stable = self.screenshot(timeout), 0
        while stable < 2:
            if time.monotonic() > deadline:
                raise TimeoutError(f"the page kept changing for {timeout:g} s")
            self.wait_frames(frames, timeout)
            time.sleep(0.2)
            image = self.screenshot(timeout)
            stable = (
                stable + 1 if np.mean(np.abs(image.astype(float) - previous)) < tolerance else 0
            )
            previous = image
        return previous

    def close(self) -> None:
        """Quit Chromium and delete its profile."""
        if self._ws is not None:
            try:
                self._ws.close()
            except Exception:  # already gone
                pass
            self._ws = None
        if self._proc.poll() is None:
            self._proc.terminate()
            try:
                self._proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait()
        shutil.rmtree(self._profile, ignore_errors=True)

    def __enter__(self) -> HeadlessBrowser:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class JupyterLab:
    """A JupyterLab server on 127.0.0.1 for browser tests, serving one folder.

    Starts ``jupyter lab`` headless on a free localhost port with a random token, its
    settings, workspaces and runtime files in a temporary folder (news and update checks off,
    the application exposed as ``window.jupyterapp`` for the page scripts), and stops it on
    :meth:`close`. Use it as a context manager.

    Parameters
    ----------
    root : str or Path
        The folder the server serves (the notebooks the test opens).
    timeout : float
        Seconds to wait for the server to answer.
    """

    def __init__(self, root, timeout: float = 60.0) -> None:
        import os
        import secrets
        import socket
        import sys

        self.root = Path(root)
        if not self.root.is_dir():
            raise ValueError(f"root: expected an existing folder, got {str(root)!r}")
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            self.port = s.getsockname()[1]
        self.token = secrets.token_hex(16)
        self._home = Path(tempfile.mkdtemp(prefix="skillkit-lab-"))
        settings = self._home / "settings" / "@jupyterlab" / "apputils-extension"
        settings.mkdir(parents=True)
        (settings / "notification.jupyterlab-settings").write_text(
            json.dumps({"fetchNews": "false", "checkForUpdates": False})
        )
        env = {
            **os.environ,
            "JUPYTER_RUNTIME_DIR": str(self._home / "runtime"),
            "JUPYTER_CONFIG_DIR": str(self._home / "config"),
            "IPYTHONDIR": str(self._home / "ipython"),
        }
        self._log = open(self._home / "server.log", "wb")  # noqa: SIM115  (closed in close())
        self._proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "jupyter",
                "lab",
                "--no-browser",
                "--ServerApp.ip=127.0.0.1",
                f"--ServerApp.port={self.port}",
                "--ServerApp.port_retries=0",
                f"--IdentityProvider.token={self.token}",
                f"--ServerApp.root_dir={self.root}",
                f"--LabApp.user_settings_dir={self._home / 'settings'}",
                f"--LabApp.workspaces_dir={self._home / 'workspaces'}",
                "--LabApp.expose_app_in_browser=True",
                *(["--allow-root"] if os.geteuid() == 0 else []),
            ],
            stdout=self._log,
            stderr=subprocess.STDOUT,
            env=env,
        )
        try:
            deadline = time.monotonic() + timeout
            while True:
                if self._proc.poll() is not None:
                    raise RuntimeError(f"jupyter lab exited ({self._proc.poll()}): {self.log()}")
                try:
                    with urllib.request.urlopen(f"{self.url('api/status')}", timeout=5):
                        break
                except OSError:
                    if time.monotonic() > deadline:
                        raise TimeoutError(f"jupyter lab did not answer in {timeout:g} s") from None
                    time.sleep(0.25)
        except BaseException:
            self.close()
            raise

    def url(self, path: str = "lab") -> str:
        """The address of ``path`` on the server, with the token."""
        return f"http://127.0.0.1:{self.port}/{path}?token={self.token}"

    def log(self) -> str:
        """The server's output so far (the end of it)."""
        self._log.flush()
        return (self._home / "server.log").read_text(errors="replace")[-4000:]

    def close(self) -> None:
        """Stop the server (and its kernels) and delete its temporary folder."""
        if self._proc.poll() is None:
            self._proc.terminate()  # SIGTERM: the server shuts its kernels down
            try:
                self._proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait()
        self._log.close()
        shutil.rmtree(self._home, ignore_errors=True)

    def __enter__(self) -> JupyterLab:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def evaluate(browser: HeadlessBrowser, expression: str, timeout: float = 60.0):
    """The value of a JavaScript expression in the page (promises awaited); raises on a
    thrown error."""
    reply = browser.call(
        "Runtime.evaluate",
        timeout=timeout,
        expression=expression,
        awaitPromise=True,
        returnByValue=True,
    )
    if "exceptionDetails" in reply:
        raise RuntimeError(f"page script failed: {reply['exceptionDetails']}")
    return reply.get("result", {}).get("value")


def wait_until(browser: HeadlessBrowser, expression: str, timeout: float, what: str):
    """Poll a JavaScript expression until it is truthy; return its value."""
    deadline = time.monotonic() + timeout
    while True:
        value = evaluate(browser, expression)
        if value:
            return value
        if time.monotonic() > deadline:
            raise TimeoutError(f"{what}: not after {timeout:g} s")
        time.sleep(0.25)


def run_notebook_in_lab(
    browser: HeadlessBrowser, lab: JupyterLab, name: str, timeout: float = 60.0
) -> None:
    """Open notebook ``name`` of ``lab`` in the page, wait for its kernel, run all its cells
    and wait until the kernel is idle again (the left side bar closed)."""
    browser.call("Emulation.setFocusEmulationEnabled", enabled=True)  # as if in front
    browser.open(lab.url(f"lab/tree/{name}"))
    panel = (
        "(window.jupyterapp && [...window.jupyterapp.shell.widgets('main')]"
        f".find(w => w.sessionContext && w.context && w.context.path === {json.dumps(name)}))"
    )
    kernel = (
        f"(() => {{ const w = {panel}; const k = w && w.sessionContext.session &&"
        " w.sessionContext.session.kernel; return k ? k.status : ''; })()"
    )
    wait_until(browser, f"{kernel} === 'idle'", timeout, "the notebook's kernel is idle")
    evaluate(browser, "window.jupyterapp.shell.collapseLeft()")
    evaluate(browser, f"window.jupyterapp.shell.activateById({panel}.id)")
    evaluate(browser, "window.jupyterapp.commands.execute('notebook:run-all-cells')", timeout)
    wait_until(
        browser,
        "[...document.querySelectorAll('.jp-Notebook .jp-InputPrompt')]"
        ".every(e => /\\[\\d+\\]/.test(e.textContent))",
        timeout,
        "every cell ran",
    )
    wait_until(browser, f"{kernel} === 'idle'", timeout, "the kernel is idle after the run")


def type_into_slider(
    browser: HeadlessBrowser, text: str, index: int = 0, timeout: float = 30.0
) -> None:
    """Type ``text`` into the readout of the ``index``-th ipywidgets slider on the page and
    press Enter, as a user sets a slider to an exact value."""
    readout = f"document.querySelectorAll('.widget-slider .widget-readout')[{int(index)}]"
    wait_until(browser, f"!!{readout}", timeout, "a slider is on the page")
    evaluate(
        browser,
        f"(() => {{ const r = {readout}; r.scrollIntoView({{block: 'center'}}); r.focus();"
        " const s = window.getSelection(); s.removeAllRanges(); const g = document.createRange();"
        " g.selectNodeContents(r); s.addRange(g); return true; })()",
    )
    browser.call("Input.insertText", text=text)
    for kind in ("keyDown", "keyUp"):
        browser.call(
            "Input.dispatchKeyEvent",
            type=kind,
            key="Enter",
            code="Enter",
            windowsVirtualKeyCode=13,
            nativeVirtualKeyCode=13,
        )
