"""Start-up: colour-science without its plotting sub-package until something asks for it.

``import colour`` (0.4) imports ``colour.plotting`` whenever matplotlib is installed, and with it ``matplotlib.pyplot``:
~0.35 s of every process's start (the CLI, the service, each Dask worker of a fleet refit) for figures illumon draws
with matplotlib directly (:mod:`illumon.reports`). :func:`defer_colour_plotting` puts a stand-in for
``colour.plotting`` in ``sys.modules`` before colour is imported; the first attribute anyone reads from it imports
the real sub-package and rebinds ``colour.plotting``, so ``colour.plotting.plot_single_sd`` and ``from
colour.plotting import …`` work as before, a moment later.
"""

from __future__ import annotations

import importlib
import sys
import threading
import types

__all__ = ["defer_colour_plotting"]

_NAME = "colour.plotting"
_LOCK = threading.Lock()


class _DeferredPlotting(types.ModuleType):
    """Stands in for ``colour.plotting`` until an attribute is read from it."""

    def __getattr__(self, name: str) -> object:
        return getattr(_load_real(self), name)

    def __dir__(self) -> list[str]:
        return dir(_load_real(self))


def _load_real(stand_in: types.ModuleType) -> types.ModuleType:
    with _LOCK:
        if sys.modules.get(_NAME) is stand_in:
            del sys.modules[_NAME]
        real = importlib.import_module(_NAME)
        parent = sys.modules.get("colour")
        if parent is not None and getattr(parent, "plotting", None) is stand_in:
            parent.plotting = real
    return real


def defer_colour_plotting() -> None:
    """Install the stand-in, unless colour (or its plotting) is already imported."""
    if "colour" in sys.modules or _NAME in sys.modules:
        return
    sys.modules[_NAME] = _DeferredPlotting(_NAME, "colour.plotting, imported on first use (illumon._imports)")
