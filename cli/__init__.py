"""The ``starterbus`` command line."""
