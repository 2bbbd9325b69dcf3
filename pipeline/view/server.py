"""The viewer's HTTP server: one page, its static files, and the JSON endpoints the page calls.

The standard library's threading HTTP server is enough for one local user; the
page draws with Plotly.js, served from the `plotly` Python package, so nothing
is fetched from the network.

    GET  /                     the page
    GET  /static/NAME          the page's JavaScript and CSS; /static/plotly.min.js from the plotly package
    GET  /api/catalog          runs and inputs under the viewer's folders, with the decompositions running
    GET  /api/summary?run=     run.json, bounds, rejected pulses with reasons, distributions
    GET  /api/echoes?run=&colour=&box=xmin,xmax,ymin,ymax&limit=   a sample of the echoes in a box
    GET  /api/returns?run=&box=&limit=  a sample of the system's own returns in a box
    GET  /api/pulses?run=&order=&limit= the pulses to look at first (most kept echoes, most echoes,
                                        most spurious, worst fit)
    GET  /api/pulse?run=&file=&pulse=   one pulse: samples, denoised, model, components, echo table rows
    GET  /api/grids?run=                the run's maps (fwl grid's folders), each band a layer for the map
    GET  /api/grid?run=&grid=&map=&band=&box= one layer: its cells' values (in a box) and where the map draws them
    POST /api/try              {run, file, pulse, preset, changes}: the run's fit and another, side by side
    POST /api/decompose        {input}: decompose an input without a run, in the background

Identities (pulse_id, shot_number, lfid) go out as strings of their digits and come back as such: GEDI's
shot numbers and LVIS's pulse ids lie beyond 2^53, where a JavaScript number rounds them to other shots.
"""

from __future__ import annotations

import collections
import hmac
import ipaddress
import json
import math
import mimetypes
import socket
import sys
import threading
import traceback
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from pathlib import Path
from urllib.parse import parse_qs, unquote, urlsplit

import numpy as np

from fwcore.engine.config import PRESETS, Model, Optimizer
from pipeline.layout import RUN_JSON
from pipeline.view import grids as layers
from pipeline.view import params, queries
from pipeline.view.catalog import OutsideRoots, Roots, run_inputs, run_summary
from pipeline.view.jobs import Jobs
from pipeline.view.params import BadRequest
from pipeline.view.pulse import (decompose_pulse, forest_markers, load_pulse, reproduces, shot_details,
                                 system_return_points, system_returns, try_config, try_pulse)

STATIC = Path(__file__).resolve().parent / "static"
MAX_BODY = 64 * 1024
LOOPBACK = {"127.0.0.1", "::1"}


def _plotly_js() -> Path:
    return Path(str(resources.files("plotly") / "package_data" / "plotly.min.js"))


JS_SAFE_INTEGER = 2**53 - 1  # beyond it a JavaScript number is not exact: GEDI's shot numbers go as strings
# identities, always as their digits: GEDI's shot numbers and LVIS's pulse ids lie beyond 2^53, and a page that
# holds some ids as numbers and others as strings rounds one some day (the page never makes a number of them)
ID_COLUMNS = ("pulse_id", "shot_number", "lfid")


def text_ids(row: dict) -> dict:
    """A table row for the page: its identities as decimal strings (exact), everything else as it is."""
    return {k: str(int(v)) if k in ID_COLUMNS and v is not None else v for k, v in row.items()}


def _exact(value: int) -> int | str:
    return str(value) if abs(value) > JS_SAFE_INTEGER else value


