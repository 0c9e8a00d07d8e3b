"""A phone running phyphox as a capture port: its remote-interface REST API, read like a board.

phyphox's "remote access" (⋮ menu → "Allow remote access") serves the open experiment over HTTP
on the local network (phyphox-docs ``docs/remote-interface``; phyphox-android ``RemoteServer.java``):

- ``/config``: the experiment's title, buffers, and ``inputs``, each sensor (``source``:
  ``accelerometer``, ``gyroscope``, ``magnetic_field``, ``linear_acceleration``, …) with the buffers
  its components x, y, z, t write to;
- ``/get?buf=T&buf2=T|buf&…``: per buffer its values after the first one above T (8 significant
  digits), or ``full``, or only the last value; plus ``status`` (session, measuring, timedRun,
  countDown). Polling with the last time received gives only what is new;
- ``/control?cmd=start|stop|clear``, ``/meta`` (device), ``/time``.

The server is slow and handles one request at a time, so :class:`PhyphoxClient` sends one request
after another, each on its own connection (``Connection: close``, no keep-alive), as the bundled web
interface does. :class:`PhyphoxPort` polls it (every ``poll_s``), puts the sensors on the gyroscope's
time base (:class:`kfkit.clocks.OneClock`) and hands the rows to the :class:`~kfkit.capture.Recorder`
as kfkit protocol v1 lines (fixed-point counts, :data:`kfkit.sensors.PHONE_LSB`), so a phone records with the
same statistics, streamed file, progress bar and live plot as a board. A gap in the phone's gyro
timestamps shows as dropped samples; its jitter is the recording's.

    kfkit capture --port phyphox://192.168.0.42:8080 --seconds 60 --out phone.csv

Options ride on the address: ``phyphox://HOST:PORT?mount=upright&poll=0.2`` (mount: a name in
:data:`kfkit.sensors.PHONE_MOUNTS`). Without a port, 8080 (Android's default; iPhones use 80).
"""

from __future__ import annotations

import contextlib
import errno
import http.client
import json
import math
import re
import socket
import time
import urllib.error
import urllib.request
from urllib.parse import parse_qsl, urlencode, urlsplit

import numpy as np

from ..clocks import OneClock, SampleCounter
from ..readers.phyphox_export import KINDS, SOURCES
from ..sensors import DEFAULT_PHONE_MOUNT, PHONE_BOARD, phone_counts, phone_mount, phone_sensor_metadata
from .errors import (
    PhoneError,
    PhoneExperimentError,
    PhoneStoppedError,
    PhoneUnreachableError,
    PortAddressError,
    RemoteAccessOffError,
)
from .protocol import MICROS_MODULO, SEQ_MODULO, encode_header, encode_sample

SCHEME = "phyphox://"
DEFAULT_PORT = 8080
SIMPLE_EXPERIMENT = (
    "in phyphox tap '+' → 'New simple experiment', tick Accelerometer, Gyroscope and Magnetometer, "
    "open it and allow remote access again (⋮ menu)"
)


#: what may ride on a phone's address (``?mount=upright&poll=0.2``), with what each takes
URL_OPTIONS = {
    "mount": "a phone mounting (kfkit.sensors.PHONE_MOUNTS)",
    "poll": "seconds between requests, > 0",
    "timeout": "seconds one request may take, > 0",
}
URL_FORM = f"{SCHEME}HOST[:PORT][?mount=NAME&poll=S&timeout=S], e.g. {SCHEME}192.168.0.42:8080"
_HOST = re.compile(r"[A-Za-z0-9._:%-]+")  # a name, an IPv4 address or (inside [ ]) an IPv6 one


