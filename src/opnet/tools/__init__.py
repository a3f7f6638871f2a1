"""The tools users run on their runs and checkpoints, each a console script and ``python -m
opnet.tools.<name>``: ``opnet-compare-runs`` (a sweep in the layout of Table I), ``opnet-tune-decoding``
(the decoding tuned on a validation split), ``opnet-record-trained-clip`` (the training clip planes
written into an older checkpoint), ``opnet-oracle`` (the parameterization ceiling),
``opnet-diagnose-sources`` (where a model's hypotheses come from)."""
