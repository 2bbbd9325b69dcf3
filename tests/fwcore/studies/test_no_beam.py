import pkgutil
import subprocess
import sys

import fwcore.studies


def test_studies_never_import_apache_beam():
    modules = [f"fwcore.studies.{m.name}" for m in pkgutil.iter_modules(fwcore.studies.__path__)]
    assert {"fwcore.studies.comparison", "fwcore.studies.evaluate", "fwcore.studies.simulate", "fwcore.studies.truth"} <= set(modules)
    code = "import sys\n" + "".join(f"import {m}\n" for m in modules) + "print('apache_beam' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
