import pkgutil
import subprocess
import sys

import fwcore


def test_fwcore_never_imports_apache_beam():
    modules = [m.name for m in pkgutil.walk_packages(fwcore.__path__, "fwcore.")]
    assert {"fwcore.engine", "fwcore.optimizers.evolution", "fwcore.io.reader"} <= set(modules)
    code = "import sys\n" + "".join(f"import {m}\n" for m in modules) + "print('apache_beam' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
