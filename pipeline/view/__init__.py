"""fwl view: a local, offline web viewer of runs and their pulses (see server.py for the endpoints)."""

from pipeline.view.server import make_server, url_of

__all__ = ["make_server", "url_of"]