def jsonable(value):
    """numpy arrays and scalars to JSON types; NaN and infinities to null (JSON has no NaN); integers beyond
    JavaScript's exact range to strings."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        if value.dtype.kind == "f":
            return [v if math.isfinite(v) else None for v in value.astype(float).tolist()]
        if value.dtype.kind in "iu" and value.size and np.abs(value.astype(np.float64)).max() > JS_SAFE_INTEGER:
            return [_exact(int(v)) for v in value.ravel().tolist()] if value.ndim == 1 else jsonable(list(value))
        return value.tolist()
    if isinstance(value, np.generic):
        return jsonable(value.item())
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, int) and not isinstance(value, bool):
        return _exact(value)
    return value


def _first_pulse(run: Path) -> list[str] | None:
    found = queries.first_pulse(run)
    return None if found is None else [found[0], str(found[1])]


def _rejected(run: Path) -> dict:
    rejected = queries.rejected(run)
    return {**rejected, "rows": [text_ids(r) for r in rejected["rows"]]}


class Refits:
    """A bounded queue for the fits a request asks for (a pulse, a refit): at most `slots` at a time and
    `waiting` queued; a page's later request cancels its own one still waiting (it moved on)."""

    def __init__(self, slots: int = 1, waiting: int = 8):
        self.slots, self.max_waiting = slots, waiting
        self._running = 0
        self._queue: list[dict] = []
        self._cond = threading.Condition()

    def run(self, page: str | None, kind: str, work):
        ticket = {"page": page, "kind": kind, "cancelled": False}
        with self._cond:
            if page is not None:
                for other in self._queue:
                    if other["page"] == page and other["kind"] == kind:
                        other["cancelled"] = True
            self._queue = [t for t in self._queue if not t["cancelled"]]
            if len(self._queue) >= self.max_waiting:
                raise Busy(f"the viewer is busy: {len(self._queue)} fits are waiting; try again in a moment")
            self._queue.append(ticket)
            self._cond.notify_all()
            while not ticket["cancelled"] and (self._running >= self.slots or self._queue[0] is not ticket):
                self._cond.wait()
            if ticket["cancelled"]:
                self._cond.notify_all()
                raise Cancelled(f"this {kind} was replaced by a later one from the same page")
            self._queue.pop(0)
            self._running += 1
        try:
            return work()
        finally:
            with self._cond:
                self._running -= 1
                self._cond.notify_all()


class Encoded(bytes):
    """An answer already in JSON."""


class Answers:
    """The last `size` answers by key; a key many requests ask for at once is made once, the others wait for it
    (a reload, or many pages on the same view, read the tables and encode the JSON once)."""

    def __init__(self, size: int = 32):
        self.size = size
        self._answers: collections.OrderedDict = collections.OrderedDict()
        self._making: dict = {}
        self._lock = threading.Lock()

    def clear(self) -> None:
        with self._lock:
            self._answers.clear()

    def get(self, key, make) -> Encoded:
        with self._lock:
            if key in self._answers:
                self._answers.move_to_end(key)
                return self._answers[key]
            making = self._making.setdefault(key, threading.Lock())
        with making:
            with self._lock:
                if key in self._answers:
                    return self._answers[key]
            answer = Encoded(json.dumps(jsonable(make()), allow_nan=False).encode())
            with self._lock:
                self._answers[key] = answer
                while len(self._answers) > self.size:
                    self._answers.popitem(last=False)
                self._making.pop(key, None)
        return answer


class Busy(RuntimeError):
    """Too many fits waiting (HTTP 503)."""


class Cancelled(RuntimeError):
    """A waiting fit that its page replaced (HTTP 409)."""


