"""fwl view's server: the JSON endpoints the page calls, against the run's own Parquet tables, without a browser."""

import http.client
import json
from urllib.parse import urlsplit

import laspy
import numpy as np
import pytest


def test_picking_an_input_decomposed_it_in_the_background(viewed):
    first, last = viewed.job_states[0], viewed.job_states[-1]
    assert first["status"] == "running" and first["pulses"] == 924 and first["progress"] < 1
    during = [s["pulses_done"] for s in viewed.job_states if s["status"] == "running"]
    assert during == sorted(during) and all(0 <= d <= 90 for d in during)  # --limit 90
    assert last["status"] == "done" and last["progress"] == 1.0
    summary = json.loads((viewed.run / "run.json").read_text())
    assert summary["config"]["optimizer"] == "lm" and summary["limit"] == 90  # fwl run's config, the fast preset
    catalog = viewed.get("/api/catalog")
    (run,) = catalog["runs"]
    assert run["id"] == viewed.run_id and run["inputs"] == ["leica_a.las"]
    assert catalog["inputs"][0]["run"] == viewed.run_id  # the input now shows its run


def test_summary_counts_and_distributions_add_up(viewed):
    s = viewed.get(f"/api/summary?run={viewed.run_id}")
    echoes, pulses = viewed.echoes(), viewed.pulses()
    c = s["counts"]
    assert c["pulses_read"] == 90 == c["pulses_decomposed"] + c["pulses_rejected"] and s["read_adds_up"]
    assert c["echoes_kept"] == int(echoes.kept.sum()) and c["echoes_spurious"] == int((~echoes.kept).sum())
    d = s["distributions"]
    assert sum(d["echoes_per_pulse"]["counts"]) == len(pulses) == sum(d["kept_echoes_per_pulse"]["counts"])
    centres = np.array(d["echoes_per_pulse"]["edges"][:-1]) + 0.5
    assert np.dot(centres, d["echoes_per_pulse"]["counts"]) == len(echoes)
    assert sum(d["amplitude_kept"]["counts"]) == c["echoes_kept"]
    assert sum(d["amplitude_spurious"]["counts"]) == c["echoes_spurious"]
    assert s["bounds"]["echoes"] == len(echoes) and s["bounds"]["z"] == [echoes.z.min(), echoes.z.max()]
    assert s["rejected"]["total"] == c["pulses_rejected"] + c["files_rejected"]
    top = pulses.sort_values(["n_echoes", "gps_time"], ascending=[False, True]).iloc[0]
    assert s["first_pulse"] == ["leica_a.las", str(top.pulse_id)]  # ids as their digits


def test_echoes_in_a_box_are_the_tables_rows(viewed):
    echoes = viewed.echoes()
    everything = viewed.get(f"/api/echoes?run={viewed.run_id}&colour=amplitude&limit=200000")
    assert everything["total"] == len(echoes) == len(everything["x"])
    x0, x1 = np.percentile(echoes.x, [20, 70])
    y0, y1 = np.percentile(echoes.y, [10, 90])
    inside = echoes[echoes.x.between(x0, x1) & echoes.y.between(y0, y1)]
    some = viewed.get(f"/api/echoes?run={viewed.run_id}&colour=amplitude&box={x0},{x1},{y0},{y1}&limit=25")
    assert some["total"] == len(inside) > 25 and len(some["x"]) == 25
    again = viewed.get(f"/api/echoes?run={viewed.run_id}&colour=amplitude&box={x0},{x1},{y0},{y1}&limit=25")
    assert again["pulse_id"] == some["pulse_id"]  # the sample is deterministic
    for i in range(25):
        same = [np.isclose(inside[c], some[c][i], rtol=0, atol=6e-4) for c in ("x", "y", "z")]
        row = inside[(inside.pulse_id == int(some["pulse_id"][i])) & same[0] & same[1] & same[2]]
        assert len(row) == 1 and np.isclose(row.amplitude.iloc[0], some["value"][i], rtol=1e-6, atol=0)
        assert bool(row.kept.iloc[0]) == some["kept"][i]
    kept = viewed.get(f"/api/echoes?run={viewed.run_id}&colour=height&kept=1&limit=200000")
    assert kept["total"] == int(echoes.kept.sum()) and all(kept["kept"])
    assert np.allclose(sorted(kept["value"]), sorted(echoes.z[echoes.kept]))


