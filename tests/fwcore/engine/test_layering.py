"""The engine's floor: importing any fwcore.engine module loads nothing of the instrument's measuring code
(fwcore.instrument.measure, fwcore.instrument.width), which runs the engine and so sits a floor above it."""

import json
import pkgutil
import subprocess
import sys

import fwcore.engine

ABOVE_THE_ENGINE = ("fwcore.instrument.measure", "fwcore.instrument.width")


def test_no_engine_module_loads_the_instruments_measuring_code():
    modules = [m.name for m in pkgutil.walk_packages(fwcore.engine.__path__, "fwcore.engine.")]
    assert {"fwcore.engine.decompose", "fwcore.engine.model", "fwcore.engine.records",
            "fwcore.engine.optimizers.local"} <= set(modules)
    code = ("import sys\n" + "".join(f"import {m}\n" for m in modules)
            + "import json\nprint(json.dumps(sorted(k for k in sys.modules if k.startswith('fwcore.instrument'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    loaded = json.loads(out.stdout)
    assert "fwcore.instrument.pulse" in loaded  # the engine does take the file's pulse (the data below it)
    assert not set(ABOVE_THE_ENGINE) & set(loaded), loaded
