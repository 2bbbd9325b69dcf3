"""A DirectRunner worker ends without the interpreter's teardown, with the exit code it would have had; no other
process is touched."""

import os
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _exit_of(body: str, tmp_path, worker: bool) -> tuple[int, str, bool]:
    script = tmp_path / "sdk_worker_main.py"  # the name Beam's worker module runs under
    log = tmp_path / "worker.log"
    script.write_text(textwrap.dedent(f"""
        import logging, sys
        sys.path.insert(0, {str(ROOT)!r})
        from pipeline.worker_exit import leave_quickly_at_exit
        handler = logging.FileHandler({str(log)!r})
        handler.stream.reconfigure(write_through=False)
        logging.getLogger("fwl").addHandler(handler)
        logging.getLogger("fwl").setLevel(logging.INFO)
        import atexit  # the interpreter's teardown, registered before: a worker leaves without it
        atexit.register(lambda: open(sys.argv[0] + ".teardown", "w").write("ran"))
        registered = leave_quickly_at_exit()
        logging.getLogger("fwl").info("registered %s", registered)
    """) + textwrap.dedent(body))
    env = {k: v for k, v in os.environ.items() if k != "CONTROL_API_SERVICE_DESCRIPTOR"}
    if worker:
        env["CONTROL_API_SERVICE_DESCRIPTOR"] = "url: 'localhost:1'"
    done = subprocess.run([sys.executable, str(script)], env=env, capture_output=True, text=True)
    return done.returncode, log.read_text(), script.with_name(script.name + ".teardown").exists()


def test_a_worker_leaves_at_once_with_its_logs_flushed_and_its_exit_code(tmp_path):
    code, log, teardown = _exit_of("logging.getLogger('fwl').info('last line')", tmp_path, worker=True)
    assert code == 0 and "registered True" in log and "last line" in log and not teardown
    code, log, teardown = _exit_of("raise RuntimeError('the harness failed')", tmp_path, worker=True)
    assert code == 1 and "registered True" in log and not teardown


def test_any_other_process_keeps_its_exit(tmp_path):
    code, log, teardown = _exit_of("sys.exit(3)", tmp_path, worker=False)
    assert code == 3 and "registered False" in log and teardown


def test_a_command_leaves_now_with_its_code_and_its_output_flushed(tmp_path):
    code, log, teardown = _exit_of("""
        from pipeline.worker_exit import leave_now
        logging.getLogger('fwl').info('done')
        sys.stdout = open(sys.argv[0] + ".out", "w")  # a file: buffered until flushed
        print('said', end='')
        leave_now(3)
    """, tmp_path, worker=False)
    assert code == 3 and "done" in log and not teardown
    assert (tmp_path / "sdk_worker_main.py.out").read_text() == "said"
