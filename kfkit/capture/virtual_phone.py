"""A virtual phone: phyphox's remote access on 127.0.0.1, serving the phone simulator.

``VirtualPhone`` runs an ``http.server`` on a free port of 127.0.0.1 (a thread) that answers as
phyphox-android's ``RemoteServer`` does (docs: phyphox-docs ``docs/remote-interface/openapi.yaml``):

- ``/config``  the experiment: title, buffers, inputs (sensor → its buffers), export sets
- ``/get``     buffers by name: ``name`` (last value), ``name=full``, ``name=T`` (values after the
  first one above T, with phyphox's nudge of T by one unit in its 8th significant digit) or
  ``name=T|ref`` (at the indices where buffer ``ref`` is above T); numbers with 8 significant
  digits, NaN as null; ``status``: session, measuring, timedRun, countDown
- ``/control`` ``cmd=start|stop|clear`` → ``{"result": true}``
- ``/meta`` device and sensor properties, ``/time`` the start/pause events

One connection per request (HTTP/1.0, no keep-alive), as phyphox's server. The phone plays a
:class:`kfkit.motions.Motion` (looped, fresh noise each time; default: lying flat and still) through
:func:`kfkit.phone_sim.simulate_phone`, so its noise, rates and timestamp jitter are a phone's. The gyro's
and accelerometer's bias random walks (:data:`kfkit.unit_errors.PHONE_UNIT`) run on across the loops, one path per
sensor, as a real phone's biases do.
While measuring, its experiment clock runs at ``speed`` × real time, or (``step_s``) moves on by
``step_s`` seconds at each ``/get``, so that the phone runs exactly as fast as it is polled whatever
the machine's load (tests); the buffers hold every sample up to it. Faults for tests: ``refuse_start`` (start
answers false), ``pause_at`` (the phone pauses itself at that experiment time, s), ``hang_after`` (after that many
``/get`` requests it stops answering, as a phone that left the network).

    python -m kfkit.capture.virtual_phone [--experiment simple] [--speed 1]

serves one until Ctrl-C and prints the ``phyphox://`` address to record from.
"""

from __future__ import annotations

import json
import math
import threading
import time
import uuid
import zlib
from dataclasses import dataclass
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from urllib.parse import parse_qsl, urlsplit

import numpy as np

from .. import attitude_motions, motions
from ..phone_sim import simulate_phone
from ..sensors import DEFAULT_PHONE_MOUNT, PHONE_ACCEL, PHONE_GYRO, PHONE_LSB, PHONE_MAG, SENSORS
from ..unit_errors import PHONE_UNIT

_COMPONENTS = ("x", "y", "z", "t")
#: the phone unit's bias random-walk densities (rad/s/√s, m/s²/√s), walked here across loops instead
_BIAS_WALKS = {"gyr": PHONE_UNIT["gyro_bias_rw"], "acc": PHONE_UNIT["accel_bias_rw"]}
_UNIT_WITHOUT_WALKS = {**PHONE_UNIT, "gyro_bias_rw": 0.0, "accel_bias_rw": 0.0}


@dataclass(frozen=True)
class PhoneInput:
    """One sensor input of an experiment: phyphox's sensor type, where its data comes from, its buffers."""

    source: str  # "accelerometer", "gyroscope", "magnetic_field", "linear_acceleration"
    data: str  # the simulator's "acc", "gyr", "mag", or "lin" (accelerometer minus gravity)
    buffers: tuple  # buffer names for x, y, z, t
    export: tuple  # (set name, x/y/z labels)


def _android(source, data, prefix, time_name, set_name, labels):
    return PhoneInput(source, data, (f"{prefix}X", f"{prefix}Y", f"{prefix}Z", time_name), (set_name, labels))


