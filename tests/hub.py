"""A real JupyterHub on 127.0.0.1 for tests/test_hub.py and benchmarks/bench_hub.py.

The hub is PyPI's ``jupyterhub`` with its standard proxy, npm's ``configurable-http-proxy``; the test-only
``DummyAuthenticator`` (one shared password) and ``LocalProcessSpawner``: each student is a real local
user (``useradd``, removed afterwards) with a home of their own (mode 700). The single-user environment is
what the README tells an instructor to build: a copy of the kit without ``solutions/`` (``git archive HEAD
':!solutions'``; ``PYTHONPATH`` puts its ``kfkit/`` and ``data/`` first), with this virtual environment's
Python packages (``requirements-hub.txt`` adds nbgitpuller). As in an image, the instructor's own files are
not there: each server starts in its own mount namespace where root's home and the instructor's checkout
of the kit are empty (only the Python install and the virtual environment inside them are mounted back),
then drops to the student's user.

Layout under ``root`` (``/tmp/kfkit-hub-…``, mode 711): ``home/<student>/``, ``kit/`` (the kit copy),
``labs.git`` (what nbgitpuller pulls), ``instructor/`` (mode 700: the hub's database and logs,
submissions, gradebook).
"""

from __future__ import annotations

import asyncio
import json
import os
import pwd
import re
import secrets
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.parse
import urllib.request
import uuid
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from waiting import HANG_GUARD_S

from kfkit.paths import KIT_ROOT

CHP = "configurable-http-proxy"
PASSWORD = "kfkit-class-" + secrets.token_hex(4)
START_TIMEOUT = HANG_GUARD_S  # s a server may take to start on a busy machine (a hang guard, not a measurement)
POLL = re.compile(r"200 GET /hub/api/users/\w+ \(instructor@")  # wait_ready's requests: noise in a failure's log


def why_no_hub() -> str | None:
    """Why a hub cannot run here (said in the skip), or None."""
    if not sys.platform.startswith("linux"):
        return "the hub test needs Linux (local users, mount namespaces)"
    if os.geteuid() != 0:
        return "the hub test needs root: it creates local users (useradd) and one mount namespace per server"
    for tool in ("node", CHP, "git", "useradd", "userdel", "unshare", "setpriv"):
        if shutil.which(tool) is None:
            hint = " (npm install -g configurable-http-proxy@5.3.0, as .ci/run does)" if tool in ("node", CHP) else ""
            return f"no '{tool}' on the PATH{hint}"
    for module in ("jupyterhub", "nbgitpuller"):
        try:
            __import__(module)
        except ImportError:
            return f"Python package {module} is missing (pip install -r requirements-test.txt)"
    probe = subprocess.run(["unshare", "--mount", "--propagation", "private", "true"], capture_output=True, text=True)
    if probe.returncode:
        return f"cannot make a mount namespace here ({probe.stderr.strip()})"
    return None


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def git(*args, cwd):
    subprocess.run(
        ["git", "-c", "user.name=Instructor", "-c", "user.email=instructor@example.org", *args],
        cwd=cwd,
        check=True,
        capture_output=True,
    )


SPAWNER = '''
import os
from jupyterhub.spawner import LocalProcessSpawner


class ImageSpawner(LocalProcessSpawner):
    """LocalProcessSpawner whose command (namespace.sh) drops to the student's user itself, after hiding
    the instructor's files: the preexec step only enters the home, as root."""

    def make_preexec_fn(self, name):
        home = self.user_env({})["HOME"]
        return lambda: os.chdir(home)
'''


