"""motionaug: augment layer."""
