"""motionaug: models layer."""
