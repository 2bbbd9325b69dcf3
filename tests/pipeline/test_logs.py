"""Where a run's logs go: a worker's own lines to logs/worker-<host>-<pid>.log under each output folder it works
for; the driver's to logs/driver.log, with only our warnings and anyone's errors on the terminal."""

import logging
import os
import socket

from pipeline.logs import log_to_file, watched_logs


def _worker_handlers():
    return [h for h in logging.getLogger("fwl").handlers if getattr(h, "fwl_worker", None)]


def test_a_worker_logs_into_the_folder_it_works_for_once(tmp_path):
    logger = logging.getLogger("fwl")
    try:
        log_to_file(tmp_path / "one")
        log_to_file(tmp_path / "one")  # the same folder: the same handler, not a second
        assert len(_worker_handlers()) == 1
        logger.info("range done")
        log_to_file(tmp_path / "two")  # another folder (the driver's in-process jobs): its own file from now on
        logger.info("other range")
        for h in _worker_handlers():
            h.flush()
        name = f"worker-{socket.gethostname()}-{os.getpid()}.log"
        first, second = (tmp_path / "one" / "logs" / name).read_text(), (tmp_path / "two" / "logs" / name).read_text()
        assert "INFO fwl range done" in first and "other range" not in first
        assert "INFO fwl other range" in second and "range done" not in second
    finally:
        for h in _worker_handlers():
            logger.removeHandler(h)
            h.close()


def test_the_driver_s_log_takes_everything_the_terminal_only_ours_and_errors(tmp_path, capfd):
    with watched_logs(tmp_path, verbose=False) as (say, terminal):
        logging.getLogger("pipeline.run").warning("our warning")
        logging.getLogger("laspy").warning("a library's warning")
        logging.getLogger("laspy").error("a library's error")
        logging.getLogger("pipeline.run").info("our info")
        say.write("the start line\n")
    driver = (tmp_path / "logs" / "driver.log").read_text()
    assert all(m in driver for m in ("our warning", "a library's warning", "a library's error", "our info"))
    out, err = capfd.readouterr()
    assert out == "the start line\n"
    assert "our warning" in err and "a library's error" in err
    assert "a library's warning" not in err and "our info" not in err
