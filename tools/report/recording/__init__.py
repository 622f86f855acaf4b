"""The rerun recording (.rrd) of a run, in one convention for every chain (convention.py)."""
