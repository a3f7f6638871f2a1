"""Moved to ``opnet-tune-decoding`` (:mod:`opnet.tools.tune_decoding`)."""

from opnet.tools.tune_decoding import RecordedSplit, search  # noqa: F401