def parse_url(url: str) -> tuple[str, int, dict]:
    """``phyphox://HOST[:PORT][?key=value…]`` → (host, port, options), the options of :data:`URL_OPTIONS`
    (``poll`` and ``timeout`` as floats). Raises :class:`PortAddressError` naming the address and what is wrong."""

    def bad(why):
        return PortAddressError(f"phone address {url!r}: {why}; a phone's address is {URL_FORM}")

    if not url.startswith(SCHEME):
        raise bad(f"it does not start with {SCHEME}")
    parts = urlsplit("http://" + url[len(SCHEME) :])
    if not parts.hostname:
        raise bad("no host: give the address phyphox shows under 'Allow remote access'")
    try:
        port = parts.port
    except ValueError:
        raise bad("the port after ':' must be a whole number 1 … 65535") from None
    if not _HOST.fullmatch(parts.hostname):
        raise bad(f"{parts.hostname!r} is not a host name or IP address")
    if port == 0 or parts.path not in ("", "/") or parts.fragment:
        raise bad(
            "the port after ':' must be a whole number 1 … 65535"
            if port == 0
            else "nothing may follow the port but ?options"
        )
    options = dict(parse_qsl(parts.query, keep_blank_values=True))
    for key, text in options.items():
        if key not in URL_OPTIONS:
            raise bad(
                f"unknown option {key!r}; the options are " + ", ".join(f"{k} ({v})" for k, v in URL_OPTIONS.items())
            )
        if key == "mount":
            try:
                phone_mount(text)
            except ValueError as e:
                raise bad(str(e)) from None
            continue
        try:
            options[key] = float(text)
        except ValueError:
            options[key] = math.nan
        if not (0.0 < options[key] < math.inf):
            raise bad(f"{key}={text!r}: {URL_OPTIONS[key]}")
    return parts.hostname, port or DEFAULT_PORT, options


class PhyphoxClient:
    """phyphox's REST API at ``host:port``: one request at a time, each on a new connection."""

    def __init__(self, host: str, port: int = DEFAULT_PORT, timeout: float = 3.0):
        self.host, self.port, self.timeout = host, int(port), float(timeout)
        self.base = f"http://{host}:{self.port}"

    def request(self, path: str, params=()):
        """GET ``path`` with query ``params`` ((name, value) pairs) → the decoded JSON."""
        url = self.base + path + (f"?{urlencode(list(params))}" if params else "")
        req = urllib.request.Request(url, headers={"Connection": "close", "User-Agent": "kfkit"})
        try:
            with urllib.request.urlopen(req, timeout=self.timeout) as response:
                body = response.read()
        except urllib.error.HTTPError as e:
            detail = e.read()[:200].decode("utf-8", "replace")
            hint = ": phyphox older than 1.1.6 has no /config, or this is not phyphox" if e.code == 404 else ""
            raise PhoneError(f"{self.base}{path} answered HTTP {e.code} ({detail.strip() or e.reason}){hint}") from None
        except urllib.error.URLError as e:
            raise self._connection_error(e.reason) from None
        except TimeoutError as e:
            raise self._connection_error(e) from None
        except (ConnectionError, http.client.HTTPException) as e:
            raise PhoneError(
                f"{self.base} closed the connection ({e.__class__.__name__}: {e}): is the phone still on "
                f"the network with phyphox in front?"
            ) from None
        try:
            return json.loads(body)
        except ValueError:
            shown = body[:60].decode("utf-8", "replace")
            raise PhoneError(
                f"{self.base}{path} answered, but not with phyphox's JSON (got {shown!r}): is "
                f"{self.host}:{self.port} the address phyphox shows under 'Allow remote access'?"
            ) from None

    def _connection_error(self, reason) -> PhoneError:
        where = f"{self.host}:{self.port}"
        if isinstance(reason, ConnectionRefusedError):
            return RemoteAccessOffError(
                f"nothing listens on {where} (connection refused): the phone is there, but phyphox's remote access "
                f"is off or on another port. In phyphox open the experiment, tap ⋮ → 'Allow remote access' and use "
                f"the address it then shows (port 8080 on Android, 80 on an iPhone)"
            )
        if isinstance(reason, socket.gaierror):
            return PhoneUnreachableError(
                f"cannot find the phone {self.host!r} ({reason.strerror}): type the "
                f"address phyphox shows under 'Allow remote access', e.g. 192.168.0.42:8080"
            )
        if isinstance(reason, (TimeoutError, socket.timeout)) or getattr(reason, "errno", None) in (
            errno.EHOSTUNREACH,
            errno.ENETUNREACH,
            errno.EHOSTDOWN,
            errno.ETIMEDOUT,
        ):
            return PhoneUnreachableError(
                f"no answer from {where} within {self.timeout:g} s: the phone is not reachable. Is this computer on "
                f"the same Wi-Fi as the phone (guest and campus networks often keep devices apart)? Is the phone's "
                f"screen on with phyphox in front (a phone in standby stops serving)? Is the address the one phyphox "
                f"shows?"
            )
        return PhoneUnreachableError(f"cannot reach {where}: {reason}")

    def config(self) -> dict:
        return self.request("/config")

    def meta(self) -> dict:
        return self.request("/meta")

    def get(self, params) -> dict:
        return self.request("/get", params)

    def control(self, cmd: str) -> bool:
        return bool(self.request("/control", [("cmd", cmd)]).get("result"))

    def start(self) -> bool:
        """Start measuring (or the countdown of a timed run); False if phyphox refused."""
        return self.control("start")

    def stop(self) -> bool:
        return self.control("stop")

    def clear(self) -> bool:
        """Delete the experiment's data on the phone (and stop measuring)."""
        return self.control("clear")


