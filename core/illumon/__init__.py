"""illumon."""

from ._imports import defer_colour_plotting

defer_colour_plotting()
del defer_colour_plotting
