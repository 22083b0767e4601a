"""starterbus-canopen: a CANopen transport for starterbus, written only against starterbus's public API.

The object dictionary and PDO layout are a design in the spirit of CiA 442 (not CiA 442's own indices, which are
not public); see the package README for the table.
"""

__version__ = "0.1.0"
