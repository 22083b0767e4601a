"""The profibus-pkw transport plugin."""
