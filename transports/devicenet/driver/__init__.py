"""Where DeviceNet meets the medium: the master engine run on a python-can bus (the scanner), frames <-> messages."""
