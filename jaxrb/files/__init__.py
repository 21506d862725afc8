"""Scene files: jaxrb JSON and MJCF."""
