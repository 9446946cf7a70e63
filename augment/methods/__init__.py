"""Style-transfer methods behind one interface (``augment.methods.base``), looked up by name."""
