"""motionaug: workflows layer."""
