"""Fleets: many soft starters on many buses, polled together; the demo fleet; cross-checks."""