def test_pulse_list_orders(viewed):
    listed = viewed.get(f"/api/pulses?run={viewed.run_id}&order=echoes&limit=10")["pulses"]
    counts = [p["n_echoes"] for p in listed]
    assert len(listed) == 10 and counts == sorted(counts, reverse=True)
    assert counts[0] == viewed.pulses().n_echoes.max()
    worst = viewed.get(f"/api/pulses?run={viewed.run_id}&order=fit_error&limit=3")["pulses"]
    assert worst[0]["r2"] == viewed.pulses().r2.min()


def _pulses_of_several_ranges(viewed):
    pulses = viewed.pulses().sort_values("gps_time")
    return [int(pulses.pulse_id.iloc[i]) for i in (0, len(pulses) // 2, len(pulses) - 1)]


@pytest.mark.parametrize("which", [0, 1, 2])
def test_a_pulse_is_re_read_and_its_decomposition_reproduced(viewed, which):
    pulse_id = _pulses_of_several_ranges(viewed)[which]
    echoes, pulses = viewed.echoes(), viewed.pulses()
    table = echoes[echoes.pulse_id == pulse_id].sort_values("echo_index")
    p = viewed.get(f"/api/pulse?run={viewed.run_id}&file=leica_a.las&pulse={pulse_id}")
    fit = p["fit"]
    assert p["reproduced"] and len(fit["echoes"]) == len(table) == len(p["echo_rows"])
    for got, want in zip(fit["echoes"], table.itertuples()):
        for name in ("amplitude", "time_ps", "sigma_chauve", "alpha", "fwhm_ps", "energy"):
            if got[name] is None:  # JSON's null: an echo of the system response has no sigma_chauve or alpha
                assert name in ("sigma_chauve", "alpha") and np.isnan(getattr(want, name)), name
                continue
            assert got[name] == pytest.approx(getattr(want, name), rel=1e-9, abs=1e-9), name
        assert got["kept"] == want.kept and got["reject_reason"] == want.reject_reason
    row = pulses[pulses.pulse_id == pulse_id].iloc[0]
    assert fit["rmse"] == pytest.approx(row.rmse, rel=1e-9) and fit["r2"] == pytest.approx(row.r2, rel=1e-9)
    assert len(fit["raw"]) == row.n_samples == len(fit["denoised"])
    assert len(p["system_returns"]) == row.n_system_returns
    # the raw samples are the packet's, read independently with laspy and numpy
    las = laspy.read(viewed.folder / "inputs" / "leica_a.las")
    gps = np.asarray(las.gps_time)
    (point,) = np.flatnonzero((gps == row.gps_time) & (np.asarray(las.return_number) == 1))[:1]
    offset, size = int(las.wavepacket_offset[point]), int(las.wavepacket_size[point])
    packets = np.fromfile(viewed.folder / "inputs" / "leica_a.wdp", dtype=np.uint8)
    assert fit["raw"] == packets[offset:offset + size].astype(float).tolist()
    # each component is the background plus one echo: together they are the model
    components = np.sum([np.array(e["curve"]) - fit["background"] for e in fit["echoes"]], axis=0)
    assert np.allclose(components + fit["background"], fit["model"], atol=1e-4)


def test_try_refits_with_another_method_side_by_side(viewed):
    pulse_id = _pulses_of_several_ranges(viewed)[1]
    body = {"run": viewed.run_id, "file": "leica_a.las", "pulse": pulse_id, "preset": "paper",
            "changes": {"optimizer": "mde", "min_snr": 8, "generations": 30}}
    t = viewed.post("/api/try", body)
    assert t["a"]["config"]["optimizer"] == "lm" and t["b"]["config"]["optimizer"] == "mde"
    assert t["changed"]["min_snr"] == 8 and t["changed"]["generations"] == 30
    echoes = viewed.echoes()
    assert len(t["a"]["echoes"]) == int((echoes.pulse_id == pulse_id).sum())
    # the run's pulse width stays: only what was asked changes
    assert t["b"]["pulse"]["fwhm_ps"] == t["a"]["pulse"]["fwhm_ps"] is not None
    weak = [e for e in t["b"]["echoes"] if e["amplitude"] < 8 * t["b"]["noise_sigma"]]
    assert all(not e["kept"] for e in weak)
    # a preset is the preset's method (as fwl run --preset has it), on the run's pulse width and seed
    paper = viewed.post("/api/try", {**body, "changes": {}})
    # the run was `fast` (LM, 20 iterations): paper is MDE at G 80 with the method's noise, filter and no selection;
    # the model stays the run's (a preset changes the method only)
    from fwcore.engine.config import PRESETS
    fast, published = PRESETS["fast"].config().to_dict(), PRESETS["paper"].config().to_dict()
    expected = {k: v for k, v in published.items() if fast[k] != v and k not in ("shape_tolerance", "model")}
    assert {k: v for k, v in paper["changed"].items() if k != "shape_tolerance"} == expected
    assert expected["optimizer"] == "mde" and expected["generations"] == 80 and not expected["select_echoes"]
    assert paper["b"]["config"]["model"] == paper["a"]["config"]["model"]
    same = viewed.post("/api/try", {**body, "preset": "", "changes": {}})
    assert same["changed"] == {} and same["a"]["echoes"] == same["b"]["echoes"]


def _status(viewed, method, path, body=None, headers=None):
    """A raw request: the path goes out exactly as written, no client-side normalisation."""
    url = urlsplit(viewed.url)
    con = http.client.HTTPConnection(url.hostname, url.port, timeout=60)
    con.request(method, path, body=json.dumps(body) if body is not None else None,
                headers={"Content-Type": "application/json", **(headers or {})})
    response = con.getresponse()
    data = response.read()
    con.close()
    return response.status, data


@pytest.mark.parametrize("path", [
    "/api/summary?run=0/../..", "/api/summary?run=0/%2e%2e/%2e%2e/etc", "/api/summary?run=0//etc",
    "/api/summary?run=9/", "/api/summary?run=f0", "/api/summary?run=0/runs/leica_a/../../../..",
    "/api/pulse?run=0/../../../&file=leica_a.las&pulse=1", "/api/echoes?run=..",
])
def test_a_path_outside_the_folders_is_refused(viewed, path):
    status, data = _status(viewed, "GET", path)
    assert status == 403 and "error" in json.loads(data)


@pytest.mark.parametrize("path", ["/static/../../catalog.py", "/static/%2e%2e/server.py", "/static/..%2fserver.py",
                                  "/static/%2e%2e/%2e%2e/%2e%2e/pyproject.toml", "/../pyproject.toml"])
def test_a_static_path_outside_the_page_is_refused(viewed, path):
    status, data = _status(viewed, "GET", path)
    assert status in (403, 404) and b"import" not in data and b"[project]" not in data


def test_decompose_outside_the_folders_is_refused(viewed):
    status, _ = _status(viewed, "POST", "/api/decompose", {"input": "0/../../leica_a.las"})
    assert status == 403
    status, _ = _status(viewed, "POST", "/api/decompose", {"input": "0/runs/leica_a/run.json"})
    assert status == 404


def test_another_sites_requests_are_refused(viewed):
    # a page whose name was rebound to 127.0.0.1 sends its own host name
    status, _ = _status(viewed, "GET", f"/api/summary?run={viewed.run_id}", headers={"Host": "evil.example:80"})
    assert status == 403
    assert _status(viewed, "GET", f"/api/summary?run={viewed.run_id}",
                   headers={"Host": f"localhost:{urlsplit(viewed.url).port}"})[0] == 200
    # a cross-site form can post text/plain without asking first; the viewer takes JSON only
    status, _ = _status(viewed, "POST", "/api/decompose", {"input": viewed.input_id}, {"Content-Type": "text/plain"})
    assert status == 415


def test_bad_requests_say_why(viewed):
    status, data = _status(viewed, "GET", f"/api/echoes?run={viewed.run_id}&colour=rainbow")
    assert status == 400 and b"colour must be one of" in data
    status, data = _status(viewed, "POST", "/api/try", {"run": viewed.run_id, "file": "leica_a.las", "pulse": 0,
                                                        "changes": {"population": 2}})
    assert status in (400, 404)
    pulse_id = _pulses_of_several_ranges(viewed)[0]
    status, data = _status(viewed, "POST", "/api/try", {"run": viewed.run_id, "file": "leica_a.las",
                                                        "pulse": pulse_id, "changes": {"population": 2}})
    assert status == 400 and b"population" in data


def test_the_page_and_plotly_are_served_from_the_package(viewed):
    status, page = _status(viewed, "GET", "/")
    assert status == 200 and b"/static/plotly.min.js" in page and b"http" not in page.split(b"<body>")[0]
    status, js = _status(viewed, "GET", "/static/plotly.min.js")
    assert status == 200 and len(js) > 1_000_000


def test_system_returns_overlay_are_the_input_points(viewed):
    las = laspy.read(viewed.folder / "inputs" / "leica_a.las")
    pulses = viewed.pulses()
    gps = np.asarray(las.gps_time)
    inside = (gps >= pulses.gps_time.min()) & (gps <= pulses.gps_time.max())
    r = viewed.get(f"/api/returns?run={viewed.run_id}&limit=200000")
    assert r["total"] == int(inside.sum()) == int(pulses.n_system_returns.sum())
    assert np.allclose(sorted(r["z"]), sorted(np.asarray(las.z)[inside]))


def test_fwl_view_names_a_missing_folder(tmp_path, capsys):
    from pipeline.cli import main

    assert main(["view", str(tmp_path / "nowhere"), "--no-browser", "--port", "0"]) == 2
    assert "nowhere: no such file or folder" in capsys.readouterr().err


def test_a_partial_run_shows_its_rejected_pulses_with_reasons(tmp_path, leica_dir):
    """An input whose packet file lost its end: the run is partial (fwl run exits non-zero) and shown."""
    import shutil

    import pyarrow.dataset as ds

    from pipeline.view.jobs import Jobs
    from pipeline.view.server import make_server, serve_in_thread, url_of
    from tests.pipeline.view.conftest import POINTS_PER_RANGE, RUN_ARGS, Viewed

    shutil.copy(leica_dir / "leica_a.las", tmp_path / "cut.las")
    wdp = (leica_dir / "leica_a.wdp").read_bytes()
    (tmp_path / "cut.wdp").write_bytes(wdp[: 92 + 256 * 40])  # the header and 40 packets
    runs = tmp_path / "runs"
    server = make_server([tmp_path], port=0, runs_dir=runs, jobs=Jobs(runs, RUN_ARGS, POINTS_PER_RANGE))
    serve_in_thread(server)
    try:
        v = Viewed(url_of(server), tmp_path, runs / "cut", "", "", [])
        (listed,) = v.get("/api/catalog")["inputs"]
        listed = v.decompose(listed["id"])
        assert listed["job"]["status"] == "done", (runs / "cut.log").read_text()
        s = v.get(f"/api/summary?run={listed['run']}")
        c = s["counts"]
        assert s["status"] == "partial" and s["read_adds_up"]
        assert c["pulses_rejected"] > 0 and c["pulses_decomposed"] > 0
        rejected = ds.dataset(str(runs / "cut" / "rejected"), format="parquet").to_table().to_pandas()
        assert s["rejected"]["total"] == len(rejected) == c["pulses_rejected"]
        assert sorted(int(r["pulse_id"]) for r in s["rejected"]["rows"]) == sorted(rejected.pulse_id)
        (kind,) = s["rejected"]["reasons"]  # one kind of failure, the offsets and sizes as N
        assert kind["count"] == len(rejected) and "beyond the end of cut.wdp" in kind["reason"]
        assert "N" in kind["reason"] and not any(ch.isdigit() for ch in kind["reason"])
        assert all(r["stage"] == "read" and "cut.wdp" in r["reason"] for r in s["rejected"]["rows"])
    finally:
        server.shutdown()
        server.server_close()


@pytest.mark.parametrize("stem, model", [("las13fwf_example1", "generalized"), ("riegl_example3", "system")])
def test_a_pulsewaves_input_is_decomposed_and_its_pulses_reproduced(tmp_path, stem, model):
    """A .pls+.wvs input, picked in the viewer: its pulses come back from the PulseWaves reader, refitted with
    the response the run measured on the file where echoes take its shape."""
    import shutil
    from pathlib import Path

    from pipeline.view.jobs import Jobs
    from pipeline.view.server import make_server, serve_in_thread, url_of
    from tests.pipeline.view.conftest import Viewed, run_args

    samples = Path(__file__).resolve().parents[3] / "examples" / "data" / "pulsewaves"
    for suffix in (".pls", ".wvs"):
        shutil.copy(samples / f"{stem}{suffix}", tmp_path / f"{stem}{suffix}")
    runs = tmp_path / "runs"
    server = make_server([tmp_path], port=0, runs_dir=runs, jobs=Jobs(runs, run_args(20) + ["--model", model], 10))
    serve_in_thread(server)
    try:
        v = Viewed(url_of(server), tmp_path, runs / stem, "", "", [])
        (listed,) = v.get("/api/catalog")["inputs"]
        assert listed["name"] == f"{stem}.pls" and listed["run"] is None
        listed = v.decompose(listed["id"])
        assert listed["job"]["status"] == "done", (runs / f"{stem}.log").read_text()
        echoes, pulses = v.echoes(), v.pulses()
        assert len(pulses) == 20
        for pulse_id in pulses.sort_values("gps_time").pulse_id.iloc[[0, -1]]:
            p = v.get(f"/api/pulse?run={listed['run']}&file={stem}.pls&pulse={int(pulse_id)}")
            assert p["reproduced"] and len(p["fit"]["echoes"]) == int((echoes.pulse_id == pulse_id).sum())
            assert p["fit"]["config"]["model"] == model
            assert (p["fit"]["pulse"]["response"] is not None) == (model == "system")
            # the page can draw the response the echoes are made of, at the strongest echo
            assert (p["fit"]["response"] is not None) == (model == "system")
        if stem == "riegl_example3":  # EPSG:4978: the map is east, north, up about the run's centre, as PROJ has it
            import pyproj

            served = v.get(f"/api/echoes?run={listed['run']}&colour=height&limit=200000")
            centre = [float(echoes[c].min() + echoes[c].max()) / 2 for c in ("x", "y", "z")]
            enu = pyproj.Transformer.from_pipeline(
                f"+proj=topocentric +X_0={centre[0]!r} +Y_0={centre[1]!r} +Z_0={centre[2]!r} +ellps=WGS84")
            rows = echoes.set_index(["pulse_id", "echo_index"])
            for i in range(0, len(served["x"]), 7):
                match = echoes[(echoes.pulse_id == int(served["pulse_id"][i]))]
                e, n, u = enu.transform(match.x.to_numpy(), match.y.to_numpy(), match.z.to_numpy())
                d = (e - served["x"][i]) ** 2 + (n - served["y"][i]) ** 2 + (u - served["z"][i]) ** 2
                assert d.min() < 2e-6, (i, d.min())  # millimetres, as served
            assert served["frame"]["labels"][0] == "east (m) from the run's centre" and len(rows)
            assert max(abs(np.array(served["x"]))) < 5000 and "EPSG:4978" in served["frame"]["crs"]
    finally:
        server.viewer.jobs.stop_all()
        server.shutdown()
        server.server_close()


def test_fwl_view_says_when_its_port_is_taken(viewed, capsys):
    from pipeline.cli import main

    port = urlsplit(viewed.url).port
    assert main(["view", str(viewed.run), "--no-browser", "--port", str(port)]) == 2
    assert f"cannot listen on 127.0.0.1:{port}" in capsys.readouterr().err


def test_a_gedi_shot_is_reproduced_with_its_ground_and_rh_markers(tmp_path):
    """A GEDI L1B granule picked in the viewer (its L2A beside it is not offered): a shot's refit reproduces the run
    (the same noise floor and signal window), its shot number comes back exact (beyond JavaScript's 2^53), and the
    page gets its ground and RH markers at the heights the run measured."""
    import shutil
    from pathlib import Path

    from pipeline.view.jobs import Jobs
    from pipeline.view.server import make_server, serve_in_thread, url_of
    from tests.pipeline.view.conftest import Viewed

    gedi = Path(__file__).resolve().parents[3] / "examples" / "data" / "gedi"
    for name in ("GEDI01_B_2019108080338_O01964_T05337_02_003_01_sub.h5",
                 "GEDI02_A_2019108080338_O01964_T05337_02_001_01_sub.h5"):
        shutil.copy(gedi / name, tmp_path / name)
    runs = tmp_path / "runs"
    args = ["--limit", "12", "--optimizer", "lm", "--formats", "parquet", "--direct_num_workers=1",
            "--direct_running_mode=in_memory"]
    server = make_server([tmp_path], port=0, runs_dir=runs, jobs=Jobs(runs, args, 10))
    serve_in_thread(server)
    try:
        v = Viewed(url_of(server), tmp_path, runs / "GEDI01_B_2019108080338_O01964_T05337_02_003_01_sub", "", "", [])
        (listed,) = v.get("/api/catalog")["inputs"]
        assert listed["name"].startswith("GEDI01_B_")
        listed = v.decompose(listed["id"])
        assert listed["job"]["status"] == "done"
        pulses = v.pulses()
        shot = int(pulses.pulse_id.iloc[0])
        p = v.get(f"/api/pulse?run={listed['run']}&file={listed['name']}&pulse={shot}")
        assert p["reproduced"] and int(p["pulse_id"]) == shot and shot > 2**53
        forest = p["forest"]
        row = pulses.set_index("pulse_id").loc[shot]
        heights = {m["k"]: m["height_m"] for m in forest["rh"]}
        assert heights[98] == pytest.approx(float(row.rh[98]), abs=1e-5)
        # the ground marker lies on the waveform, at the lowest mode, below RH98's marker in time order
        assert 0 < forest["rh"][-1]["time_ps"] < forest["ground_time_ps"] < p["fit"]["time_ps"][-1]
    finally:
        server.shutdown()
        server.server_close()


def test_a_gedi_runs_ids_come_as_their_digits_and_its_map_in_metres(gedi_viewed):
    """Every identity the server sends is a string of its exact digits (shot numbers lie beyond 2^53, where a
    JSON number read by a page rounds: 19640119700108618 -> ...616); an id is parsed back to int64 exactly."""
    from urllib.parse import quote

    from tests.pipeline.view.conftest import GEDI_L1B

    run = quote(gedi_viewed.run_id, safe="")
    shots = {int(s) for s in gedi_viewed.pulses().pulse_id}
    rounded = sorted(s for s in shots if int(float(s)) != s)
    assert rounded  # the test's point: ids a float64 turns into other numbers
    served = gedi_viewed.get(f"/api/echoes?run={run}&colour=height&limit=200000")
    assert all(isinstance(p, str) for p in served["pulse_id"]) and {int(p) for p in served["pulse_id"]} <= shots
    listed = gedi_viewed.get(f"/api/pulses?run={run}&order=echoes&limit=1000")["pulses"]
    assert sorted(int(p["pulse_id"]) for p in listed) == sorted(shots)
    assert all(p["pulse_id"] == str(int(p["pulse_id"])) for p in listed)
    summary = gedi_viewed.get(f"/api/summary?run={run}")
    assert isinstance(summary["first_pulse"][1], str) and int(summary["first_pulse"][1]) in shots
    shot = rounded[0]
    p = gedi_viewed.get(f"/api/pulse?run={run}&file={GEDI_L1B}&pulse=000{shot}")  # leading zeros: the same id
    assert p["pulse_id"] == p["pulse"]["pulse_id"] == str(shot) and p["reproduced"]
    assert {r["pulse_id"] for r in p["echo_rows"]} == {str(shot)}
    # EPSG:4979 drawn in metres about the run's centre: the granule's 0.03 degrees are some 3.3 km
    assert summary["frame"]["labels"][:2] == ["east (m) from the run's centre", "north (m) from the run's centre"]
    b = summary["bounds"]
    assert 500 < b["x"][1] - b["x"][0] < 4000 and 500 < b["y"][1] - b["y"][0] < 4000
    echoes = gedi_viewed.echoes()
    assert b["z"] == [echoes.z.min(), echoes.z.max()]  # heights as they are


def test_a_gedi_shot_comes_with_its_algorithm_modes_and_biomass(gedi_products, viewed):
    """With the products' columns in pulses/ (conftest.add_products): the shot's algorithm and agbd as written, its
    modes placed on the waveform by the L1B's own elevations, those below the ground passed over; a LAS run
    without them has no shot details."""
    import h5py
    from urllib.parse import quote

    from tests.pipeline.view.conftest import GEDI, GEDI_L1B, PASSED_OVER_DROPS_M

    pulses = gedi_products.pulses()
    row = pulses[pulses.agbd.notna()].iloc[-1]
    shot = int(row.pulse_id)
    p = gedi_products.get(f"/api/pulse?run={quote(gedi_products.run_id, safe='')}&file={GEDI_L1B}&pulse={shot}")
    assert p["shot"] == {"shot_number": str(shot), "selected_algorithm": 2 if shot % 2 == 0 else 1,
                         "agbd": pytest.approx(float(row.agbd)), "agbd_se": pytest.approx(float(row.agbd_se)),
                         "agbd_stratum": "GSW_SAm", "top_z": pytest.approx(float(row.top_z))}
    with h5py.File(GEDI / GEDI_L1B) as f:
        for beam in (k for k in f if k.startswith("BEAM")):
            hit = np.flatnonzero(f[beam]["shot_number"][:].astype(np.int64) == shot)
            if hit.size:
                geo, i = f[beam]["geolocation"], hit[0]
                drop = (geo["elevation_bin0"][i] - geo["elevation_lastbin"][i]) / (f[beam]["rx_sample_count"][i] - 1)
    modes = p["forest"]["modes"]
    assert [m["passed_over"] for m in modes] == [False, False, True, True]
    ground_ps = p["forest"]["ground_time_ps"]
    for m, below in zip(modes[2:], PASSED_OVER_DROPS_M):  # 1 ns a sample, `drop` metres lower each
        assert m["time_ps"] - ground_ps == pytest.approx(below / drop * 1000.0, abs=0.5)
    null = pulses[pulses.agbd.isna()]
    if len(null):  # RH98 at or below the ground: no biomass, and why
        q = gedi_products.get(f"/api/pulse?run={quote(gedi_products.run_id, safe='')}&file={GEDI_L1B}"
                              f"&pulse={int(null.pulse_id.iloc[0])}")
        assert q["shot"]["agbd"] is None and q["shot"]["agbd_reason"] == "RH98 at or below the ground"
    leica = int(viewed.pulses().pulse_id.iloc[0])
    assert viewed.get(f"/api/pulse?run={viewed.run_id}&file=leica_a.las&pulse={leica}")["shot"] is None
