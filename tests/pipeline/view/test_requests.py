"""What a request can say to the viewer: every bad value answered 400 with its reason (never 500), the headers
that keep the page's data text, colour modes a run lacks, linked inputs, and decompositions that never replace
one another."""

import http.client
import json
import os
import shutil
import threading
import time
from pathlib import Path
from urllib.parse import urlsplit

import numpy as np
import pytest

from pipeline.view.jobs import Jobs
from pipeline.view.server import CONTENT_SECURITY_POLICY, make_server, serve_in_thread, url_of
from tests.pipeline.view.conftest import POINTS_PER_RANGE, Viewed, run_args


def _request(url, method, path, body=None, headers=None, raw=None):
    """One request exactly as written; (status, headers, JSON or bytes)."""
    u = urlsplit(url)
    con = http.client.HTTPConnection(u.hostname, u.port, timeout=60)
    data = raw if raw is not None else (json.dumps(body) if body is not None else None)
    con.request(method, path, body=data, headers={"Content-Type": "application/json", **(headers or {})})
    response = con.getresponse()
    payload = response.read()
    con.close()
    try:
        payload = json.loads(payload)
    except ValueError:
        pass
    return response.status, dict(response.getheaders()), payload


def _pulse(viewed) -> int:
    return int(viewed.pulses().sort_values("gps_time").pulse_id.iloc[0])


# (what, GET query or POST body changes, the reason's words)
BAD_GETS = [
    ("/api/summary?run=", "missing parameter 'run'"),
    ("/api/summary?run=0/%01x", "printable"),
    ("/api/echoes?run={run}&colour=rainbow", "colour must be one of"),
    ("/api/echoes?run={run}&limit=-1", "limit must be a whole number"),
    ("/api/echoes?run={run}&limit=2.5", "limit must be a whole number"),
    ("/api/echoes?run={run}&limit=1e9", "limit must be a whole number"),
    ("/api/echoes?run={run}&box=1,2,3", "box must be four"),
    ("/api/echoes?run={run}&box=nan,1,2,3", "box must be four finite"),
    ("/api/echoes?run={run}&box=3,1,0,1", "xmin <= xmax"),
    ("/api/echoes?run={run}&kept=yes", "kept must be one of"),
    ("/api/returns?run={run}&box=a,b,c,d", "box must be four"),
    ("/api/returns?run={run}&limit=many", "limit must be a whole number"),
    ("/api/pulses?run={run}&order=random", "order must be one of"),
    ("/api/pulses?run={run}&limit=2.5", "limit must be a whole number"),
    ("/api/pulse?run={run}&file=leica_a.las&pulse=12345abc", "pulse must be a whole number"),
    ("/api/pulse?run={run}&file=leica_a.las&pulse=2.5", "pulse must be a whole number"),
    ("/api/pulse?run={run}&file=leica_a.las&pulse=1e9", "pulse must be a whole number"),
    ("/api/pulse?run={run}&file=leica_a.las&pulse=99999999999999999999", "64-bit"),
    ("/api/pulse?run={run}&pulse=1", "missing parameter 'file'"),
    ("/api/pulse?run={run}&file=leica_a.las&pulse={pulse}&page=../x", "page must be"),
]