class Hub:
    """One hub and its students: ``start()``, then REST calls (``api``, ``server_api``), ``spawn``, ``run_code``.

    Always ``stop()`` (it removes the users it created): use it as a context manager.
    """

    def __init__(self, students: int, prefix: str = "kfk"):
        self.tag = prefix + secrets.token_hex(3)
        self.students = [f"{self.tag}s{i}" for i in range(1, students + 1)]
        self.root = Path(tempfile.mkdtemp(prefix="kfkit-hub-", dir="/tmp"))
        self.root.chmod(0o711)
        self.instructor = self.root / "instructor"
        self.instructor.mkdir(mode=0o700)
        self.kit, self.repo, self.homes = self.root / "kit", self.root / "labs.git", self.root / "home"
        self.work = self.instructor / "labs"  # the instructor's clone of the student repository
        self.port, self.token = free_port(), secrets.token_hex(32)
        self.url = f"http://127.0.0.1:{self.port}"
        self.proc, self.users_made = None, []

    # -------------------------------------------------------------------------------- setup
    def __enter__(self):
        try:
            self.start()
        except BaseException:
            self.stop()
            raise
        return self

    def __exit__(self, *exc):
        self.stop()

    def start(self):
        self._kit_without_solutions()
        self._labs_repo()
        self._users()
        self._config()
        with open(self.instructor / "jupyterhub.log", "w") as log:  # the hub writes to its own copy of the file
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "jupyterhub", "-f", str(self.instructor / "config.py")],
                cwd=self.instructor,
                stdout=log,
                stderr=subprocess.STDOUT,
                env={**os.environ, "PATH": f"{Path(sys.executable).parent}:{os.environ['PATH']}"},
            )
        self._wait(self._answers, "the hub did not answer")  # it adds allowed_users itself

    def _kit_without_solutions(self):
        """The instructor's deployment: the committed kit minus solutions/ (README, Running a class)."""
        self.kit.mkdir(mode=0o755)
        archive = subprocess.run(
            ["git", "archive", "--format=tar", "HEAD", "--", ".", ":!solutions"],
            cwd=KIT_ROOT,
            check=True,
            capture_output=True,
        ).stdout
        subprocess.run(["tar", "-x", "-C", str(self.kit)], input=archive, check=True)

    def _labs_repo(self):
        """The student repository nbgitpuller clones (``labs.git``, as on a git server): the hand-outs only, as
        ``git subtree split --prefix=labs`` publishes them; the instructor works in a clone and pushes."""
        self.work.mkdir()
        git("init", "-q", "-b", "student", cwd=self.work)
        for nb in sorted((self.kit / "labs").glob("*.ipynb")):
            shutil.copy(nb, self.work / nb.name)
        git("add", ".", cwd=self.work)
        git("commit", "-q", "-m", "labs", cwd=self.work)
        git("clone", "-q", "--bare", str(self.work), str(self.repo), cwd=self.root)
        git("remote", "add", "origin", str(self.repo), cwd=self.work)
        for d in [self.repo, *self.repo.rglob("*")]:
            d.chmod(0o755 if d.is_dir() else 0o644)

    def push_fix(self, name: str, edit) -> None:
        """The instructor changes hand-out ``name`` (``edit(notebook dict)``), commits and pushes it."""
        path = self.work / name
        nb = json.loads(path.read_text(encoding="utf-8"))
        edit(nb)
        path.write_text(json.dumps(nb, indent=1, ensure_ascii=False) + "\n", encoding="utf-8")
        git("commit", "-q", "-am", f"fix {name}", cwd=self.work)
        git("push", "-q", "origin", "student", cwd=self.work)

    def _users(self):
        self.homes.mkdir(mode=0o711)
        for name in self.students:
            home = self.homes / name
            subprocess.run(
                ["useradd", "--no-create-home", "--home-dir", str(home), "--shell", "/bin/sh", "--user-group", name],
                check=True,
                capture_output=True,
            )
            self.users_made.append(name)
            home.mkdir(mode=0o700)
            pw = pwd.getpwnam(name)
            os.chown(home, pw.pw_uid, pw.pw_gid)

    def _config(self):
        """jupyterhub_config.py, the spawner, and namespace.sh (each server's command)."""
        hidden = [Path.home(), KIT_ROOT]
        kept = [Path(sys.base_prefix), Path(sys.prefix)]  # the Python install and the venv, wherever they are
        stage = self.instructor / "stage"
        lines = [
            "#!/bin/sh",
            "# A student's server as in a hub image: the instructor's files hidden, then the student's user.",
            "set -eu",
            "# every mount below happens in a new mount namespace, never in the machine's: re-run inside one,",
            "# and refuse to go on unless the namespace really differs from the one this script started in",
            'if [ -z "${KFKIT_OUTER_NS:-}" ]; then',
            '    KFKIT_OUTER_NS=$(readlink /proc/self/ns/mnt) exec unshare --mount --propagation private -- "$0" "$@"',
            "fi",
            '[ "$(readlink /proc/self/ns/mnt)" != "$KFKIT_OUTER_NS" ] || '
            '{ echo "not in a new mount namespace" >&2; exit 1; }',
        ]
        for i, path in enumerate(kept):
            (stage / str(i)).mkdir(parents=True)
            lines.append(f"mount --bind '{path}' '{stage / str(i)}'")
        lines += [f"mount -t tmpfs -o mode=755 tmpfs '{h}'" for h in hidden]
        for i, path in enumerate(kept):
            lines.append(f"mkdir -p '{path}' && mount --move '{stage / str(i)}' '{path}'")
        lines.append('exec setpriv --reuid="$USER" --regid="$(id -g "$USER")" --init-groups -- "$@"')
        wrapper = self.instructor / "namespace.sh"
        wrapper.write_text("\n".join(lines) + "\n")
        wrapper.chmod(0o700)
        (self.instructor / "image_spawner.py").write_text(SPAWNER)
        settings = self.root / "lab-settings"  # every cell in the DOM, no news: as tests/browser/ sets it
        tracker = "@jupyterlab/notebook-extension/tracker.jupyterlab-settings"
        news = "@jupyterlab/apputils-extension/notification.jupyterlab-settings"
        for rel, text in {
            tracker: '{"windowingMode": "none"}',
            news: '{"fetchNews": "false", "checkForUpdates": false}',
        }.items():
            (settings / rel).parent.mkdir(parents=True, exist_ok=True)
            (settings / rel).write_text(text)
        for d in [settings, *settings.rglob("*")]:
            d.chmod(0o755 if d.is_dir() else 0o644)
        singleuser = Path(sys.executable).parent / "jupyterhub-singleuser"
        env = {
            "PYTHONPATH": str(self.kit),
            "JUPYTERLAB_SETTINGS_DIR": str(settings),
            "PATH": f"{Path(sys.executable).parent}:/usr/bin:/bin",
            # the test's repository is a local folder of root's: git reads another user's repository only if a
            # global config names it safe (on a real hub the repository is on a git server: not needed)
            "GIT_CONFIG_GLOBAL": str(self.root / "gitconfig"),
        }
        (self.root / "gitconfig").write_text(f"[safe]\n\tdirectory = {self.repo}\n")
        (self.root / "gitconfig").chmod(0o644)
        config = f"""
import sys
sys.path.insert(0, {str(self.instructor)!r})
from image_spawner import ImageSpawner

c.JupyterHub.ip = "127.0.0.1"
c.JupyterHub.port = {self.port}
c.JupyterHub.hub_ip = "127.0.0.1"
c.JupyterHub.hub_port = {free_port()}
c.ConfigurableHTTPProxy.api_url = "http://127.0.0.1:{free_port()}"
c.ConfigurableHTTPProxy.command = [{shutil.which(CHP)!r}]
c.JupyterHub.db_url = "sqlite:///{self.instructor / "hub.sqlite"}"
c.JupyterHub.cookie_secret_file = {str(self.instructor / "cookie_secret")!r}
c.JupyterHub.pid_file = {str(self.instructor / "hub.pid")!r}
c.JupyterHub.authenticator_class = "dummy"
c.DummyAuthenticator.password = {PASSWORD!r}
c.Authenticator.allowed_users = {set(self.students)!r}
c.JupyterHub.services = [{{"name": "instructor", "api_token": {self.token!r}}}]
c.JupyterHub.load_roles = [{{"name": "instructor", "services": ["instructor"],
    "scopes": ["admin:users", "admin:servers", "tokens", "access:servers", "read:users"]}}]
c.JupyterHub.spawner_class = ImageSpawner
c.Spawner.cmd = [{str(wrapper)!r}, {str(singleuser)!r}]
c.Spawner.args = ["--LabApp.expose_app_in_browser=True", "--LabApp.news_url="]
c.Spawner.default_url = "/lab"
c.Spawner.environment = {env!r}
c.Spawner.start_timeout = {int(START_TIMEOUT)}
c.Spawner.http_timeout = {int(START_TIMEOUT)}
c.JupyterHub.cleanup_servers = True
"""
        (self.instructor / "config.py").write_text(config)

    # -------------------------------------------------------------------------------- REST
    def request(self, method, url, body=None, token=None, timeout=60):
        """JSON of a REST call (None for 404), raising with the hub's answer otherwise."""
        data = None if body is None else json.dumps(body).encode()
        req = urllib.request.Request(
            url,
            data=data,
            method=method,
            headers={"Authorization": f"token {token or self.token}", "Content-Type": "application/json"},
        )
        try:
            with urllib.request.urlopen(req, timeout=timeout) as r:
                text = r.read().decode()
        except urllib.error.HTTPError as exc:
            if exc.code == 404:
                return None
            raise AssertionError(f"{method} {url}: HTTP {exc.code} {exc.read().decode()[:500]}") from None
        return json.loads(text) if text.strip() else {}

    def api(self, method, path, body=None):
        """The hub's REST API (``/hub/api``) with the instructor service's token."""
        try:
            return self.request(method, f"{self.url}/hub/api{path}", body)
        except OSError:
            return None

    def _answers(self) -> bool:
        try:
            with urllib.request.urlopen(f"{self.url}/hub/api", timeout=5) as r:
                return r.status == 200
        except OSError:  # not listening yet, or the proxy's 503 before the hub's route is in
            return False

    def user_token(self, name) -> str:
        return self.api("POST", f"/users/{name}/tokens", {"note": "kfkit test", "expires_in": 3600})["token"]

    def spawn(self, name):
        """Ask the hub to start ``name``'s server; returns at once (see :meth:`wait_ready`)."""
        self.api("POST", f"/users/{name}/server")

    def wait_ready(self, name):
        """Wait for the server :meth:`spawn` asked for; a spawn the hub gave up on fails at once, with the log."""

        def ready():
            server = ((self.api("GET", f"/users/{name}") or {}).get("servers") or {}).get("")
            if server is None or not (server.get("ready") or server.get("pending")):
                raise AssertionError(
                    f"{name}'s server stopped before it was ready: {server}; the hub's log:\n{self.hub_log()}"
                )
            return server["ready"]

        self._wait(ready, f"{name}'s server did not become ready")

    def server_api(self, name, method, path, body=None, token=None):
        """The student's Jupyter server REST API (``/user/<name>/api``) through the proxy."""
        return self.request(method, f"{self.url}/user/{name}/api{path}", body, token)

    def pull(self, name, token, targetpath="kfkit-labs"):
        """What an nbgitpuller link does: nbgitpuller's own API streams git's progress; → that text."""
        query = urllib.parse.urlencode({"repo": f"file://{self.repo}", "branch": "student", "targetpath": targetpath})
        req = urllib.request.Request(
            f"{self.url}/user/{name}/git-pull/api?{query}", headers={"Authorization": f"token {token}"}
        )
        with urllib.request.urlopen(req, timeout=START_TIMEOUT) as r:
            text = r.read().decode()
        events = [json.loads(ln[5:]) for ln in text.splitlines() if ln.startswith("data:")]
        if not events or events[-1].get("phase") != "finished":
            raise AssertionError(f"nbgitpuller did not finish for {name}: {text[-2000:]}")
        return "".join(e.get("output", "") for e in events)

    def pull_link(self, name_in_repo: str) -> str:
        """The nbgitpuller link an instructor hands out (README), for this hub and repository."""
        query = urllib.parse.urlencode(
            {
                "repo": f"file://{self.repo}",
                "branch": "student",
                "targetpath": "kfkit-labs",
                "urlpath": f"lab/tree/kfkit-labs/{name_in_repo}",
            }
        )
        return f"{self.url}/hub/user-redirect/git-pull?{query}"

    def run_code(self, name, token, code: str, timeout=HANG_GUARD_S, keep=False) -> str:
        """Run ``code`` in a new kernel on ``name``'s server (REST + the kernel's websocket); → its stdout.
        The kernel is shut down afterwards unless ``keep``."""
        kernel = self.server_api(name, "POST", "/kernels", {"name": "python3"}, token)
        try:
            with ThreadPoolExecutor(1) as pool:  # its own event loop: the caller's thread may run one (playwright's)
                return pool.submit(asyncio.run, self._execute(name, token, kernel["id"], code, timeout)).result()
        finally:
            if not keep:
                self.server_api(name, "DELETE", f"/kernels/{kernel['id']}", token=token)

    async def _execute(self, name, token, kernel_id, code, timeout):
        from tornado.httpclient import HTTPRequest
        from tornado.websocket import websocket_connect

        url = f"ws://127.0.0.1:{self.port}/user/{name}/api/kernels/{kernel_id}/channels"
        ws = await websocket_connect(HTTPRequest(url, headers={"Authorization": f"token {token}"}))
        msg_id = uuid.uuid4().hex
        ws.write_message(
            json.dumps(
                {
                    "header": {
                        "msg_id": msg_id,
                        "username": name,
                        "session": uuid.uuid4().hex,
                        "msg_type": "execute_request",
                        "version": "5.3",
                        "date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                    },
                    "parent_header": {},
                    "metadata": {},
                    "channel": "shell",
                    "buffers": [],
                    "content": {
                        "code": code,
                        "silent": False,
                        "store_history": False,
                        "user_expressions": {},
                        "allow_stdin": False,
                        "stop_on_error": True,
                    },
                }
            )
        )
        out, deadline = [], time.monotonic() + timeout
        try:
            while time.monotonic() < deadline:
                text = await asyncio.wait_for(ws.read_message(), deadline - time.monotonic())
                if text is None:
                    raise AssertionError(f"{name}'s kernel websocket closed")
                msg = json.loads(text)
                if msg.get("parent_header", {}).get("msg_id") != msg_id:
                    continue
                kind, content = msg["msg_type"], msg["content"]
                if kind == "stream" and content["name"] == "stdout":
                    out.append(content["text"])
                elif kind == "error":
                    raise AssertionError(f"{name}'s kernel: {content['ename']}: {content['evalue']}")
                elif kind == "status" and content["execution_state"] == "idle":
                    return "".join(out)
            raise AssertionError(f"{name}'s kernel did not finish within {timeout:g} s")
        finally:
            ws.close()

    # -------------------------------------------------------------------------------- teardown
    def _wait(self, ready, what):
        deadline = time.monotonic() + START_TIMEOUT
        while not ready():
            if self.proc is not None and self.proc.poll() is not None:
                raise AssertionError(f"{what}: the hub exited; its log:\n{self.hub_log()}")
            if time.monotonic() > deadline:
                raise AssertionError(f"{what} within {START_TIMEOUT:g} s; the hub's log:\n{self.hub_log()}")
            time.sleep(0.3)

    def hub_log(self) -> str:
        """The end of the hub's log (its servers' output included), without the test's own polling of the REST API."""
        path = self.instructor / "jupyterhub.log"
        if not path.exists():
            return "(no log)"
        lines = [ln for ln in path.read_text(errors="replace").splitlines() if not POLL.search(ln)]
        return "\n".join(lines)[-6000:]

    def stop(self):
        """Stop every server and the hub (cleanup_servers), then remove the users and the folder."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=60)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        for name in self.users_made:
            subprocess.run(["pkill", "-KILL", "-u", name], capture_output=True)  # only that user's processes
            subprocess.run(["userdel", name], capture_output=True)
        shutil.rmtree(self.root, ignore_errors=True)