class Viewer:
    """The state behind the endpoints: the roots it may read, its background jobs and its queue of fits."""

    def __init__(self, roots: Roots, jobs: Jobs, token: str | None = None):
        self.roots, self.jobs, self.token = roots, jobs, token
        self.refits = Refits()
        self.answers = Answers()

    # ------------------------------------------------------------ endpoints

    def catalog(self, _params) -> dict:
        runs, by_input, unavailable = [], {}, []
        for folder in self.roots.runs():
            try:
                summary = run_summary(folder)
                ident = self.roots.id_of(folder)
                inputs = run_inputs(folder)
            except (OSError, ValueError) as err:  # one unreadable run is listed as such, not a blank page
                unavailable.append({"name": folder.name, "reason": str(err)})
                continue
            for path in inputs.values():
                by_input.setdefault(str(path.resolve()), ident)
            runs.append({"id": ident, "name": folder.name, "inputs": sorted(inputs),
                         "counts": summary.get("counts", {}), "status": summary.get("status"),
                         "optimizer": summary.get("config", {}).get("optimizer")})
        jobs = {str(p): s for p, s in self.jobs.states().items()}
        inputs = []
        for path in self.roots.inputs():
            try:
                ident = self.roots.id_of(path)
            except OutsideRoots as err:
                unavailable.append({"name": path.name, "reason": str(err)})
                continue
            inputs.append({"id": ident, "name": path.name, "run": by_input.get(str(path.resolve())),
                           "job": jobs.get(str(path))})
        return {"runs": runs, "inputs": inputs, "unavailable": unavailable, "presets": sorted(PRESETS),
                "optimizers": [o.value for o in Optimizer], "models": [m.value for m in Model],
                "try_settings": {k: list(v) for k, v in params.TRY_SETTINGS.items()}}

    def summary(self, query) -> dict:
        ident = params.name(params.query_value(query, "run"), "run")
        run = self.roots.run_of(ident)
        summary = run_summary(run)
        counts = summary.get("counts", {})
        return {"run": ident, "name": run.name, "inputs": sorted(run_inputs(run)),
                "status": summary.get("status"), "counts": counts, "config": summary.get("config", {}),
                "seconds": summary.get("seconds"),
                "read_adds_up": counts.get("pulses_read") == counts.get("pulses_decomposed", 0)
                + counts.get("pulses_rejected", 0),
                "bounds": queries.bounds(run), "frame": queries.frame(run).describe(),
                "colours": queries.colours(run), "files": queries.source_files(run),
                "first_pulse": _first_pulse(run), "rejected": _rejected(run),
                "distributions": queries.distributions(run)}

    def echoes(self, query) -> dict:
        run = self.roots.run_of(params.name(params.query_value(query, "run"), "run"))
        colour = params.choice(query, "colour", tuple(queries.COLOUR_COLUMNS), "height")
        box, limit, kept = params.box(query), params.limit(query, 20000), params.flag(query, "kept")
        marker = run / RUN_JSON  # a run written again is another run
        key = ("echoes", str(run), marker.stat().st_mtime_ns, colour, box, limit, kept)
        return self.answers.get(key, lambda: queries.echoes_in_box(run, colour, box, limit, kept))

    def returns(self, query) -> dict:
        run = self.roots.run_of(params.name(params.query_value(query, "run"), "run"))
        return system_return_points(run, params.box(query), params.limit(query, 20000))

    def pulses(self, query) -> dict:
        run = self.roots.run_of(params.name(params.query_value(query, "run"), "run"))
        order = params.choice(query, "order", tuple(queries.PULSE_ORDERS), "kept")
        listed = queries.pulse_list(run, order, params.limit(query, 40, params.MAX_PULSE_LIST))
        return {"pulses": [text_ids(p) for p in listed]}

    def pulse(self, query) -> dict:
        ident = params.name(params.query_value(query, "run"), "run")
        run = self.roots.run_of(ident)
        source_file = params.name(params.query_value(query, "file"), "file")
        pulse_id = params.pulse_id(params.query_value(query, "pulse"))
        page = params.page(params.query_value(query, "page", ""))
        raw, config, pulse, row = load_pulse(run, source_file, pulse_id)
        rows = queries.pulse_echoes(run, source_file, pulse_id)
        fit = self.refits.run(page, "pulse", lambda: decompose_pulse(raw, config, pulse))
        mx, my, mz = queries.frame(run).apply([r["x"] for r in rows], [r["y"] for r in rows],
                                              [r["z"] for r in rows])
        return {"run": ident, "file": source_file, "pulse_id": str(pulse_id), "pulse": text_ids(row),
                "echo_rows": [text_ids(r) for r in rows], "map": {"x": mx, "y": my, "z": mz}, "fit": fit,
                "system_returns": system_returns(raw), "forest": forest_markers(raw, row), "shot": shot_details(row),
                "reproduced": reproduces(fit, rows)}

    def grids(self, query) -> dict:
        ident = params.name(params.query_value(query, "run"), "run")
        run = self.roots.run_of(ident)
        frame = queries.frame(run)
        listed = layers.listing(self.roots, run, frame.planar)
        for grid in listed:
            grid["cell"] = layers.cell_words(grid["cell_m"], frame) if frame.planar else None
        return {"run": ident, "grids": listed}

    def grid(self, query) -> dict:
        run = self.roots.run_of(params.name(params.query_value(query, "run"), "run"))
        frame = queries.frame(run)
        path, band = layers.request(self.roots, run, query, frame.planar)
        box = params.box(query)
        key = ("grid", str(path), path.stat().st_mtime_ns, band, box, frame)
        return self.answers.get(key, lambda: layers.in_frame(
            layers.read_layer(path, band, box=layers.crs_box(box, frame)), frame))

    def try_fit(self, body) -> dict:
        ident = params.name(body.get("run"), "run")
        run = self.roots.run_of(ident)
        source_file, pulse_id = params.name(body.get("file"), "file"), params.pulse_id(body.get("pulse"))
        changes, preset = params.try_changes(body.get("changes")), params.preset(body.get("preset"))
        page = params.page(body.get("page"))
        raw, base, pulse, _ = load_pulse(run, source_file, pulse_id)
        other, other_pulse = try_config(base, preset, changes), try_pulse(pulse, preset)
        a, b = self.refits.run(page, "refit", lambda: (decompose_pulse(raw, base, pulse),
                                                       decompose_pulse(raw, other, other_pulse)))
        changed = {k: v for k, v in other.to_dict().items() if base.to_dict()[k] != v}
        if other_pulse.shape_tolerance != pulse.shape_tolerance:  # a preset's word on the pulse (the paper's)
            changed["shape_tolerance"] = other_pulse.shape_tolerance
        return {"run": ident, "file": source_file, "pulse_id": str(pulse_id), "system_returns": system_returns(raw),
                "a": a, "b": b, "changed": changed}

    def decompose(self, body) -> dict:
        ident = params.name(body.get("input"), "input")
        path = self.roots.input_of(ident)
        job = self.jobs.start(path)
        return {"input": ident, "output": self.roots.id_of(job.output), **job.state()}


