"""The GNSS front end: RINEX, broadcast ephemeris, observation models, single-point positioning, RTKLIB peer."""