BAD_TRIES = [
    ({"changes": {"max_echoes": "3"}}, "max_echoes must be a number"),
    ({"changes": {"max_echoes": 2.5}}, "max_echoes must be a whole number"),
    ({"changes": {"max_echoes": 1e9}}, "max_echoes must be a whole number"),
    ({"changes": {"max_echoes": 1000000000}}, "max_echoes must lie in [1, 24]"),
    ({"changes": {"max_echoes": True}}, "max_echoes must be a number"),
    ({"changes": {"generations": 100000}}, "generations must lie in [0, 1000]"),
    ({"changes": {"generations": -1}}, "generations must lie"),
    ({"changes": {"population": 2}}, "population must lie in [5, 200]"),
    ({"changes": {"population": 100000}}, "population must lie"),
    ({"changes": {"min_snr": None}}, "min_snr must be a number"),
    ({"changes": {"noise_threshold": 0}}, "noise_threshold must lie"),
    ({"changes": {"optimizer": "simplex"}}, "optimizer must be one of"),
    ({"changes": {"model": "<b>"}}, "model must be one of"),
    ({"changes": {"system_response": "/etc/passwd"}}, "'system_response' cannot be changed"),
    ({"changes": {"prune_echoes": True}}, "'prune_echoes' cannot be changed"),
    ({"changes": ["max_echoes", 3]}, "changes must be an object"),
    ({"preset": "turbo"}, "preset must be one of"),
    ({"preset": 3}, "preset must be one of"),
    ({"pulse": "12345abc"}, "pulse must be a whole number"),
    ({"pulse": 2.5}, "pulse must be a whole number"),
    ({"pulse": None}, "pulse must be a whole number"),
    ({"file": 7}, "file must be a string"),
    ({"run": ["0/"]}, "run must be a string"),
    ({"page": {"a": 1}}, "page must be"),
]


@pytest.mark.parametrize("path, reason", BAD_GETS)
def test_a_bad_query_value_is_a_400_with_its_reason(viewed, path, reason):
    status, _, data = _request(viewed.url, "GET", path.format(run=viewed.run_id, pulse=_pulse(viewed)))
    assert status == 400 and reason in data["error"], data


@pytest.mark.parametrize("body, reason", BAD_TRIES)
def test_a_bad_refit_is_a_400_with_its_reason(viewed, body, reason):
    full = {"run": viewed.run_id, "file": "leica_a.las", "pulse": _pulse(viewed), "changes": {}, **body}
    status, _, data = _request(viewed.url, "POST", "/api/try", full)
    assert status == 400 and reason in data["error"], data


@pytest.mark.parametrize("body, reason", [({"input": 5}, "input must be a string"), ({}, "missing parameter"),
                                          ({"input": "x" * 5000}, "printable")])
def test_a_bad_decompose_is_a_400_with_its_reason(viewed, body, reason):
    status, _, data = _request(viewed.url, "POST", "/api/decompose", body)
    assert status == 400 and reason in data["error"], data


@pytest.mark.parametrize("headers, raw, status", [
    ({"Content-Length": "-1"}, b"", 400), ({"Content-Length": "abc"}, b"", 400),
    ({}, b"\xff\xfe not json", 400), ({}, b"[1, 2]", 400),
])
def test_a_malformed_body_is_refused_at_once(viewed, headers, raw, status):
    started = time.monotonic()
    got, _, data = _request(viewed.url, "POST", "/api/try", headers=headers, raw=raw)
    assert got == status and "error" in data and time.monotonic() - started < 5


def test_a_good_refit_with_every_setting_at_its_cap_answers(viewed):
    changes = {"max_echoes": 24, "generations": 5, "population": 5, "min_snr": 0, "min_amplitude_ratio": 1.0,
               "model": "gaussian", "optimizer": "mde", "select_echoes": False}
    status, _, data = _request(viewed.url, "POST", "/api/try", {"run": viewed.run_id, "file": "leica_a.las",
                                                               "pulse": _pulse(viewed), "changes": changes})
    assert status == 200 and data["b"]["config"]["max_echoes"] == 24 and data["b"]["config"]["model"] == "gaussian"


def test_every_answer_says_it_is_data_not_a_page_to_frame_or_sniff(viewed):
    for path in ("/", "/static/viewer.js", f"/api/summary?run={viewed.run_id}", "/api/summary?run=9/"):
        _, headers, _ = _request(viewed.url, "GET", path)
        assert headers["X-Content-Type-Options"] == "nosniff"
        csp = headers["Content-Security-Policy"]
        assert csp == CONTENT_SECURITY_POLICY and "frame-ancestors 'none'" in csp
        script = next(d for d in csp.split(";") if d.strip().startswith("script-src"))
        assert script.split() == ["script-src", "'self'", "'unsafe-eval'"]  # no inline script (regl needs eval)
    _, _, page = _request(viewed.url, "GET", "/")
    assert b"<script>" not in page and b"onclick" not in page and b"javascript:" not in page


