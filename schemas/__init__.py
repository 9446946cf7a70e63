"""motionaug: schemas layer."""
