"""Operator workflows: parameter backup, diff and restore; history and events in SQLite; recording a start.

Every write goes through the core's guarded path (:mod:`starterbus.core.guarded`); nothing here talks to a
protocol directly.
"""
