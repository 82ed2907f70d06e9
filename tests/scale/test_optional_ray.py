"""Ray stays optional: the service and the CLI's start-up never import it."""

from __future__ import annotations

import subprocess
import sys


def test_service_and_cli_do_not_import_ray() -> None:
    code = (
        "import sys, itnet.service.app, itnet.service.server, itnet.cli\n"
        "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('ray', 'pyarrow'))\n"
        "print(bad)\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "[]"
