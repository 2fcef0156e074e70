"""roadtruth observers: one observer family per module, registered by name (see ``roadtruth.observers.registry``)."""
