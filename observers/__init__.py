"""roadtruth observers: one observer family per module, registered by name (see ``observers.registry``)."""