# the page runs only its own files' scripts, never inline script or markup's handlers; Plotly sets inline styles,
# and its WebGL layer (regl) builds its draw calls with Function, hence 'unsafe-eval' (over no text of a file)
CONTENT_SECURITY_POLICY = ("default-src 'self'; script-src 'self' 'unsafe-eval'; style-src 'self' 'unsafe-inline'; "
                           "img-src 'self' data: blob:; worker-src 'self' blob:; connect-src 'self'; "
                           "object-src 'none'; base-uri 'none'; form-action 'self'; frame-ancestors 'none'")
REQUEST_TIMEOUT = 10.0  # seconds a connection may stay silent (a short body, a half-open client)
LISTEN_BACKLOG = 256


class Handler(BaseHTTPRequestHandler):
    server_version = "fwl-view"
    timeout = REQUEST_TIMEOUT
    viewer: Viewer  # set on the subclass that serve() makes

    GET_ROUTES = {"/api/catalog": "catalog", "/api/summary": "summary", "/api/echoes": "echoes",
                  "/api/returns": "returns", "/api/pulses": "pulses", "/api/pulse": "pulse",
                  "/api/grids": "grids", "/api/grid": "grid"}
    POST_ROUTES = {"/api/try": "try_fit", "/api/decompose": "decompose"}

    def log_message(self, format, *args):  # quiet: the terminal shows the URL, not every request
        pass

    def _refused(self, url) -> str | None:
        """Why the request is refused before any route, or None: another host name (a web page that
        rebound its name to this machine), or an API call without the token of a viewer open to the network."""
        host = urlsplit("//" + (self.headers.get("Host") or "")).hostname or ""
        bound = self.server.server_address[0]
        if bound in LOOPBACK and host not in LOOPBACK | {"localhost"}:
            return "this viewer answers requests for 127.0.0.1 and localhost only"
        token = self.viewer.token
        if token and url.path.startswith("/api/"):
            given = self.headers.get("X-Fwl-Token") or (parse_qs(url.query).get("token") or [""])[0]
            if not hmac.compare_digest(given.encode(), token.encode()):
                return "this viewer asks for its token: open the URL `fwl view` printed (.../?token=...)"
        return None

    def do_GET(self):
        url = urlsplit(self.path)
        refused = self._refused(url)
        if refused:
            return self._error(403, refused)
        if url.path in ("/", "/index.html"):
            return self._file(STATIC / "index.html")
        if url.path.startswith("/static/"):
            return self._static(unquote(url.path[len("/static/"):]))
        if url.path in self.GET_ROUTES:
            return self._call(getattr(self.viewer, self.GET_ROUTES[url.path]), parse_qs(url.query))
        self._error(404, f"no such page {url.path}")

    def do_POST(self):
        url = urlsplit(self.path)
        refused = self._refused(url)
        if refused:
            return self._error(403, refused)
        if url.path not in self.POST_ROUTES:
            return self._error(404, f"no such endpoint {url.path}")
        # JSON only: another site's page cannot send it without the browser asking this server first
        if (self.headers.get("Content-Type") or "").split(";")[0].strip() != "application/json":
            return self._error(415, "send the body as application/json")
        text = (self.headers.get("Content-Length") or "0").strip()
        if not text.isdigit():
            return self._error(400, f"Content-Length must be a whole number of bytes, not {text!r}")
        if int(text) > MAX_BODY:
            return self._error(413, "request too large")
        try:
            body = json.loads(self.rfile.read(int(text)) or b"{}")
        except (json.JSONDecodeError, UnicodeDecodeError) as err:
            return self._error(400, f"the body is not JSON: {err}")
        if not isinstance(body, dict):
            return self._error(400, "the body must be a JSON object")
        self._call(getattr(self.viewer, self.POST_ROUTES[url.path]), body)

    # ------------------------------------------------------------ responses

    def _call(self, endpoint, argument):
        try:
            answer = endpoint(argument)
            payload = answer if isinstance(answer, Encoded) else json.dumps(jsonable(answer), allow_nan=False).encode()
        except OutsideRoots as err:
            return self._error(403, str(err))
        except (BadRequest, ValueError) as err:
            return self._error(400, str(err))
        except (LookupError, FileNotFoundError) as err:
            return self._error(404, str(err))
        except Cancelled as err:
            return self._error(409, str(err))
        except Busy as err:
            return self._error(503, str(err))
        except Exception as err:  # the page shows the message; the terminal the trace
            traceback.print_exc()
            return self._error(500, f"{type(err).__name__}: {err}")
        self._send(200, payload, "application/json")

    def _static(self, name: str):
        if name == "plotly.min.js":
            return self._file(_plotly_js())
        path = (STATIC / name).resolve()
        if not path.is_relative_to(STATIC) or not path.is_file():
            return self._error(404 if path.is_relative_to(STATIC) else 403, f"no such static file {name}")
        self._file(path)

    def _file(self, path: Path):
        kind = mimetypes.guess_type(path.name)[0] or "application/octet-stream"
        if kind.startswith("text/") or kind.endswith("javascript"):
            kind += "; charset=utf-8"
        self._send(200, path.read_bytes(), kind, cache=path.name == "plotly.min.js")

    def _error(self, status: int, message: str):
        self._send(status, json.dumps({"error": message}).encode(), "application/json")

    def _send(self, status: int, body: bytes, kind: str, cache: bool = False):
        try:
            self.send_response(status)
            self.send_header("Content-Type", kind)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "max-age=86400" if cache else "no-store")
            self.send_header("X-Content-Type-Options", "nosniff")
            self.send_header("Content-Security-Policy", CONTENT_SECURITY_POLICY)
            self.send_header("X-Frame-Options", "DENY")
            self.send_header("Referrer-Policy", "no-referrer")
            self.end_headers()
            self.wfile.write(body)
        except (ConnectionError, TimeoutError) as err:  # the page moved on before its answer
            self.server.note_dropped(err)
            self.close_connection = True


