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
    POST /api/try              {run, file, pulse, preset, changes}: the run's fit and another, side by side
    POST /api/decompose        {input}: decompose an input without a run, in the background
"""

from __future__ import annotations

import json
import math
import mimetypes
import threading
import traceback
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from pathlib import Path
from urllib.parse import parse_qs, unquote, urlsplit

import numpy as np

from pipeline.view import queries
from pipeline.view.catalog import OutsideRoots, Roots, run_inputs, run_summary
from pipeline.view.jobs import Jobs
from fwcore.config import PRESETS, Optimizer
from pipeline.view.pulse import (decompose_pulse, load_pulse, reproduces, system_return_points, system_returns,
                                 try_config)

STATIC = Path(__file__).resolve().parent / "static"
MAX_ECHOES = 200_000  # the most one request returns, whatever the page asks
MAX_BODY = 64 * 1024
LOOPBACK = {"127.0.0.1", "::1"}


def _plotly_js() -> Path:
    return Path(str(resources.files("plotly") / "package_data" / "plotly.min.js"))


def jsonable(value):
    """numpy arrays and scalars to JSON types; NaN and infinities to null (JSON has no NaN)."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        if value.dtype.kind == "f":
            return [v if math.isfinite(v) else None for v in value.astype(float).tolist()]
        return value.tolist()
    if isinstance(value, np.generic):
        return jsonable(value.item())
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, Path):
        return str(value)
    return value


class BadRequest(ValueError):
    pass


class Viewer:
    """The state behind the endpoints: the roots it may read and its background jobs."""

    def __init__(self, roots: Roots, jobs: Jobs):
        self.roots, self.jobs = roots, jobs

    # ------------------------------------------------------------ endpoints

    def catalog(self, _params) -> dict:
        runs = []
        by_input: dict[str, str] = {}
        for folder in self.roots.runs():
            summary = run_summary(folder)
            ident = self.roots.id_of(folder)
            inputs = run_inputs(folder)
            for path in inputs.values():
                by_input.setdefault(str(path.resolve()), ident)
            runs.append({"id": ident, "name": folder.name, "inputs": sorted(inputs),
                         "counts": summary.get("counts", {}), "status": summary.get("status"),
                         "optimizer": summary.get("config", {}).get("optimizer")})
        jobs = {str(p): s for p, s in self.jobs.states().items()}
        inputs = []
        for path in self.roots.inputs():
            inputs.append({"id": self.roots.id_of(path), "name": path.name, "run": by_input.get(str(path)),
                           "job": jobs.get(str(path))})
        return {"runs": runs, "inputs": inputs, "presets": sorted(PRESETS), "optimizers": [o.value for o in Optimizer]}

    def summary(self, params) -> dict:
        run = self.roots.run_of(_param(params, "run"))
        summary = run_summary(run)
        counts = summary.get("counts", {})
        return {"run": _param(params, "run"), "name": run.name, "inputs": sorted(run_inputs(run)),
                "status": summary.get("status"), "counts": counts, "config": summary.get("config", {}),
                "seconds": summary.get("seconds"),
                "read_adds_up": counts.get("pulses_read") == counts.get("pulses_decomposed", 0)
                + counts.get("pulses_rejected", 0),
                "bounds": queries.bounds(run), "files": queries.source_files(run),
                "first_pulse": queries.first_pulse(run), "rejected": queries.rejected(run),
                "distributions": queries.distributions(run)}

    def echoes(self, params) -> dict:
        run = self.roots.run_of(_param(params, "run"))
        return queries.echoes_in_box(run, params.get("colour", ["height"])[0], _box(params), _limit(params),
                                     params.get("kept", ["0"])[0] == "1")

    def returns(self, params) -> dict:
        return system_return_points(self.roots.run_of(_param(params, "run")), _box(params), _limit(params))

    def pulses(self, params) -> dict:
        run = self.roots.run_of(_param(params, "run"))
        return {"pulses": queries.pulse_list(run, params.get("order", ["kept"])[0], _limit(params, 40))}

    def pulse(self, params) -> dict:
        ident = _param(params, "run")
        run = self.roots.run_of(ident)
        source_file, pulse_id = _param(params, "file"), _int(_param(params, "pulse"), "pulse")
        raw, config, row = load_pulse(run, source_file, pulse_id)
        rows = queries.pulse_echoes(run, source_file, pulse_id)
        fit = decompose_pulse(raw, config)
        return {"run": ident, "file": source_file, "pulse_id": pulse_id, "pulse": row, "echo_rows": rows,
                "fit": fit, "system_returns": system_returns(raw), "reproduced": reproduces(fit, rows)}

    def try_fit(self, body) -> dict:
        ident = body.get("run")
        run = self.roots.run_of(ident)
        source_file, pulse_id = str(body.get("file")), _int(body.get("pulse"), "pulse")
        changes = body.get("changes") or {}
        if not isinstance(changes, dict):
            raise BadRequest("changes must be an object of decomposition settings")
        raw, base, _ = load_pulse(run, source_file, pulse_id)
        other = try_config(base, body.get("preset") or None, changes)
        return {"run": ident, "file": source_file, "pulse_id": pulse_id, "system_returns": system_returns(raw),
                "a": decompose_pulse(raw, base), "b": decompose_pulse(raw, other),
                "changed": {k: v for k, v in other.to_dict().items() if base.to_dict()[k] != v}}

    def decompose(self, body) -> dict:
        path = self.roots.input_of(body.get("input", ""))
        job = self.jobs.start(path)
        return {"input": body.get("input"), "output": self.roots.id_of(job.output), **job.state()}