def experiment_sensors(config: dict) -> dict[str, dict[str, str]]:
    """{sensor: {"x", "y", "z", "t": buffer name}} of the 3-axis sensor inputs in ``/config``."""
    sensors = {}
    for inp in config.get("inputs", []):
        kind = SOURCES.get(inp.get("source"))
        if kind is None or kind in sensors:
            continue
        outputs = {c: b for out in inp.get("outputs", []) for c, b in out.items()}
        if all(c in outputs for c in ("x", "y", "z", "t")):
            sensors[kind] = {c: outputs[c] for c in ("x", "y", "z", "t")}
    return sensors


def check_experiment(config: dict, require=("acc", "gyr")) -> dict[str, dict[str, str]]:
    """The experiment's sensors, or :class:`PhoneExperimentError` naming what is missing and what to open."""
    sensors = experiment_sensors(config)
    title = config.get("localTitle") or config.get("title") or "?"
    found = ", ".join(KINDS[k] for k in sensors) or "no 3-axis sensor"
    for need in require:
        if need in sensors:
            continue
        msg = f"the experiment open in phyphox ({title!r}) has no {KINDS[need]} (it has: {found})."
        if need == "acc" and ("lin" in sensors or "gra" in sensors):
            msg += (
                " It measures the linear acceleration (gravity removed); the filters need the accelerometer's "
                "specific force with gravity: tick 'Accelerometer' (not 'Linear Acceleration') in a simple "
                "experiment, as in phyphox's 'Acceleration with g'."
            )
        raise PhoneExperimentError(f"{msg} To record acc + gyro + mag at once: {SIMPLE_EXPERIMENT}")
    return sensors


