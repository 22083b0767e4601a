"""The vendor's Profibus DP telegrams (PPO1 / PPO3) and their codes, sans-IO: bytes <-> words <-> named tuples."""
