"""The Click command line: option parsing and printing only (``cdgps`` = :func:`main`)."""
