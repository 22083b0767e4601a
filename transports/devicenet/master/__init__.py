"""The DeviceNet master as a sans-IO engine: frames and times in, frames out (no thread, no bus)."""
