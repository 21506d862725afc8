"""Collision detection: shape geometry, the static pair table and one kernel per pair kind."""