def test_colour_by_a_column_the_run_lacks_answers_with_the_reason(viewed):
    """The Leica sample has no radiometry: reflectance and range are offered greyed, and asking still answers."""
    summary = viewed.get(f"/api/summary?run={viewed.run_id}")
    assert summary["colours"]["height"] is None and summary["colours"]["amplitude"] is None
    assert "radiometry" in summary["colours"]["reflectance"] and summary["colours"]["range"]
    status, _, data = _request(viewed.url, "GET", f"/api/echoes?run={viewed.run_id}&colour=reflectance")
    assert status == 200 and "radiometry" in data["unavailable"]
    assert len(data["x"]) == len(viewed.echoes()) and all(v is None for v in data["value"])


def test_the_colour_scale_is_the_2nd_to_98th_percentile(viewed):
    data = viewed.get(f"/api/echoes?run={viewed.run_id}&colour=amplitude&limit=200000")
    amplitude = viewed.echoes().amplitude.to_numpy()
    lo, hi = np.percentile(amplitude, [2, 98])
    assert data["cmin"] == pytest.approx(lo, rel=1e-12) and data["cmax"] == pytest.approx(hi, rel=1e-12)
    assert data["below"] == int((amplitude < lo).sum()) > 0 and data["above"] == int((amplitude > hi).sum()) > 0
    width = viewed.get(f"/api/echoes?run={viewed.run_id}&colour=width&limit=200000")
    assert width["unit"] == "ns" and np.nanmax(width["value"]) == pytest.approx(viewed.echoes().fwhm_ps.max() / 1000,
                                                                                 rel=1e-6)


def test_the_picked_pulse_comes_with_its_place_on_the_map(viewed):
    pulse_id = _pulse(viewed)
    p = viewed.get(f"/api/pulse?run={viewed.run_id}&file=leica_a.las&pulse={pulse_id}")
    rows = viewed.echoes()[lambda e: e.pulse_id == pulse_id].sort_values("echo_index")
    assert np.allclose(p["map"]["x"], rows.x) and np.allclose(p["map"]["y"], rows.y)  # a projected frame: as is


@pytest.fixture
def two_folders(tmp_path, leica_dir):
    """a/leica_a.las, b/leica_a.las (same name, two folders) and link/linked.las, a link to a file outside."""
    for sub in ("a", "b"):
        (tmp_path / "view" / sub).mkdir(parents=True)
        for suffix in (".las", ".wdp"):
            shutil.copy(leica_dir / f"leica_a{suffix}", tmp_path / "view" / sub / f"leica_a{suffix}")
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "view" / "link").mkdir()
    for suffix in (".las", ".wdp"):
        shutil.copy(leica_dir / f"leica_a{suffix}", tmp_path / "elsewhere" / f"linked{suffix}")
        os.symlink(tmp_path / "elsewhere" / f"linked{suffix}", tmp_path / "view" / "link" / f"linked{suffix}")
    runs = tmp_path / "runs"
    server = make_server([tmp_path / "view"], port=0, runs_dir=runs,
                         jobs=Jobs(runs, run_args(10), POINTS_PER_RANGE))
    serve_in_thread(server)
    try:
        yield Viewed(url_of(server), tmp_path / "view", runs, "", "", []), runs
    finally:
        server.viewer.jobs.stop_all()
        server.shutdown()
        server.server_close()


def _wait_done(v: Viewed, input_id: str) -> dict:
    deadline = time.time() + 600
    while time.time() < deadline:
        listed = {i["id"]: i for i in v.get("/api/catalog")["inputs"]}[input_id]
        if listed["job"] and listed["job"]["status"] != "running":
            return listed
        time.sleep(0.5)
    raise AssertionError(f"{input_id} still running")


