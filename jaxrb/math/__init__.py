"""Shared math: gradient-safe vector math, quaternions, the component algebra."""
