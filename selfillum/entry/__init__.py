"""A wind-tunnel entry processed: many datapoints, each calibrated from the tunnel, its
unsteady run, its Kulites compared (``selfillum entry``, docs/entry.md)."""
