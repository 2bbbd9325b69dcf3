import pkgutil
import subprocess
import sys

import fwcore


def test_fwcore_never_imports_apache_beam():
    modules = [f"fwcore.{m.name}" for m in pkgutil.iter_modules(fwcore.__path__)]
    assert "fwcore.decompose" in modules
    code = "import sys\n" + "".join(f"import {m}\n" for m in modules) + "print('apache_beam' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
