"""File input and output that every layer uses: atomic writes that name a full disk
(:mod:`opnet.fileio.atomic`) and reads that refuse special files and non-finite JSON
(:mod:`opnet.fileio.files`). Imports nothing of opnet, so any package may use it."""
