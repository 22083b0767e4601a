"""Transport plugins shipped with starterbus (each registered through entry points like any third-party one)."""