def test_inputs_of_one_name_get_runs_of_their_own_and_a_link_is_followed(two_folders):
    v, runs = two_folders
    catalog = v.get("/api/catalog")  # the link out of the folder does not blank the catalog
    ids = {i["name"] + ":" + i["id"].split("/", 1)[1]: i["id"] for i in catalog["inputs"]}
    assert set(ids) == {"leica_a.las:a/leica_a.las", "leica_a.las:b/leica_a.las", "linked.las:link/linked.las"}
    outputs = [v.post("/api/decompose", {"input": ids[k]})["output"]
               for k in ("leica_a.las:a/leica_a.las", "leica_a.las:b/leica_a.las", "linked.las:link/linked.las")]
    assert len(set(outputs)) == 3
    done = [_wait_done(v, ids[k]) for k in ids]
    assert all(d["job"]["status"] == "done" for d in done), [d["job"] for d in done]
    owners = {}
    for run in ("leica_a", "leica_a-2", "linked"):
        (entry,) = json.loads((runs / run / "run.json").read_text())["inputs"]
        owners[run] = entry["path"] if isinstance(entry, dict) else entry
    assert {owners["leica_a"], owners["leica_a-2"]} == {str(v.folder / "a" / "leica_a.las"),
                                                         str(v.folder / "b" / "leica_a.las")}
    assert Path(owners["linked"]).resolve() == (v.folder / "link" / "linked.las").resolve()
    # picked again, each input keeps its own folder
    again = v.post("/api/decompose", {"input": ids["leica_a.las:b/leica_a.las"]})["output"]
    assert again == outputs[1]
    v_catalog = v.get("/api/catalog")
    assert {i["run"] for i in v_catalog["inputs"]} == {r["id"] for r in v_catalog["runs"]}


def test_a_refused_decompose_creates_nothing(tmp_path):
    (tmp_path / "view").mkdir()
    (tmp_path / "view" / "broken.pls").write_bytes(b"not a pulsewaves file")
    runs = tmp_path / "out" / "view"
    server = make_server([tmp_path / "view"], port=0, runs_dir=runs, jobs=Jobs(runs, run_args(10), POINTS_PER_RANGE))
    serve_in_thread(server)
    try:
        for body in ({"input": "0/broken.pls"}, {"input": "0/../../etc/passwd"}, {"input": "0/nothing.las"}):
            status, _, data = _request(url_of(server), "POST", "/api/decompose", body)
            assert status in (400, 403, 404) and data["error"]
        assert not (tmp_path / "out").exists()
    finally:
        server.shutdown()
        server.server_close()


def test_many_requests_at_once_and_idle_connections_are_all_answered(viewed):
    """200 map requests at once all answer 200 (a deep listen backlog: none reset), with the same echoes; with
    300 connections open and silent, another request is still answered (a thread each, dropped on timeout)."""
    import socket
    from concurrent.futures import ThreadPoolExecutor

    path = f"/api/echoes?run={viewed.run_id}&colour=amplitude&limit=60000"
    with ThreadPoolExecutor(200) as pool:
        answers = list(pool.map(lambda _: _request(viewed.url, "GET", path), range(200)))
    assert [a[0] for a in answers] == [200] * 200
    assert all(a[2]["pulse_id"] == answers[0][2]["pulse_id"] for a in answers)
    u = urlsplit(viewed.url)
    idle = [socket.create_connection((u.hostname, u.port), timeout=30) for _ in range(300)]
    try:
        idle[0].sendall(b"POST /api/try HTTP/1.1\r\nContent-Type: application/json\r\nContent-Length: 100\r\n\r\n{")
        status, _, data = _request(viewed.url, "GET", f"/api/summary?run={viewed.run_id}")
        assert status == 200 and data["counts"]["pulses_read"] == 90
    finally:
        for s in idle:
            s.close()


def test_a_fit_waiting_is_cancelled_by_its_pages_next(viewed):
    from concurrent.futures import ThreadPoolExecutor

    from pipeline.view.server import Busy, Cancelled, Refits

    refits, started, release = Refits(slots=1, waiting=2), threading.Event(), threading.Event()

    def slow():
        started.set()
        release.wait(30)
        return "first"

    with ThreadPoolExecutor(4) as pool:
        first = pool.submit(refits.run, "page-a", "refit", slow)
        started.wait(30)
        waiting = pool.submit(refits.run, "page-b", "refit", lambda: "b, first try")
        time.sleep(0.2)
        later = pool.submit(refits.run, "page-b", "refit", lambda: "b, moved on")
        other = pool.submit(refits.run, "page-c", "refit", lambda: "c")
        time.sleep(0.2)
        with pytest.raises(Busy):  # two waiting already: the queue is bounded
            refits.run("page-d", "refit", lambda: "d")
        release.set()
        assert first.result(30) == "first" and later.result(30) == "b, moved on" and other.result(30) == "c"
        with pytest.raises(Cancelled):
            waiting.result(30)


