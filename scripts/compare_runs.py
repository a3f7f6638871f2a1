"""Moved to ``opnet-compare-runs`` (:mod:`opnet.tools.compare_runs`, :mod:`opnet.studies.sweeps`)."""

from opnet.studies import mean_sd  # noqa: F401
from opnet.studies.sweeps import PAPER_ORDER, cell_text, collect, table  # noqa: F401
