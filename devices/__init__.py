"""Device interfaces, one per kind, with real drivers and simulated twins side by side."""
