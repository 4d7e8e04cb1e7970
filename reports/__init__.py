"""Reports (one-file HTML with embedded figures, JSON) and exports built on the domain packages."""
