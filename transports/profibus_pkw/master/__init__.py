"""The PKW master as a sans-IO engine: which task goes out each cycle, which response answers it."""
