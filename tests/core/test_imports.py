"""Start-up: colour-science's plotting (and matplotlib) is imported only when something uses it."""

from __future__ import annotations

import subprocess
import sys

SCRIPT = """
import sys
import illumon.model, illumon.cli  # what the CLI, the service's refit and every Dask worker import
heavy = [m for m in ("matplotlib", "matplotlib.pyplot", "scipy.signal", "scipy.stats") if m in sys.modules]
import colour
print("before:", ",".join(heavy) or "-")
from colour.plotting import plot_single_sd  # the real sub-package, on first use
print("after:", callable(plot_single_sd), callable(colour.plotting.plot_multi_sds), "matplotlib" in sys.modules,
      type(sys.modules["colour.plotting"]).__name__)
"""


def test_colour_plotting_waits_until_it_is_used():
    """``import colour`` imports matplotlib.pyplot when matplotlib is installed (~0.35 s a process); illumon defers it
    (:mod:`illumon._imports`), and the lamp lattice no longer needs ``scipy.signal`` / ``scipy.stats`` (~0.3 s)."""
    out = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, check=True).stdout.split("\n")
    assert out[0] == "before: -", out
    assert out[1] == "after: True True True module", out
