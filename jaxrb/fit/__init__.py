"""Fitting: sysid, observations, transforms, shooting, least squares, measured data, scoring."""
