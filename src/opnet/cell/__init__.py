"""A cell set up from its own depth frames, no ground truth: the planes (:mod:`~opnet.cell.planes`), the bin in a
frame (:mod:`~opnet.cell.bin_view`), the generator's terms (:mod:`~opnet.cell.rig`), the cell over its frames
(:mod:`~opnet.cell.estimate`), its file and picture (:mod:`~opnet.cell.cellfile`, :mod:`~opnet.cell.figure`) and
the sim-versus-real check (:mod:`~opnet.cell.check`, :mod:`~opnet.cell.check_report`). The command line is
``opnet-cell`` (:mod:`opnet.cli.cell`)."""
