"""A real JupyterLab in a real (headless) browser, as a student sees the labs.

The server runs on a free localhost port with a random token, in a temporary folder holding
copies of the notebooks (so autosave never touches solutions/). Chromium is Debian's package
(``/usr/bin/chromium``, or ``KFKIT_CHROMIUM``), driven by Playwright; no browser is downloaded.
Screenshots go to ``artifacts/browser/`` (ignored by git) for a person to look at.
"""

from __future__ import annotations

import json
import os
import secrets
import shutil
import socket
import subprocess
import sys
import urllib.request
from pathlib import Path

import pytest
from waiting import wait_until

from kfkit.paths import KIT_ROOT

ARTIFACTS = KIT_ROOT / "artifacts" / "browser"
CHROMIUM_FLAGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-dev-shm-usage",
]


def chromium_path() -> str | None:
    return os.environ.get("KFKIT_CHROMIUM") or shutil.which("chromium") or shutil.which("chromium-browser")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def browser():
    """Chromium for one test module: Playwright's sync API runs an event loop for as long as it is open, which
    would break the next module on the same worker that runs a loop of its own (or opens Playwright again)."""
    path = chromium_path()
    if path is None:
        pytest.skip("no Chromium installed (Debian: apt-get install chromium); browser tests need a real browser")
    sync_api = pytest.importorskip(
        "playwright.sync_api", reason="playwright is not installed (pip install -r requirements-test.txt)"
    )
    with sync_api.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=path, headless=True, args=CHROMIUM_FLAGS)
        yield browser
        browser.close()


class Lab:
    """A running JupyterLab: ``url(path)`` opens a file with the token."""

    def __init__(self, root: Path, port: int, token: str):
        self.root, self.port, self.token = root, port, token

    def url(self, relpath: str) -> str:
        return f"http://127.0.0.1:{self.port}/lab/tree/{relpath}?token={self.token}&reset"

    def shutdown_kernels(self):
        """Shut down every kernel the server runs (REST ``DELETE /api/kernels/<id>``)."""
        base = f"http://127.0.0.1:{self.port}/api/kernels"
        with urllib.request.urlopen(f"{base}?token={self.token}", timeout=30) as reply:
            kernels = json.load(reply)
        for kernel in kernels:
            request = urllib.request.Request(f"{base}/{kernel['id']}?token={self.token}", method="DELETE")
            urllib.request.urlopen(request, timeout=60).close()


@pytest.fixture(scope="session")
def jupyter_lab(tmp_path_factory):
    root = tmp_path_factory.mktemp("lab")
    for nb in sorted((KIT_ROOT / "solutions").glob("*.ipynb")):
        shutil.copy(nb, root / nb.name)
    shutil.copytree(KIT_ROOT / "labs", root / "labs")
    settings = tmp_path_factory.mktemp("lab-settings")
    # every cell in the DOM (no windowing), so the test sees each output as a student scrolling would
    tracker = settings / "@jupyterlab" / "notebook-extension" / "tracker.jupyterlab-settings"
    tracker.parent.mkdir(parents=True)
    tracker.write_text('{"windowingMode": "none"}')
    news = settings / "@jupyterlab" / "apputils-extension" / "notification.jupyterlab-settings"
    news.parent.mkdir(parents=True)
    news.write_text('{"fetchNews": "false", "checkForUpdates": false}')
    port, token = _free_port(), secrets.token_hex(16)
    with open(root / "jupyter.log", "w") as log:  # the server writes to its own copy of the file
        server = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "jupyter",
                "lab",
                "--no-browser",
                f"--port={port}",
                "--ip=127.0.0.1",
                f"--ServerApp.token={token}",
                f"--ServerApp.root_dir={root}",
                "--allow-root",
                "--LabApp.expose_app_in_browser=True",
                "--LabApp.news_url=",
            ],
            stdout=log,
            stderr=subprocess.STDOUT,
            env={**os.environ, "JUPYTERLAB_SETTINGS_DIR": str(settings), "JUPYTERLAB_WORKSPACES_DIR": str(settings)},
        )

    def answers():
        if server.poll() is not None:
            pytest.fail(f"JupyterLab exited; its log:\n{(root / 'jupyter.log').read_text()[-3000:]}")
        try:
            urllib.request.urlopen(f"http://127.0.0.1:{port}/api/status?token={token}", timeout=30).close()
            return True
        except OSError:
            return False

    try:
        wait_until(answers, "JupyterLab to answer", poll_s=0.3)  # a busy machine starts it late, not never
    except AssertionError as hang:
        server.kill()
        pytest.fail(f"{hang}; its log:\n{(root / 'jupyter.log').read_text()[-3000:]}")
    yield Lab(root, port, token)
    server.terminate()
    try:
        server.wait(timeout=10)
    except subprocess.TimeoutExpired:
        server.kill()


@pytest.fixture()
def page(browser):
    context = browser.new_context(viewport={"width": 1400, "height": 1000})
    page = context.new_page()
    yield page
    context.close()
