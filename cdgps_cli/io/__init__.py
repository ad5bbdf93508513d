"""Files at the edge: atomic writes, MCAP, logs, RINEX, UBX, RUN, STATES, INIT and other records."""
