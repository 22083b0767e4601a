"""The devicenet transport plugin."""
