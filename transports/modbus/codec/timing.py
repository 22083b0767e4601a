"""RTU timing: character time and the 3.5-character silent interval that delimits frames.

The manuals compute the interval with 11 bits per character (start + 8 data + parity + stop, or 2 stop bits
without parity): ``3.5 x 11 / 9600 = 4.01 ms``. Above 19200 baud the Modbus serial line specification fixes
it at 1.75 ms. Wire times here also count 11 bits per character, the conservative figure for every framing.
"""

from __future__ import annotations

BITS_PER_CHAR = 11
FIXED_SILENCE_ABOVE_BAUD = 19200
FIXED_SILENCE = 0.00175


def char_time(baudrate: int) -> float:
    """Seconds one character occupies the line."""
    if baudrate <= 0:
        raise ValueError(f"baud rate {baudrate!r} must be positive")
    return BITS_PER_CHAR / baudrate


def silent_interval(baudrate: int) -> float:
    """The 3.5-character interval between frames, in seconds (at least 1.75 ms above 19200 baud)."""
    if baudrate > FIXED_SILENCE_ABOVE_BAUD:
        return FIXED_SILENCE
    return 3.5 * char_time(baudrate)


def wire_time(n_bytes: int, baudrate: int) -> float:
    """Seconds ``n_bytes`` take on the line at ``baudrate``."""
    return n_bytes * char_time(baudrate)
