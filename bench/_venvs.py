"""Side virtual environments for benches that compare bgc with other libraries.

Some reference libraries cannot live in the project's .venv: ``particles``
(N. Chopin's SMC library) pins numpy < 2, numba follows its own numpy range.
:func:`ensure_venv` makes bench/.venvs/<name> with pip the first time it is
asked for and reuses it while its import probe passes; a bench then runs its
code there in a subprocess. Delete a venv's folder to rebuild it.

Used by bench/filter_speed.py and bench/calibrate_particle_check.py.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parent
ROOT = BENCH.parent
VENVS = BENCH / ".venvs"
#: name -> (pip requirements, import probe)
VENV_SPECS = {
    "numba": (["numba"], "import numba, numpy"),
    "particles": (["particles", "numpy<2"], "import particles, numpy; assert numpy.__version__ < '2'"),
}


def progress(message: str) -> None:
    """A line on stderr, at once (stdout is the bench's table)."""
    print(message, file=sys.stderr, flush=True)


def ensure_venv(name: str) -> tuple[str | None, str]:
    """The python of bench/.venvs/<name>, created and filled with pip when missing; (None, why) on failure."""
    requirements, probe = VENV_SPECS[name]
    home = VENVS / name
    python = home / "bin" / "python"
    if python.exists() and subprocess.run([str(python), "-c", probe], capture_output=True).returncode == 0:
        return str(python), "reused"
    progress(f"creating {home.relative_to(ROOT)}: pip install {' '.join(requirements)} (needs PyPI) ...")
    steps = [[sys.executable, "-m", "venv", "--clear", str(home)],
             [str(python), "-m", "pip", "install", "--quiet", "--disable-pip-version-check", *requirements],
             [str(python), "-c", probe]]
    for cmd in steps:
        try:
            done = subprocess.run(cmd, capture_output=True, text=True, timeout=1800)
        except (OSError, subprocess.TimeoutExpired) as exc:
            return None, f"{' '.join(cmd[:4])}: {exc}"
        if done.returncode != 0:
            tail = (done.stderr or done.stdout).strip().splitlines()[-3:]
            return None, f"{' '.join(cmd[:4])} failed: " + " | ".join(tail)
    return str(python), "created"
