"""Contact response: penalty forces and the impulse solver."""