_ACC = ("Acceleration x (m/s^2)", "Acceleration y (m/s^2)", "Acceleration z (m/s^2)")
_GYR = ("Gyroscope x (rad/s)", "Gyroscope y (rad/s)", "Gyroscope z (rad/s)")
_MAG = ("Magnetic field x (µT)", "Magnetic field y (µT)", "Magnetic field z (µT)")
_LIN = ("Linear Acceleration x (m/s^2)", "Linear Acceleration y (m/s^2)", "Linear Acceleration z (m/s^2)")
_SIMPLE = {
    "acc": _android("accelerometer", "acc", "acc", "acc_time", "Accelerometer", _ACC),
    "gyr": _android("gyroscope", "gyr", "gyr", "gyr_time", "Gyroscope", _GYR),
    "mag": _android("magnetic_field", "mag", "mag", "mag_time", "Magnetometer", _MAG),
    "lin": _android("linear_acceleration", "lin", "lin", "lin_time", "Linear Acceleration", _LIN),
}

#: name → (title, inputs): Android's simple experiments (phyphox-android SimpleExperimentCreator)
#: and two of its single-sensor experiments (phyphox-experiments: gyroscope, linear_accelerometer)
EXPERIMENTS = {
    "simple": ("Phone IMU", (_SIMPLE["acc"], _SIMPLE["gyr"], _SIMPLE["mag"])),
    "simple-no-mag": ("Phone IMU", (_SIMPLE["acc"], _SIMPLE["gyr"])),
    "simple-linear": ("Phone IMU", (_SIMPLE["lin"], _SIMPLE["gyr"], _SIMPLE["mag"])),
    "gyroscope": ("Gyroscope", (_android("gyroscope", "gyr", "gyr", "gyr_time", "Raw Data", _GYR),)),
    "acceleration-without-g": (
        "Acceleration (without g)",
        (_android("linear_acceleration", "lin", "acc", "acc_time", "Raw Data", _LIN),),
    ),
}


def format_number(v: float) -> str:
    """A value as phyphox's /get writes it: DecimalFormat("0.#######E0"), 8 significant digits; NaN → null."""
    if not math.isfinite(v):
        return "null"
    mantissa, exponent = f"{v:.7E}".split("E")
    mantissa = mantissa.rstrip("0").rstrip(".")
    return f"{mantissa}E{int(exponent)}"


def _nudged(threshold: float) -> float:
    """phyphox moves a threshold up by one unit of its 8th significant digit (values carry 8)."""
    if threshold == 0 or not math.isfinite(threshold):
        return threshold
    return threshold + 10.0 ** math.floor(math.log10(abs(threshold) / 1e7))


