import pkgutil
import subprocess
import sys

import fwcore
import fwcore.io


def test_fwcore_never_imports_apache_beam():
    modules = [m.name for m in pkgutil.walk_packages(fwcore.__path__, "fwcore.")]
    assert {"fwcore.engine.decompose", "fwcore.engine.optimizers.evolution", "fwcore.io.las", "fwcore.instrument.measure",
            "fwcore.radiometry.flight", "fwcore.studies.simulate"} <= set(modules)
    code = "import sys\n" + "".join(f"import {m}\n" for m in modules) + "print('apache_beam' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_fwcore_io_reads_formats_without_the_engine():
    modules = [m.name for m in pkgutil.walk_packages(fwcore.io.__path__, "fwcore.io.")]
    assert {"fwcore.io.las", "fwcore.io.pulsewaves", "fwcore.io.neon", "fwcore.io.info"} <= set(modules)
    code = ("import sys\n" + "".join(f"import {m}\n" for m in modules)
            + "print(sorted(k for k in sys.modules if k.startswith('fwcore.') and not k.startswith('fwcore.io')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "['fwcore._jit']"  # numba's flags, nothing of the engine
