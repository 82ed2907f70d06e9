"""scripts/quiet.sh: the matching jobs are stopped while the command runs, and resumed after it,
also when the command fails."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "quiet.sh"


def _state(pid: int) -> str:
    return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize("exit_code", [0, 3])
def test_jobs_are_paused_during_the_command_and_resumed_after(exit_code: int) -> None:
    marker = f"quiet-test-job-{exit_code}"
    job = subprocess.Popen(["bash", "-c", f"exec -a {marker} sleep 60"])
    try:
        check = f'grep -q "^State:.*T" /proc/{job.pid}/status && echo stopped; exit {exit_code}'
        done = subprocess.run(
            ["bash", str(SCRIPT), "bash", "-c", check],
            env={"QUIET_PATTERN": marker, "PATH": "/usr/bin:/bin"},
            capture_output=True,
            text=True,
            timeout=30,
        )
        assert done.returncode == exit_code
        assert done.stdout.strip() == "stopped"  # the job was stopped while the command ran
        assert "paused 1 process" in done.stderr
        assert _state(job.pid) in {"S", "R"}  # and runs again afterwards
    finally:
        job.kill()
        job.wait()