def test_a_viewer_open_to_the_network_warns_and_asks_for_its_token(viewed):
    """--host 0.0.0.0: a warning, a URL with this machine's name and a token (never http://0.0.0.0), and every
    API call refused without that token, whatever Host it names."""
    import re
    import subprocess
    import sys

    process = subprocess.Popen([sys.executable, "-m", "pipeline.cli", "view", str(viewed.run), "--host", "0.0.0.0",
                                "--port", "0", "--no-browser"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        warning = process.stderr.readline()
        while "WARNING" not in warning and warning:
            warning = process.stderr.readline()
        line = process.stdout.readline()
        assert "WARNING: listening on 0.0.0.0" in warning and "token" in warning
        assert "0.0.0.0" not in line
        match = re.search(r"http://([^:/]+):(\d+)/\?token=([A-Za-z0-9_-]{20,})", line)
        assert match, line
        port, token = match.group(2), match.group(3)
        url = f"http://127.0.0.1:{port}/"
        assert _request(url, "GET", "/")[0] == 200  # the page itself holds no data
        for headers in ({}, {"X-Fwl-Token": "guess"}, {"Host": "evil.example"}):
            status, _, data = _request(url, "GET", "/api/catalog", headers=headers)
            assert status == 403 and "token" in data["error"]
        assert _request(url, "GET", "/api/catalog", headers={"X-Fwl-Token": token})[0] == 200
        assert _request(url, "GET", f"/api/catalog?token={token}", headers={"Host": "evil.example"})[0] == 200
        status, _, _ = _request(url, "POST", "/api/decompose", {"input": "0/x.las"})
        assert status == 403
    finally:
        process.terminate()
        process.wait(20)


def test_the_loopback_viewer_prints_its_address_and_needs_no_token(viewed):
    from pipeline.view.server import is_loopback

    assert is_loopback("127.0.0.1") and is_loopback("::1") and is_loopback("localhost")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.168.1.4")
    assert "token" not in viewed.url and viewed.get("/api/catalog")["runs"]


def test_a_connection_that_goes_silent_is_dropped(tmp_path):
    """A body shorter than its Content-Length: the thread waits REQUEST_TIMEOUT (here 1 s), then lets go."""
    import socket

    server = make_server([tmp_path], port=0, runs_dir=tmp_path / "runs")
    server.RequestHandlerClass.timeout = 1.0
    serve_in_thread(server)
    try:
        host, port = server.server_address[:2]
        with socket.create_connection((host, port), timeout=30) as s:
            s.sendall(b"POST /api/try HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
                      b"Content-Length: 100\r\n\r\n{")
            started = time.monotonic()
            assert s.recv(1024) == b""  # closed, no answer: nothing was asked in full
            assert time.monotonic() - started < 10
        assert _request(url_of(server), "GET", "/api/catalog")[0] == 200
    finally:
        server.shutdown()
        server.server_close()


def test_clients_that_hang_up_are_logged_once_quietly(tmp_path, capfd):
    import socket
    import struct

    server = make_server([tmp_path], port=0, runs_dir=tmp_path / "runs")
    serve_in_thread(server)
    try:
        host, port = server.server_address[:2]
        for _ in range(5):  # ask for plotly.min.js (megabytes), then reset the connection at once
            s = socket.create_connection((host, port), timeout=30)
            s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            s.sendall(b"GET /static/plotly.min.js HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            s.recv(1)
            s.close()
        time.sleep(1.0)
        assert _request(url_of(server), "GET", "/api/catalog")[0] == 200
    finally:
        server.shutdown()
        server.server_close()
    err = capfd.readouterr().err
    assert err.count("closed its connection before its answer") == 1 and "Traceback" not in err
