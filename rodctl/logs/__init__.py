"""Sinks for step records: MCAP (Foxglove), Rerun. The only package that imports mcap/rerun."""