class PhyphoxPort:
    """A phone running phyphox, opened like a serial port for the :class:`~kfkit.capture.Recorder`.

    Opening reads ``/config`` (the sensors must be there), starts measuring if the phone is paused (and
    stops it again on :meth:`close`), skips what the phone recorded before, and waits for the first
    ``start_s`` of data to learn the gyro's rate. :meth:`read` polls ``/get`` every ``poll_s`` and
    returns protocol v1 lines; :meth:`header_metadata` gives the recording its phone metadata. A phone
    that pauses, switches experiment, clears its data or stops answering ends the capture with a
    :class:`PhoneError` (what arrived is saved by the recorder).
    """

    def __init__(
        self,
        url: str,
        read_timeout=0.05,
        http_timeout=3.0,
        poll_s=0.1,
        mount=DEFAULT_PHONE_MOUNT,
        require=("acc", "gyr"),
        start_s=3.0,
        stall_s=2.0,
        min_rows=20,
    ):
        host, port, options = parse_url(url)
        self.url, self.read_timeout = url, float(read_timeout)
        self.poll_s = float(options.get("poll", poll_s))
        self.mount_name, self.M = phone_mount(options.get("mount", mount))
        self.stall_s = stall_s
        self.client = PhyphoxClient(host, port, float(options.get("timeout", http_timeout)))
        config = self.client.config()
        self.sensors = check_experiment(config, require)
        self.kinds = [k for k in ("gyr", "acc", "mag") if k in self.sensors]
        self.title = config.get("localTitle") or config.get("title") or ""
        try:
            meta = self.client.meta()
        except PhoneError:
            meta = {}
        self.device = {k: v for k, v in meta.items() if isinstance(v, str) or v is None}
        self.chips = {
            k: (meta.get("sensors") or {}).get(name, {}).get("Name")
            for k, name in (("acc", "accelerometer"), ("gyr", "gyroscope"), ("mag", "magnetic_field"))
        }
        first = self.client.get([(self.sensors[k]["t"], "") for k in self.kinds])
        self.session = first["status"]["session"]
        self._threshold = {k: self._last_value(first, k) for k in self.kinds}  # skip what was recorded before
        self._started = False
        countdown = 0.0
        if not first["status"]["measuring"]:
            if not self.client.start():
                raise PhoneExperimentError(
                    f"phyphox on {host}:{port} refused to start {self.title!r} (a Bluetooth "
                    f"device it needs not connected?): press play on the phone and try again"
                )
            self._started = True
            status = self.client.get([])["status"]
            if status.get("timedRun") and not status.get("measuring"):
                countdown = float(status.get("countDown", 0.0)) / 1000.0  # ms: a timed run starts after its delay
        self.clock = OneClock(base="gyr", interpolated=("acc",), held=("mag",) if "mag" in self.kinds else ())
        self.info = {
            "url": url,
            "experiment": self.title,
            "crc32": config.get("crc32"),
            "device": self.device,
            "buffers": self.sensors,
            "time_base": "gyroscope",
            "merge": self.clock.stats,
        }
        self._rows: list = []
        self._out = bytearray()
        self._closed = False
        self.header = None
        self._last_mag = np.zeros(3, dtype=np.int64)
        self._last_new = self._polled = time.monotonic()
        try:
            deadline = time.monotonic() + countdown + start_s
            while sum(len(r[0]) for r in self._rows) < min_rows:
                if time.monotonic() > deadline:
                    got = ", ".join(f"{KINDS[k]} until {v:.2f} s" for k, v in self._threshold.items() if v is not None)
                    raise PhoneStoppedError(
                        f"phyphox on {host}:{port} is measuring {self.title!r} but sent no gyroscope + accelerometer "
                        f"rows in {start_s:g} s (phone data: {got or 'none'}): is the phone's screen on with phyphox "
                        f"in front, and are its sensors available on this phone?"
                    )
                time.sleep(self.poll_s)
                self._poll()
        except BaseException:
            self.close()
            raise
        self._start_stream()

    def _last_value(self, response, kind):
        """The newest time the phone holds for ``kind`` (s), None if its buffer is empty."""
        values = response.get("buffer", {}).get(self.sensors[kind]["t"], {}).get("buffer") or [None]
        return None if values[-1] is None else float(values[-1])

    # -- polling -----------------------------------------------------------------------------------------
    def _request(self):
        params = []
        for k in self.kinds:
            b, thr = self.sensors[k], self._threshold[k]
            if thr is None:
                params += [(b[c], "full") for c in ("t", "x", "y", "z")]
            else:
                params += [(b["t"], repr(thr))] + [(b[c], f"{thr!r}|{b['t']}") for c in ("x", "y", "z")]
        return params

    def _poll(self):
        response = self.client.get(self._request())
        status = response.get("status", {})
        if status.get("session") != self.session:
            raise PhoneStoppedError(
                "another experiment was opened on the phone (phyphox's session changed): start a new capture"
            )
        buffers = response.get("buffer", {})
        new = False
        for k in self.kinds:
            b = self.sensors[k]
            cols = [
                np.array([np.nan if v is None else v for v in buffers.get(b[c], {}).get("buffer", [])], dtype=float)
                for c in ("t", "x", "y", "z")
            ]
            n = min(len(c) for c in cols)
            table = np.column_stack([c[:n] for c in cols]) if n else np.zeros((0, 4))
            table = table[np.isfinite(table).all(axis=1)]
            if self._threshold[k] is not None:
                table = table[table[:, 0] > self._threshold[k]]
            if len(table):
                self._threshold[k] = float(table[-1, 0])
                self.clock.push(k, table[:, 0], table[:, 1:])
                new |= k == "gyr"
        t, values, _ = self.clock.pop()
        if len(t):
            self._rows.append((t, values))
        now = time.monotonic()
        if new:
            self._last_new = now
        elif self.header is not None and now - self._last_new > self.stall_s:
            if not status.get("measuring", False):
                raise PhoneStoppedError(
                    "the phone stopped measuring (paused in phyphox, or its timed run ended): "
                    "what arrived is saved; start a new capture to go on"
                )
            raise PhoneStoppedError(
                f"the phone is measuring but sent no new gyroscope samples for {self.stall_s:g} s: "
                f"its data was cleared, or phyphox went to the background; start a new capture"
            )

    def _start_stream(self):
        t = np.concatenate([r[0] for r in self._rows])
        self.nominal_dt = float(np.median(np.diff(t)))
        self.rate_hz = round(1.0 / self.nominal_dt, 2)
        self._counter = SampleCounter(
            self.nominal_dt
        )  # a gap in the gyro's timestamps is dropped samples, jitter is not
        self.fields = ("t_us", "seq", "ax", "ay", "az", "gx", "gy", "gz") + (
            ("mx", "my", "mz", "mag_new") if "mag" in self.kinds else ()
        )
        self.header = encode_header(PHONE_BOARD, self.rate_hz, self.fields, source="phyphox")
        self._out += self.header
        self._encode()

    def _encode(self):
        for t, values in self._rows:
            counts = {k: phone_counts(k, values[k]) for k in self.kinds}
            seq = self._counter.count(t)
            for i, ti in enumerate(t.tolist()):
                row = [
                    round(ti * 1e6) % MICROS_MODULO,
                    int(seq[i]) % SEQ_MODULO,
                    *counts["acc"][i].tolist(),
                    *counts["gyr"][i].tolist(),
                ]
                if "mag" in self.kinds:
                    m = counts["mag"][i]
                    fresh = bool(np.isfinite(m).all())
                    if fresh:
                        self._last_mag = m.astype(np.int64)
                    row += [*self._last_mag.tolist(), int(fresh)]
                self._out += encode_sample(row)
        self._rows = []

    # -- the serial-port interface the Recorder uses -----------------------------------------------------------
    @property
    def in_waiting(self) -> int:
        return len(self._out)

    def read(self, size=1) -> bytes:
        if not self._out and not self._closed:
            wait = self._next_poll() - time.monotonic()
            if wait > 0:
                time.sleep(min(wait, self.read_timeout))
            if time.monotonic() >= self._next_poll():
                self._polled = time.monotonic()
                self._poll()
                self._encode()
        data = bytes(self._out[:size])
        del self._out[:size]
        return data

    def _next_poll(self) -> float:
        return self._polled + self.poll_s

    def write(self, data: bytes) -> int:
        """``h``: send the header again; ``s``: pause/resume measuring on the phone."""
        for c in bytes(data):
            if c == ord("h") and self.header is not None and not self._out.startswith(self.header):
                self._out += self.header
            elif c == ord("s"):
                self.client.control("stop" if self.client.get([])["status"]["measuring"] else "start")
        return len(data)

    def close(self):
        """Stop measuring if this port started it (what the phone recorded stays on the phone)."""
        if self._closed:
            return
        self._closed = True
        if self._started:
            with contextlib.suppress(PhoneError):  # the phone is gone: nothing to stop
                self.client.stop()

    def header_metadata(self, header) -> dict:
        """The recording's metadata: phone counts, the mounting, and what phyphox said about itself.
        ``meta["phone"]["merge"]`` is the live merge statistics (updated until the capture ends)."""
        return {
            "board": PHONE_BOARD,
            "rate_hz": header.rate_hz,
            "source": "capture (phone, phyphox remote access)",
            "units": {"t": "s", "sensors": "counts (see sensors.*.sensitivity)"},
            "protocol": {"version": header.version, "header": "#" + header.text},
            "sensors": {k: phone_sensor_metadata(k, self.chips[k]) for k in self.kinds},
            "mount": {k: self.M.tolist() for k in self.kinds},
            "mount_name": self.mount_name,
            "phone": self.info,
        }