class VirtualPhone:
    """phyphox's remote access for a simulated phone on 127.0.0.1 (a context manager; ``.url``).

    motion       a :class:`kfkit.motions.Motion` (sampled well above 100 Hz), looped; None: flat and still
    experiment   a name in :data:`EXPERIMENTS` (what is open in phyphox)
    seed         seeds the phone's noise (loop k uses seed + k) and its bias walks
    speed        experiment seconds per wall-clock second while measuring (tests run faster)
    step_s       instead of ``speed``: experiment seconds added by each ``/get`` while measuring (None: use speed)
    autostart    measure from the start, as if the student had pressed play
    rates, drop  passed to :func:`kfkit.phone_sim.simulate_phone` (sensor rates, probability of a lost sample)
    faults       {"refuse_start": True, "pause_at": s, "hang_after": n}; see the module docstring
    """

    def __init__(
        self,
        motion=None,
        experiment="simple",
        seed=0,
        speed=1.0,
        autostart=False,
        rates=None,
        drop=0.0,
        faults=None,
        mount=DEFAULT_PHONE_MOUNT,
        step_s=None,
    ):
        if experiment not in EXPERIMENTS:
            raise ValueError(f"unknown experiment {experiment!r}; known: {', '.join(EXPERIMENTS)}")
        self.title, self.inputs = EXPERIMENTS[experiment]
        self.motion = motion if motion is not None else motions.stationary(30.0, 200.0, yaw=np.radians(30.0))
        self.seed, self.speed, self.rates, self.drop, self.mount = seed, float(speed), rates, drop, mount
        if step_s is not None and not step_s > 0:
            raise ValueError(f"step_s must be a positive number of seconds (or None), got {step_s!r}")
        self.step_s = step_s
        self.faults = dict(faults or {})
        unknown = set(self.faults) - {"refuse_start", "pause_at", "hang_after"}
        if unknown:
            raise ValueError(
                f"unknown fault(s) {', '.join(sorted(unknown))}; known: refuse_start, pause_at, hang_after"
            )
        self.session = uuid.uuid4().hex[:6]
        self.requests = {"get": 0, "control": 0, "config": 0, "keep_alive": 0}  # keep_alive: asked to keep a connection
        self._buffers = {name: (inp, i) for inp in self.inputs for i, name in enumerate(inp.buffers)}
        self._lock = threading.Lock()
        self._closed = threading.Event()
        self._server = self._thread = None
        self._duration = float(self.motion.t[-1] - self.motion.t[0] + 1.0 / self.motion.rate_hz)
        self._reset()
        if autostart:
            self._start()

    # -- the experiment's state ----------------------------------------------------------------------
    def _reset(self):
        self.measuring = False
        self._t_exp, self._wall = 0.0, time.monotonic()
        self._loops: list = []  # per loop: {data: (t, values)}
        self._events = []
        self._generation = getattr(self, "_generation", -1) + 1
        # bias walks b(t) = ∫ w dt (phone frame), carried from loop to loop: sensor → (time s, value (3,))
        self._walk_rng = np.random.default_rng([self.seed, self._generation, 1])
        self._walk = {sensor: (0.0, np.zeros(3)) for sensor in _BIAS_WALKS}

    def _start(self) -> bool:
        if self.faults.get("refuse_start"):
            return False
        if not self.measuring:
            self._wall, self.measuring = time.monotonic(), True
            self._events.append(("START", self._t_exp))
        return True

    def _stop(self):
        self._t_exp = self.experiment_time()
        self.measuring = False
        self._events.append(("PAUSE", self._t_exp))

    def experiment_time(self) -> float:
        """The phone's experiment time now, s (it stands still while paused; with ``step_s``, between polls)."""
        running = self.measuring and self.step_s is None
        t = self._t_exp + (time.monotonic() - self._wall) * self.speed if running else self._t_exp
        pause = self.faults.get("pause_at")
        if pause is not None and self.measuring and t >= pause:
            self._t_exp, self.measuring = float(pause), False
            self._events.append(("PAUSE", self._t_exp))
            return self._t_exp
        return t

    def _loop(self, k):
        while len(self._loops) <= k:
            i = len(self._loops)
            s = simulate_phone(
                self.motion,
                seed=self.seed + 1000 * self._generation + i,
                rates=self.rates,
                drop=self.drop,
                mount=self.mount,
                unit=_UNIT_WITHOUT_WALKS,
            )
            shift = i * self._duration - float(self.motion.t[0])
            data = {}
            for sensor in SENSORS:
                t, v = s.t[sensor] + shift, s.values[sensor]
                if i and len(t):  # each sensor's clock runs on across the seam: one period after the last sample
                    t = t + (self._loops[-1][sensor][0][-1] + 1.0 / s.sim["rates_hz"][sensor] - t[0])
                if sensor in _BIAS_WALKS:  # + the walk, back on the phone's fixed-point grid
                    v = np.round((v + self._walk_path(sensor, t)) / PHONE_LSB[sensor]) * PHONE_LSB[sensor]
                data[sensor] = (t, v)
            data["lin"] = (data["acc"][0], data["acc"][1] - s.gravity)
            self._loops.append(data)
        return self._loops[k]

    def _walk_path(self, sensor, t):
        """The bias walk of ``sensor`` at times t (s, increasing), continuing its path: b_k = b_{k−1} + w_k,
        w_k ~ N(0, K²·(t_k − t_{k−1})) with K the phone unit's density."""
        t_last, b_last = self._walk[sensor]
        dt = np.maximum(np.diff(np.concatenate([[t_last], t])), 0.0)
        path = b_last + np.cumsum(
            self._walk_rng.normal(0.0, 1.0, (len(t), 3)) * (_BIAS_WALKS[sensor] * np.sqrt(dt))[:, None], axis=0
        )
        if len(t):
            self._walk[sensor] = (float(t[-1]), path[-1])
        return path

    def _series(self, data, t_now):
        """(times, values (N, 3)) of simulator stream ``data`` up to experiment time t_now."""
        if t_now < 0:
            return np.zeros(0), np.zeros((0, 3))
        last = int(t_now // self._duration) + 1  # + 1: a loop may start up to a sample period early (seams above)
        ts, vs = zip(*(self._loop(k)[data] for k in range(last + 1)))
        t, v = np.concatenate(ts), np.concatenate(vs)
        n = int(np.searchsorted(t, t_now, side="right"))
        return t[:n], v[:n]

    # -- the endpoints ---------------------------------------------------------------------------------
    def config(self) -> dict:
        buffers = [{"name": name, "size": 0} for inp in self.inputs for name in inp.buffers]
        inputs = [
            {"source": inp.source, "outputs": [{c: b} for c, b in zip(_COMPONENTS, inp.buffers)]} for inp in self.inputs
        ]
        export = [
            {
                "set": inp.export[0],
                "sources": [{"label": "Time (s)", "buffer": inp.buffers[3]}]
                + [{"label": label, "buffer": b} for label, b in zip(inp.export[1], inp.buffers)],
            }
            for inp in self.inputs
        ]
        return {
            "crc32": f"{zlib.crc32(repr(self.inputs).encode()):x}",
            "title": self.title,
            "localTitle": self.title,
            "category": "New experiment",
            "localCategory": "New experiment",
            "buffers": buffers,
            "inputs": inputs,
            "export": export,
        }

    def meta(self) -> dict:
        specs = {"accelerometer": PHONE_ACCEL, "gyroscope": PHONE_GYRO, "magnetic_field": PHONE_MAG}
        sensors = {
            name: {
                "Name": f"{spec.chip} (simulated)",
                "Vendor": "kfkit",
                "Range": f"{spec.full_scale:.6g}",
                "Resolution": f"{spec.sensitivity:g}",
            }
            for name, spec in specs.items()
        }
        return {
            "version": "1.2.0",
            "build": "1020000",
            "fileFormat": "1.19",
            "deviceModel": "kfkit virtual phone",
            "deviceBrand": "kfkit",
            "deviceManufacturer": "kfkit",
            "deviceBaseOS": "",
            "deviceRelease": "simulation",
            "sensors": sensors,
        }

    def get(self, params) -> tuple[int, str]:
        """(HTTP status, JSON text) for /get with the query's (name, value) pairs."""
        with self._lock:
            if self.measuring and self.step_s is not None:
                self._t_exp += self.step_s
            t_now = self.experiment_time()
            series = {inp.data: self._series(inp.data, t_now) for inp in self.inputs}
            parts, seen = [], set()
            for name, value in params:
                if name in seen or name not in self._buffers:
                    continue  # phyphox skips unknown buffers and repeated names
                seen.add(name)
                inp, comp = self._buffers[name]
                t, v = series[inp.data]
                column = t if comp == 3 else v[:, comp]
                if value == "":
                    mode, shown = "single", column[-1:] if len(column) else np.array([np.nan])
                elif value == "full":
                    mode, shown = "full", column
                else:
                    threshold, _, ref = value.partition("|")
                    try:
                        threshold = _nudged(float(threshold))
                    except ValueError:
                        return 400, json.dumps({"error": "Invalid threshold."})
                    if ref and ref not in self._buffers:
                        return 400, json.dumps({"error": "Unknown reference buffer."})
                    ref_inp, ref_comp = self._buffers[ref] if ref else (inp, comp)
                    rt, rv = series[ref_inp.data]
                    reference = rt if ref_comp == 3 else rv[:, ref_comp]
                    n = min(len(reference), len(column))
                    mode, shown = "partial", column[:n][reference[:n] > threshold]
                values = ",".join(format_number(float(x)) for x in shown)
                parts.append(f'"{name}":{{"size":0,"updateMode":"{mode}","buffer":[{values}]}}')
            status = {"session": self.session, "measuring": self.measuring, "timedRun": False, "countDown": 0}
        return 200, '{"buffer":{\n' + ",\n".join(parts) + '\n},\n"status":' + json.dumps(status) + "\n}\n"

    def control(self, params) -> dict:
        cmd = dict(params).get("cmd")
        with self._lock:
            if cmd == "start":
                return {"result": self._start()}
            if cmd == "stop":
                self.experiment_time()
                if self.measuring:
                    self._stop()
                return {"result": True}
            if cmd == "clear":
                self._reset()
                return {"result": True}
        return {"result": False}

    def time_events(self) -> list:
        return [{"event": e, "experimentTime": t, "systemTime": time.time()} for e, t in self._events]

    # -- the server -------------------------------------------------------------------------------------
    @property
    def port(self) -> int | None:
        return self._server.server_address[1] if self._server is not None else None

    @property
    def address(self) -> str:
        return f"127.0.0.1:{self.port}"

    @property
    def url(self) -> str:
        """What to record from: ``phyphox://127.0.0.1:PORT``."""
        return f"phyphox://{self.address}"

    def start(self) -> VirtualPhone:
        phone_ = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.0"  # one request per connection, as phyphox's server

            def log_message(self, *args):
                pass

            def do_GET(self):
                phone_._serve(self)

            do_POST = do_GET

        self._server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self._server.daemon_threads = True
        self._server.block_on_close = False
        self._thread = threading.Thread(
            target=self._server.serve_forever,
            kwargs={"poll_interval": 0.05},
            name=f"kfkit-virtual-phone {self.address}",
            daemon=True,
        )
        self._thread.start()
        return self

    def _serve(self, handler):
        self.requests["keep_alive"] += handler.headers.get("Connection", "").lower() != "close"
        parts = urlsplit(handler.path)
        params = parse_qsl(parts.query, keep_blank_values=True)
        route = parts.path.rstrip("/") or "/"
        if route == "/get":
            self.requests["get"] += 1
            hang = self.faults.get("hang_after")
            if hang is not None and self.requests["get"] > hang:
                self._closed.wait()  # gone from the network: no answer until the phone is closed
                return
            status, body = self.get(params)
        elif route == "/control":
            self.requests["control"] += 1
            status, body = 200, json.dumps(self.control(params))
        elif route == "/config":
            self.requests["config"] += 1
            status, body = 200, json.dumps(self.config())
        elif route == "/meta":
            status, body = 200, json.dumps(self.meta())
        elif route == "/time":
            status, body = 200, json.dumps(self.time_events())
        elif route == "/":
            status, body = 200, "<html><body>kfkit virtual phone (phyphox remote access)</body></html>"
        else:
            status, body = 404, json.dumps({"error": f"Unknown document {route}."})
        data = body.encode("utf-8")
        try:
            handler.send_response(status)
            handler.send_header("Content-Type", "text/html" if route == "/" else "application/json")
            handler.send_header("Access-Control-Allow-Origin", "*")
            handler.send_header("Content-Length", str(len(data)))
            handler.end_headers()
            handler.wfile.write(data)
        except (BrokenPipeError, ConnectionResetError):
            pass

    def close(self):
        """Stop serving (idempotent); a hung request is released."""
        self._closed.set()
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            self._server = None

    def __enter__(self):
        return self.start() if self._server is None else self

    def __exit__(self, *exc):
        self.close()

    def __repr__(self):
        return f"VirtualPhone({self.title!r}, {self.url if self._server else 'not started'})"


def main(argv=None) -> int:
    import argparse

    parser = argparse.ArgumentParser(
        prog="python -m kfkit.capture.virtual_phone",
        description="Serve a simulated phone as phyphox's remote access on 127.0.0.1.",
    )
    parser.add_argument("--experiment", choices=list(EXPERIMENTS), default="simple")
    parser.add_argument("--motion", choices=["still", "attitude-tour"], default="attitude-tour")
    parser.add_argument("--speed", type=float, default=1.0, help="experiment seconds per second (default: %(default)s)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    motion = attitude_motions.attitude_tour(rate_hz=400.0) if args.motion == "attitude-tour" else None
    with VirtualPhone(motion, args.experiment, args.seed, args.speed) as vp:
        print(
            f"virtual phone serving; record with:  kfkit capture --port {vp.url} --seconds 30 --out phone.csv",
            flush=True,
        )
        try:
            while True:
                time.sleep(1.0)
        except KeyboardInterrupt:
            pass
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