class ViewerServer(ThreadingHTTPServer):
    """A thread per connection, a deep listen backlog, silent connections dropped after REQUEST_TIMEOUT, and
    clients that hang up logged once, quietly, not as a traceback each."""

    daemon_threads = True
    request_queue_size = LISTEN_BACKLOG
    viewer: Viewer

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._dropped = 0
        self._dropped_lock = threading.Lock()

    def note_dropped(self, err: BaseException) -> None:
        with self._dropped_lock:
            self._dropped += 1
            first = self._dropped == 1
        if first:
            print(f"fwl view: a client closed its connection before its answer ({type(err).__name__}); "
                  f"such drops are not shown again", file=sys.stderr, flush=True)

    def handle_error(self, request, client_address):
        err = sys.exc_info()[1]
        if isinstance(err, (ConnectionError, TimeoutError)):
            return self.note_dropped(err)
        super().handle_error(request, client_address)


def make_server(paths: list[str | Path], host: str = "127.0.0.1", port: int = 0, runs_dir: str | Path = "out/view",
                jobs: Jobs | None = None, token: str | None = None) -> ViewerServer:
    """A server on host:port (0: any free port) over the given run folders, folders and inputs; with a token,
    every API call must carry it (X-Fwl-Token header or ?token=)."""
    roots = Roots.from_paths(paths, runs_dir)
    viewer = Viewer(roots, jobs or Jobs(Path(runs_dir).resolve()), token)
    handler = type("ViewerHandler", (Handler,), {"viewer": viewer})
    server = ViewerServer((host, port), handler)
    server.viewer = viewer
    return server


def is_loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return host == "localhost"


def url_of(server: ThreadingHTTPServer) -> str:
    """The page's URL: a wildcard address (0.0.0.0, ::) is no address to open, so this machine's name stands
    for it; the token, when the server has one, rides along once."""
    host, port = server.server_address[:2]
    if host in ("0.0.0.0", "::", ""):
        host = socket.gethostname()
    elif ":" in host:
        host = f"[{host}]"
    token = getattr(getattr(server, "viewer", None), "token", None)
    return f"http://{host}:{port}/" + (f"?token={token}" if token else "")


def serve_in_thread(server: ThreadingHTTPServer) -> threading.Thread:
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    return thread
