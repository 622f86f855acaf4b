"""Run configuration: the processing settings and scenario files (world + installation + processing)."""