def _param(params: dict, name: str) -> str:
    values = params.get(name)
    if not values or values[0] == "":
        raise BadRequest(f"missing parameter {name!r}")
    return values[0]


def _box(params: dict) -> tuple[float, float, float, float] | None:
    if not params.get("box"):
        return None
    try:
        box = tuple(float(v) for v in _param(params, "box").split(","))
    except ValueError:
        raise BadRequest("box must be xmin,xmax,ymin,ymax") from None
    if len(box) != 4 or not all(math.isfinite(v) for v in box):
        raise BadRequest("box must be four finite numbers xmin,xmax,ymin,ymax")
    return box


def _limit(params: dict, default: int = 20000) -> int:
    return max(0, min(_int(params.get("limit", [default])[0], "limit"), MAX_ECHOES))


def _int(value, name: str) -> int:
    try:
        return int(value)
    except (TypeError, ValueError):
        raise BadRequest(f"{name} must be an integer, not {value!r}") from None


class Handler(BaseHTTPRequestHandler):
    server_version = "fwl-view"
    viewer: Viewer  # set on the subclass that serve() makes

    GET_ROUTES = {"/api/catalog": "catalog", "/api/summary": "summary", "/api/echoes": "echoes",
                  "/api/returns": "returns", "/api/pulses": "pulses", "/api/pulse": "pulse"}
    POST_ROUTES = {"/api/try": "try_fit", "/api/decompose": "decompose"}

    def log_message(self, format, *args):  # quiet: the terminal shows the URL, not every request
        pass

    def _foreign(self) -> bool:
        """A request for another host name (a web page that rebound its name to this machine), refused."""
        host = urlsplit("//" + (self.headers.get("Host") or "")).hostname or ""
        bound = self.server.server_address[0]
        return bound in LOOPBACK and host not in LOOPBACK | {"localhost"}

    def do_GET(self):
        if self._foreign():
            return self._error(403, "this viewer answers requests for 127.0.0.1 and localhost only")
        url = urlsplit(self.path)
        if url.path in ("/", "/index.html"):
            return self._file(STATIC / "index.html")
        if url.path.startswith("/static/"):
            return self._static(unquote(url.path[len("/static/"):]))
        if url.path in self.GET_ROUTES:
            return self._call(getattr(self.viewer, self.GET_ROUTES[url.path]), parse_qs(url.query))
        self._error(404, f"no such page {url.path}")

    def do_POST(self):
        if self._foreign():
            return self._error(403, "this viewer answers requests for 127.0.0.1 and localhost only")
        url = urlsplit(self.path)
        if url.path not in self.POST_ROUTES:
            return self._error(404, f"no such endpoint {url.path}")
        # JSON only: another site's page cannot send it without the browser asking this server first
        if (self.headers.get("Content-Type") or "").split(";")[0].strip() != "application/json":
            return self._error(415, "send the body as application/json")
        length = int(self.headers.get("Content-Length") or 0)
        if length > MAX_BODY:
            return self._error(413, "request too large")
        try:
            body = json.loads(self.rfile.read(length) or b"{}")
        except json.JSONDecodeError as err:
            return self._error(400, f"the body is not JSON: {err}")
        if not isinstance(body, dict):
            return self._error(400, "the body must be a JSON object")
        self._call(getattr(self.viewer, self.POST_ROUTES[url.path]), body)

    # ------------------------------------------------------------ responses

    def _call(self, endpoint, argument):
        try:
            payload = jsonable(endpoint(argument))
        except OutsideRoots as err:
            return self._error(403, str(err))
        except (BadRequest, ValueError) as err:
            return self._error(400, str(err))
        except (LookupError, FileNotFoundError) as err:
            return self._error(404, str(err))
        except Exception as err:  # the page shows the message; the terminal the trace
            traceback.print_exc()
            return self._error(500, f"{type(err).__name__}: {err}")
        self._send(200, json.dumps(payload, allow_nan=False).encode(), "application/json")

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
        self.send_response(status)
        self.send_header("Content-Type", kind)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "max-age=86400" if cache else "no-store")
        self.end_headers()
        self.wfile.write(body)


def make_server(paths: list[str | Path], host: str = "127.0.0.1", port: int = 0, runs_dir: str | Path = "out/view",
                jobs: Jobs | None = None) -> ThreadingHTTPServer:
    """A server on host:port (0: any free port) over the given run folders, folders and inputs."""
    roots = Roots.from_paths(paths, runs_dir)
    viewer = Viewer(roots, jobs or Jobs(Path(runs_dir).resolve()))
    handler = type("ViewerHandler", (Handler,), {"viewer": viewer})
    server = ThreadingHTTPServer((host, port), handler)
    server.daemon_threads = True
    server.viewer = viewer
    return server


def url_of(server: ThreadingHTTPServer) -> str:
    host, port = server.server_address[:2]
    return f"http://{host}:{port}/"


def serve_in_thread(server: ThreadingHTTPServer) -> threading.Thread:
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    return thread
